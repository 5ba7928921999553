// Cutting real meshes and replaying recordings through the cutter (geometry only).
#include "engine/errors.h"
#include "engine/mesh_io.h"
#include "engine/recording.h"
#include "engine/scene.h"
#include "harness/plot.h"
#include "harness/replay_outputs.h"
#include "sim/cut.h"
#include "sim/mesh_distance.h"
#include "sim/surface_metrics.h"
#include "sim/voxelize.h"
#include "support.h"

#include <doctest/doctest.h>
#include <nlohmann/json.hpp>

#include <unistd.h>

#define STB_IMAGE_IMPLEMENTATION
#include <stb/stb_image.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

using namespace dvx;
namespace fs = std::filesystem;

namespace {

using dvx_test::TempDir;

std::string read_file(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

const std::string kBunny = dvx_test::source_path("assets/meshes/bunny_npm.obj");

// The options of a replay of `recording` into `out` (the rest at their defaults: physics on).
ReplayOptions replay_of(const std::string& recording, const fs::path& out, bool physics = true) {
  ReplayOptions o;
  o.recording = recording;
  o.out_dir = out.string();
  o.physics = physics;
  return o;
}

// A scripted session: a blade along z sweeping along x at height y, then a partial vertical cut.
void write_session(const std::string& path, int resolution) {
  Scene scene = load_scene(dvx_test::source_path("assets/scenes/bunny.json"));
  scene.pbd.resolution = resolution;
  scene.pbd.sim_resolution = resolution / 8;
  RecordingWriter writer(path, scene, 1.0 / 60.0);
  uint32_t step = 0;
  for (int i = 0; i <= 60; ++i, ++step) {
    const double x = -6.0 + 12.0 * i / 60;
    writer.write_blade(step, {Vec3d(x, 5.3, -5), Vec3d(x, 5.3, 5)}, i > 0);
  }
  for (int i = 1; i <= 40; ++i, ++step) {
    const double y = 11.0 - 8.0 * i / 40;
    writer.write_blade(step, {Vec3d(-1.1, y, -5), Vec3d(-1.1, y, 5)}, true);
  }
}

}  // namespace

TEST_SUITE("replay") {
  TEST_CASE("planar through-cut of the bunny: two closed pieces, volume kept, cut vertices on the plane") {
    const LoadedMesh input = load_mesh(kBunny);
    VoxelModel model;
    std::string error;
    VoxelizeParams params;
    params.resolution = 64;
    REQUIRE(voxelize(input.mesh, params, model, error));
    const double h = model.lattice.voxel_size;
    CutState state;
    init_cut_state(model, state);
    const double uncut = surface_stats(compact_surface(state.surface)).volume;
    const double y0 = 4.137;
    BladePose previous{Vec3d(-6, y0, -5), Vec3d(-6, y0, 5)};
    for (int i = 1; i <= 80; ++i) {
      const double x = -6.0 + 12.0 * i / 80;
      const BladePose pose{Vec3d(x, y0, -5), Vec3d(x, y0, 5)};
      cut_step(model, state, previous, pose);
      previous = pose;
      if (i % 10 == 0) {
        std::string problem;
        CHECK_MESSAGE(check_cut_state(model, state, problem), problem);
        CHECK(surface_stats(compact_surface(state.surface)).boundary_edges == 0);
      }
    }
    const SurfaceMesh mesh = compact_surface(state.surface);
    const SurfaceStats stats = surface_stats(mesh);
    CHECK(stats.components == 2);
    CHECK(stats.boundary_edges == 0);
    CHECK(stats.misoriented_edges == 0);
    CHECK(std::abs(stats.volume - uncut) / uncut < 0.005);
    // Vertices of divided voxels farther than two voxels from the bunny's own surface lie on the plane.
    const TriangleBvh bvh = build_bvh(input.mesh);
    int on_plane = 0;
    for (size_t v = 0; v < mesh.positions.size(); ++v) {
      if (state.divided_of.get(mesh.vertex_voxel[v]) == kDeadIndex) continue;
      const Vec3d p = mesh.positions[v].cast<double>();
      if (closest_point(bvh, p) < 2.0 * h) continue;
      CHECK(std::abs(p.y() - y0) <= 0.01 * h);
      ++on_plane;
    }
    CHECK(on_plane > 200);
  }

  TEST_CASE("the shipped recording replays with every state hash matching") {
    TempDir dir;
    ReplayOptions options = replay_of(dvx_test::source_path("assets/recordings/bunny_cut.jsonl"), dir.path);
    const ReplayResult r = run_replay(options);
    CHECK(r.hash_checked >= 4);
    CHECK(r.hash_mismatched == 0);
    const nlohmann::json summary = nlohmann::json::parse(read_file(dir.path / "summary.json"));
    CHECK(summary["surface"]["boundary_edges"] == 0);
    CHECK(summary["surface"]["components"] == 2);  // the top of the head comes off; the second cut is partial
    CHECK(summary["nonfinite_values"] == 0);
    CHECK(summary["hash_checks"]["mismatched"] == 0);
    for (const char* phase : {"cut", "surface", "total"}) {
      for (const char* stat : {"mean", "p50", "p95", "p99", "max"}) CHECK(summary["timing_ms"][phase].contains(stat));
    }
    CHECK(fs::file_size(dir.path / "final.ply") > 1000);
    CHECK(fs::file_size(dir.path / "timings.csv") > 1000);
  }

  TEST_CASE("the shipped liver session takes a piece off with each of its three strokes and replays to its hashes") {
    // assets/recordings/liver_strokes.jsonl: tests/cli/window_pace.sh's run in the window (the default
    // scene, three strokes across the left lobe from below), recorded on a quiet machine.
    TempDir dir;
    ReplayOptions options = replay_of(dvx_test::source_path("assets/recordings/liver_strokes.jsonl"), dir.path);
    options.workers = 2;
    const ReplayResult r = run_replay(options);
    CHECK(r.steps == 2537);
    CHECK(r.hash_checked == 44);
    CHECK(r.hash_mismatched == 0);
    const nlohmann::json summary = nlohmann::json::parse(read_file(dir.path / "summary.json"));
    REQUIRE(summary["strokes"].size() == 3);
    for (const nlohmann::json& stroke : summary["strokes"]) CHECK(stroke["created"] == 1);
    CHECK(summary["surface"]["components"] == 4);
    CHECK(summary["surface"]["boundary_edges"] == 0);
    CHECK(summary["nonfinite_values"] == 0);
    // 42 whole simulated seconds of 60 steps (the last 17 steps left out), each paced above 0.
    CHECK(summary["pace_per_second"]["seconds"] == 42);
    CHECK(summary["pace_per_second"]["min"].get<double>() > 0.0);
    CHECK(summary["pace_per_second"]["min"].get<double>() <= summary["pace_per_second"]["p50"].get<double>());
  }

  TEST_CASE("a stroke across the liver's lobe tip that left a hairline takes the tip off") {
    // tests/data/liver_tip_hairline.jsonl: the commands of window_pace.sh's first stroke (across the
    // lobe's tip, the tissue swinging as it is cut), each shifted by up to a step at random, that left
    // the tip on a hairline: voxels the stroke left partly cut whose cuts turned with the tip (blade
    // normals up to ~70 degrees apart), which the stroke's end did not close while it closed only
    // voxels whose cuts lie in one plane (sim/cut.cpp cut_close_seams, docs/cutting.md).
    TempDir dir;
    const ReplayResult r = run_replay(replay_of(dvx_test::source_path("tests/data/liver_tip_hairline.jsonl"), dir.path));
    CHECK(r.steps == 700);
    const nlohmann::json summary = nlohmann::json::parse(read_file(dir.path / "summary.json"));
    REQUIRE(summary["strokes"].size() == 1);
    CHECK(summary["strokes"][0]["created"] == 1);
    CHECK(summary["surface"]["boundary_edges"] == 0);
  }

  TEST_CASE("timings.csv ends with grab_force_n: the grab's force in newtons, non-zero while a grab holds") {
    TempDir dir;
    ReplayOptions options = replay_of(dvx_test::source_path("assets/recordings/bunny_grab.jsonl"), dir.path);
    const ReplayResult r = run_replay(options);
    CHECK(r.hash_mismatched == 0);
    std::istringstream csv(read_file(dir.path / "timings.csv"));
    std::string line;
    REQUIRE(std::getline(csv, line));
    // The columns before it keep their names and order (other tools read them).
    CHECK(line == "step,cut_ms,surface_ms,deform_ms,total_ms,cut_voxels,edges_hit,edges_cut,voxels_divided,"
                  "vertices_changed,triangles_changed,cutting,sim_voxels_cut,grab_force_n");
    int rows = 0, pulling = 0;
    double first = -1.0, largest = 0.0;
    while (std::getline(csv, line)) {
      const double force = std::stod(line.substr(line.rfind(',') + 1));
      if (rows++ == 0) first = force;
      CHECK(force >= 0.0);
      pulling += force > 0.0;
      largest = std::max(largest, force);
    }
    MESSAGE(pulling << " of " << rows << " steps with a grab force, largest " << largest);
    CHECK(first == 0.0);  // no grab at step 0
    CHECK(pulling > 20);
    CHECK(pulling < rows);
    CHECK(largest > 0.0);
  }

  TEST_CASE("a replay plots its timings with gnuplot, and still succeeds without gnuplot") {
    TempDir dir;
    const std::string session = (dir.path / "session.jsonl").string();
    write_session(session, 32);
    ReplayOptions options = replay_of(session, dir.path / "plotted");
    std::string error;
    if (find_gnuplot(error).empty()) {
      MESSAGE("plotting part skipped: " << error);
    } else {
      run_replay(options);
      // A whole SVG document with one series per phase (named in the legends as <text>NAME</text>).
      const std::string svg = read_file(dir.path / "plotted" / "timings.svg");
      CHECK(svg.rfind("<?xml", 0) == 0);
      CHECK(svg.find("<svg") != std::string::npos);
      CHECK(svg.find("</svg>") != std::string::npos);
      size_t open = 0, close = 0;
      for (size_t at = svg.find("<g"); at != std::string::npos; at = svg.find("<g", at + 1)) open += svg[at + 2] == ' ' || svg[at + 2] == '>';
      for (size_t at = svg.find("</g>"); at != std::string::npos; at = svg.find("</g>", at + 1)) ++close;
      CHECK(open == close);
      for (const std::string series : {"<text>cut</text>", "<text>surface</text>", "<text>deform</text>",
                                       "<text>total</text>", "steps that cut voxels", "frame budget 33 ms",
                                       "haptic budget 1 ms", "p99"}) {
        CAPTURE(series);
        CHECK(svg.find(series) != std::string::npos);
      }
      CHECK(fs::file_size(dir.path / "plotted" / "timings.png") > 1000);
    }
    // No gnuplot: the CSV and the summary are written, the plot is skipped, the replay succeeds.
    const dvx_test::ScopedEnv no_gnuplot("DIVVOX_GNUPLOT", (dir.path / "no-such-gnuplot").string());
    options.out_dir = (dir.path / "unplotted").string();
    const ReplayResult r = run_replay(options);
    CHECK(r.steps > 0);
    CHECK(fs::file_size(dir.path / "unplotted" / "timings.csv") > 100);
    CHECK(fs::exists(dir.path / "unplotted" / "summary.json"));
    CHECK_FALSE(fs::exists(dir.path / "unplotted" / "timings.svg"));
  }

  TEST_CASE("record, replay and replay again: identical hashes and identical final mesh") {
    TempDir dir;
    const std::string session = (dir.path / "session.jsonl").string();
    write_session(session, 48);
    // First replay writes a recording with hashes every 10 steps.
    ReplayOptions first = replay_of(session, dir.path / "a", false);
    first.record_path = (dir.path / "hashed.jsonl").string();
    first.hash_every = 10;
    const ReplayResult a = run_replay(first);
    // Replaying that recording checks every hash.
    ReplayOptions second = replay_of(first.record_path, dir.path / "b", false);
    const ReplayResult b = run_replay(second);
    CHECK(b.hash_checked >= 10);
    CHECK(b.hash_mismatched == 0);
    CHECK(a.final_hash == b.final_hash);
    CHECK(read_file(dir.path / "a" / "final.ply") == read_file(dir.path / "b" / "final.ply"));
  }

  TEST_CASE("a tampered hash is reported as a divergence at its step") {
    TempDir dir;
    const std::string session = (dir.path / "session.jsonl").string();
    write_session(session, 32);
    ReplayOptions first = replay_of(session, dir.path / "a", false);
    first.record_path = (dir.path / "hashed.jsonl").string();
    first.hash_every = 20;
    run_replay(first);
    // Change the hash recorded at step 80.
    std::string text = read_file(first.record_path);
    const std::string key = "\",\"step\":80}";  // the end of the hash line (keys are sorted)
    const size_t at = text.find(key);
    REQUIRE(at != std::string::npos);
    const size_t hash_at = text.rfind("\"hash\":\"", at) + 8;
    text[hash_at] = text[hash_at] == '0' ? '1' : '0';
    std::ofstream(first.record_path, std::ios::binary | std::ios::trunc) << text;
    ReplayOptions second = replay_of(first.record_path, dir.path / "b", false);
    const ReplayResult r = run_replay(second);
    CHECK(r.hash_mismatched == 1);
    CHECK(r.first_mismatch_step == 80);
  }

  TEST_CASE("physics replay: recorded hashes match with 1 and with 2 workers, mass is conserved") {
    // Every batch of a step split across the workers (a scene this small runs on one thread otherwise),
    // so the task pool's parallel path is what the hashes compare (and what ThreadSanitizer sees).
    const dvx_test::ScopedEnv chunks("DIVVOX_CHUNK_WORK", "1");
    TempDir dir;
    const std::string session = (dir.path / "session.jsonl").string();
    write_session(session, 32);
    ReplayOptions first = replay_of(session, dir.path / "a");
    first.record_path = (dir.path / "hashed.jsonl").string();
    first.hash_every = 10;
    first.workers = 2;
    const ReplayResult a = run_replay(first);
    for (int workers : {1, 2}) {
      ReplayOptions again = replay_of(first.record_path, dir.path / ("w" + std::to_string(workers)));
      again.workers = workers;
      const ReplayResult r = run_replay(again);
      CHECK(r.hash_checked >= 10);
      CHECK(r.hash_mismatched == 0);
      CHECK(r.final_hash == a.final_hash);
    }
    const nlohmann::json summary = nlohmann::json::parse(read_file(dir.path / "a" / "summary.json"));
    CHECK(summary["nonfinite_values"] == 0);
    const double m0 = summary["mass"]["initial"], m1 = summary["mass"]["final"];
    CHECK(std::abs(m1 - m0) <= 1e-12 * m0);
    CHECK(summary["cut"]["sim_voxels_divided"].get<int>() > 0);
    CHECK(summary["pool"]["wakeups"].get<uint64_t>() > 0);  // the workers took part
    CHECK(summary["pool"]["stages"].get<uint64_t>() > 10 * summary["steps"].get<uint64_t>());
  }
  TEST_CASE("a bad DIVVOX_CHUNK_WORK is refused naming the variable") {
    TempDir dir;
    const std::string session = (dir.path / "session.jsonl").string();
    write_session(session, 32);
    for (const char* bad : {"0", "-5", "12x", "99999999999"}) {
      CAPTURE(bad);
      const dvx_test::ScopedEnv chunks("DIVVOX_CHUNK_WORK", bad);
      try {
        run_replay(replay_of(session, dir.path / "out"));
        FAIL("accepted");
      } catch (const InputError& e) {
        CHECK(std::string(e.what()).find("DIVVOX_CHUNK_WORK") != std::string::npos);
      }
    }
  }
  TEST_CASE("headless replay with frames: the bunny renders to PNGs showing the object") {
#ifndef DIVVOX_HAS_RENDER
    DVX_SKIP_OR_FAIL_WITHOUT_GL("this build has no renderer");
#else
    TempDir dir;
    ReplayOptions options = replay_of(dvx_test::source_path("assets/recordings/bunny_cut.jsonl"), dir.path);
    options.frames_every = 130;
    options.width = 320;
    options.height = 180;
    ReplayResult r;
    try {
      r = run_replay(options);
    } catch (const InputError& e) {
      // No EGL here: say so, unless the suite requires GL.
      DVX_SKIP_OR_FAIL_WITHOUT_GL(e.what());
      return;
    }
    CHECK(r.frames_written == 5);  // steps 0, 130, 260, 390, 520 (582 steps)
    CHECK(r.hash_mismatched == 0);  // rendering does not change the simulation
    for (const char* name : {"frame_00000.png", "frame_00130.png", "frame_00260.png", "frame_00390.png"}) {
      CAPTURE(name);
      int w = 0, h = 0, channels = 0;
      unsigned char* pixels = stbi_load((dir.path / "frames" / name).string().c_str(), &w, &h, &channels, 3);
      REQUIRE(pixels != nullptr);
      CHECK(w == 320);
      CHECK(h == 180);
      // Object pixels: those that differ from the background (the corner pixel).
      int object = 0;
      for (int i = 0; i < w * h; ++i) {
        const int d = std::abs(pixels[3 * i] - pixels[0]) + std::abs(pixels[3 * i + 1] - pixels[1]) +
                      std::abs(pixels[3 * i + 2] - pixels[2]);
        object += d > 24;
      }
      stbi_image_free(pixels);
      const double coverage = double(object) / double(w * h);
      CHECK(coverage > 0.05);
      CHECK(coverage < 0.95);
    }
    const nlohmann::json summary = nlohmann::json::parse(read_file(dir.path / "summary.json"));
    CHECK(summary["frames"]["written"] == 5);
    CHECK(summary["timing_ms"]["render"]["count"].get<int>() >= 4);
    CHECK(fs::exists(dir.path / "timings.svg"));
    CHECK(fs::exists(dir.path / "frame_timings.csv"));
#endif
  }
  TEST_CASE("a camera in the recording sets the frames' view") {
#ifdef DIVVOX_HAS_RENDER
    TempDir dir;
    // The shipped poses for 11 steps, with and without a close camera at step 0.
    std::istringstream in(read_file(dvx_test::source_path("assets/recordings/bunny_cut.jsonl")));
    std::string header, line;
    std::getline(in, header);
    nlohmann::json h = nlohmann::json::parse(header);
    h["scene"]["mesh"] = dvx_test::source_path("assets/meshes/bunny_npm.obj");
    h.erase("physics");
    std::string body;
    for (int i = 0; i < 11 && std::getline(in, line);) {
      if (line.find("\"blade\"") == std::string::npos) continue;
      body += line + "\n";
      ++i;
    }
    const auto coverage_of = [&](const std::string& camera_line, const std::string& name) {
      std::ofstream((dir.path / name).string()) << h.dump() << "\n" << camera_line << body;
      ReplayOptions o = replay_of((dir.path / name).string(), dir.path / (name + ".out"));
      o.frames_every = 10;
      o.width = 160;
      o.height = 90;
      try {
        run_replay(o);
      } catch (const InputError& e) {
        DVX_SKIP_OR_FAIL_WITHOUT_GL(e.what());
        return -1.0;
      }
      int w = 0, hh = 0, n = 0;
      unsigned char* p = stbi_load((dir.path / (name + ".out") / "frames" / "frame_00010.png").string().c_str(), &w, &hh, &n, 3);
      REQUIRE(p != nullptr);
      int object = 0;
      for (int i = 0; i < w * hh; ++i) {
        object += std::abs(p[3 * i] - p[0]) + std::abs(p[3 * i + 1] - p[1]) + std::abs(p[3 * i + 2] - p[2]) > 24;
      }
      stbi_image_free(p);
      return double(object) / double(w * hh);
    };
    const double framed = coverage_of("", "framed.jsonl");
    const double close = coverage_of("{\"step\":0,\"camera\":{\"target\":[0,5,0],\"distance\":9,\"yaw\":0.5,\"pitch\":0.2}}\n",
                                     "close.jsonl");
    if (framed < 0 || close < 0) return;
    CHECK(framed > 0.05);
    CHECK(close > framed + 0.1);  // the close camera fills more of the frame
#endif
  }
}
