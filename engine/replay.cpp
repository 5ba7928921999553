#include "engine/replay.h"

#include "engine/errors.h"
#include "engine/mesh_io.h"
#include "engine/output.h"
#include "engine/recording.h"
#include "engine/task_pool.h"
#include "engine/snapshot.h"
#include "engine/svg_plot.h"
#ifdef DIVVOX_HAS_RENDER
#include "engine/headless_render.h"
#endif
#include "engine/voxelize_job.h"
#include "sim/cut.h"
#include "sim/pbd.h"
#include "sim/state_hash.h"
#include "sim/surface_metrics.h"
#include "sim/voxelize.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <atomic>
#include <csignal>
#include <sstream>
#include <thread>

namespace dvx {
namespace {

using Clock = std::chrono::steady_clock;

// SIGINT stops a replay cleanly: the step loop ends, outputs cover the steps done.
std::atomic<bool> g_interrupted{false};
void on_sigint(int) { g_interrupted.store(true); }

double ms_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

// Per-step timings and counts (one row of timings.csv).
struct StepRow {
  uint32_t step;
  bool cutting;
  double cut_ms, surface_ms, deform_ms, total_ms;
  CutStepStats stats;
  uint32_t sim_voxels_cut;
};

// {"mean","p50","p95","p99","max"} of a sample (empty: zeros).
nlohmann::json percentiles(std::vector<double> values) {
  if (values.empty()) return {{"mean", 0.0}, {"p50", 0.0}, {"p95", 0.0}, {"p99", 0.0}, {"max", 0.0}, {"count", 0}};
  std::sort(values.begin(), values.end());
  double sum = 0.0;
  for (double v : values) sum += v;
  const auto at = [&](double q) {
    const size_t i = size_t(std::ceil(q * double(values.size()))) - 1;
    return values[std::min(i, values.size() - 1)];
  };
  return {{"mean", sum / double(values.size())},
          {"p50", at(0.50)},
          {"p95", at(0.95)},
          {"p99", at(0.99)},
          {"max", values.back()},
          {"count", values.size()}};
}

bool same_pose(const BladePose& a, const BladePose& b) { return a.a == b.a && a.b == b.b; }

// PBD parameters of a scene.
PbdParams pbd_params(const Scene& scene, double dt) {
  PbdParams p;
  p.resolution = scene.resolution;
  p.sim_resolution = scene.sim_resolution;
  p.density = scene.material.density;
  p.stretch_compliance = scene.material.stretch_compliance;
  p.shape_stiffness = scene.material.shape_stiffness;
  p.dt = dt;
  p.substeps = scene.solver.substeps;
  p.iterations = scene.solver.iterations;
  p.damping = scene.solver.damping;
  p.gravity = scene.gravity;
  for (const FixedBox& b : scene.fixed) {
    Aabb box;
    box.grow(b.min);
    box.grow(b.max);
    p.fixed.push_back(box);
  }
  return p;
}

// The state hash: the cut surface, and the particles when the physics runs.
uint64_t state_hash(const CutState& cut, const PbdState* pbd) {
  uint64_t h = cut_state_hash(cut);
  if (pbd != nullptr) {
    Fnv1a f;
    f.add(h);
    for (size_t p = 0; p < pbd->position.size(); ++p) {
      if (pbd->mass[p] > 0.0) f.bytes(pbd->position[p].data(), 3 * sizeof(double));
    }
    h = f.value;
  }
  return h;
}

// A grab command from a step line: {"target": [x,y,z], "compliance": c} starts (nearest particle) or
// moves the grab; "release" ends it. Anything else is an error naming the line.
void apply_grab(const nlohmann::json& grab, PbdState& pbd, const std::string& file, uint32_t line) {
  if (grab.is_string() && grab.get<std::string>() == "release") {
    grab_end(pbd);
    return;
  }
  const auto bad = [&] {
    throw_input(file, "line " + std::to_string(line) +
                          ": grab must be {\"target\": [x,y,z], \"compliance\": c} or \"release\"");
  };
  if (!grab.is_object() || !grab.contains("target") || !grab["target"].is_array() || grab["target"].size() != 3) bad();
  Vec3d target;
  for (int a = 0; a < 3; ++a) {
    if (!grab["target"][a].is_number()) bad();
    target[a] = grab["target"][a].get<double>();
  }
  if (!target.allFinite()) bad();
  double compliance = 1e-4;
  if (grab.contains("compliance")) {
    if (!grab["compliance"].is_number() || !(grab["compliance"].get<double>() >= 0.0)) bad();
    compliance = grab["compliance"].get<double>();
  }
  if (pbd.grab_particle == ~0u) {
    grab_begin(pbd, target, compliance);
  } else {
    grab_move(pbd, target);
  }
}

}  // namespace

ReplayResult run_replay(const ReplayOptions& options) {
  const Recording recording = read_recording(options.recording);
  for (const std::string& warning : recording.warnings) std::fprintf(stderr, "divvox: warning: %s\n", warning.c_str());

  // The voxel model of the recording's scene.
  const Scene& scene = recording.scene;
  const LoadedMesh input = load_mesh(scene.mesh_path);
  check_voxelize_memory(scene.mesh_path, mesh_bounds(input.mesh), input.mesh.triangles.size(), scene.resolution);
  VoxelModel model;
  VoxelizeParams params;
  params.resolution = scene.resolution;
  std::string error;
  if (!voxelize(input.mesh, params, model, error)) throw_input(scene.mesh_path, error);
  CutState state;
  const Clock::time_point init_start = Clock::now();
  init_cut_state(model, state);
  const double init_ms = ms_between(init_start, Clock::now());
  const SurfaceStats initial = surface_stats(compact_surface(state.surface));

  // The PBD model and its worker threads.
  std::unique_ptr<PbdState> pbd;
  std::unique_ptr<TaskPool> pool;
  double initial_mass = 0.0;
  if (options.physics) {
    pbd = std::make_unique<PbdState>();
    if (!init_pbd(model, state, pbd_params(scene, recording.dt), *pbd, error)) throw_input(options.recording, error);
    pool = std::make_unique<TaskPool>(options.workers);
    initial_mass = total_mass(*pbd);
  }

  make_output_dir(options.out_dir);
  std::unique_ptr<RecordingWriter> writer;
  if (!options.record_path.empty()) {
    writer = std::make_unique<RecordingWriter>(options.record_path, scene, recording.dt, options.physics ? 1 : 0);
  }
  // Hashes taken in the other mode cannot match: say so instead of reporting a divergence.
  const bool check_hashes = recording.physics < 0 || recording.physics == (options.physics ? 1 : 0);
  if (!check_hashes) {
    std::fprintf(stderr, "divvox: warning: %s: its state hashes were taken with the physics %s; not checked\n",
                 options.recording.c_str(), recording.physics ? "on" : "off");
  }

  // Step through the recording: a line sets the pose (kept until the next line); the sweep from the
  // previous step's pose to this step's cuts when this step is cutting.
  ReplayResult result;
  std::vector<StepRow> rows;
  BladePose pose;
  bool have_pose = false, cutting = false;
  BladePose rest_pose;  // the blade in rest space after the last cutting step
  bool rest_pose_valid = false;
  uint64_t totals_voxels_cut = 0;
  size_t line = 0;
  const uint32_t last = recording.last_step();
  uint32_t steps_done = 0;
  DirtyHistory dirty_history;
  const Clock::time_point start = Clock::now();
  // The simulation loop (on its own thread when a render thread draws its snapshots).
  const auto simulate = [&](SnapshotExchange* exchange) {
  for (uint32_t step = 0; step <= last && !recording.steps.empty(); ++step) {
    if (g_interrupted.load()) {
      result.interrupted = true;
      break;
    }
    // --speed realtime: a step every dt of wall-clock time.
    if (options.realtime) std::this_thread::sleep_until(start + std::chrono::duration<double>(recording.dt * step));
    const BladePose previous = pose;
    const bool had_pose = have_pose;
    std::string recorded_hash;
    for (; line < recording.steps.size() && recording.steps[line].step == step; ++line) {
      const RecordedStep& r = recording.steps[line];
      if (r.has_blade) {
        pose = r.blade;
        cutting = r.cutting;
        have_pose = true;
      }
      if (r.has_hash && check_hashes) recorded_hash = r.hash;
      if (pbd && r.extra.is_object() && r.extra.contains("grab")) {
        apply_grab(r.extra["grab"], *pbd, options.recording, r.line);
        if (writer) writer->write_line({{"step", step}, {"grab", r.extra["grab"]}});
      }
    }
    if (!(cutting && had_pose)) rest_pose_valid = false;  // a new cut starts from the blade where it is
    StepRow row{step, cutting, 0, 0, 0, 0, {}, 0};
    const Clock::time_point t0 = Clock::now();
    if (cutting && had_pose && !same_pose(previous, pose)) {
      // The blade moves in world space; cuts are made in rest space. The sweep starts where the last
      // one ended in rest space, so consecutive sweeps join even while the body moves.
      BladePose from = previous, to = pose;
      if (pbd) {
        from = rest_pose_valid ? rest_pose
                               : BladePose{pbd_world_to_rest(*pbd, previous.a), pbd_world_to_rest(*pbd, previous.b)};
        to = {pbd_world_to_rest(*pbd, pose.a), pbd_world_to_rest(*pbd, pose.b)};
      }
      rest_pose = to;
      rest_pose_valid = true;
      cut_divide(model, state, from, to, row.stats);
      const Clock::time_point t1 = Clock::now();
      cut_update_surface(model, state, row.stats);
      const Clock::time_point t2 = Clock::now();
      if (pbd) row.sim_voxels_cut = pbd_apply_cut(model, state, *pbd);
      row.cut_ms = ms_between(t0, t1) + ms_between(t2, Clock::now());  // divide, fine and coarse
      row.surface_ms = ms_between(t1, t2);
      totals_voxels_cut += row.stats.voxels_cut;
    }
    if (pbd) {
      const Clock::time_point t3 = Clock::now();
      pbd_step(state, *pbd, pool->runner());
      row.deform_ms = ms_between(t3, Clock::now());
    }
    row.total_ms = ms_between(t0, Clock::now());
    rows.push_back(row);
    if (writer && have_pose) writer->write_blade(step, pose, cutting);

    // Determinism: compare with the recorded hash, write ours.
    const bool want_hash = !recorded_hash.empty() || (writer && options.hash_every > 0 && step % options.hash_every == 0);
    if (want_hash) {
      const std::string hash = hash_hex(state_hash(state, pbd.get()));
      if (!recorded_hash.empty()) {
        ++result.hash_checked;
        if (hash != recorded_hash) {
          ++result.hash_mismatched;
          if (result.first_mismatch_step < 0) result.first_mismatch_step = step;
        }
      }
      if (writer && options.hash_every > 0 && step % options.hash_every == 0) writer->write_hash(step, hash);
    }
    // Hand the surface to the render thread (capture frames every frames_every steps).
    if (exchange != nullptr) {
      const bool capture = options.frames_every > 0 && step % options.frames_every == 0;
      const StepTimings timings{row.cut_ms, row.surface_ms, row.deform_ms, row.total_ms};
      exchange->publish(
          [&](Snapshot& slot, uint64_t slot_sequence) {
            fill_snapshot(slot, slot_sequence, state.surface, pbd ? &pbd->deformed : nullptr, dirty_history, step,
                          timings);
          },
          capture);
      state.surface.clear_dirty();
    }
    steps_done = step + 1;
    if (options.progress && step % 200 == 0) std::fprintf(stderr, "\rdivvox: replay step %u / %u", step, last);
  }
  };

  // Threads: simulation here, or simulation on a thread and rendering here (EGL contexts belong to
  // the thread that made them).
  std::vector<FrameRow> frames;
  const bool render = options.render || options.frames_every > 0;
  const std::string frames_dir = options.frames_every > 0 ? (std::filesystem::path(options.out_dir) / "frames").string() : "";
  std::signal(SIGINT, on_sigint);
  if (render) {
#ifdef DIVVOX_HAS_RENDER
    std::string render_error;
    if (!probe_headless_render(render_error)) throw_input(options.recording, "headless rendering: " + render_error);
    if (!frames_dir.empty()) make_output_dir(frames_dir);
    HeadlessRenderOptions ro;
    ro.width = options.width;
    ro.height = options.height;
    ro.frames_dir = frames_dir;
    ro.wireframe = options.wireframe;
    ro.framing = mesh_bounds(input.mesh);
    SnapshotExchange exchange;
    std::thread sim_thread([&] {
      simulate(&exchange);
      exchange.finish();
    });
    const bool rendered = run_headless_render(exchange, ro, frames, render_error);
    sim_thread.join();
    if (!rendered) throw_input(options.recording, "headless rendering: " + render_error);
    for (const FrameRow& f : frames) result.frames_written += f.written ? 1 : 0;
#else
    throw_input(options.recording, "this build has no renderer (configured with -DDIVVOX_GRAPHICS=OFF); drop --frames");
#endif
  } else {
    simulate(nullptr);
  }
  std::signal(SIGINT, SIG_DFL);

  if (options.progress) std::fprintf(stderr, "\n");
  result.steps = steps_done;
  result.final_hash = hash_hex(state_hash(state, pbd.get()));
  if (writer && steps_done > 0 && (options.hash_every == 0 || (steps_done - 1) % options.hash_every != 0)) {
    writer->write_hash(steps_done - 1, result.final_hash);
  }

  // Final surface and its checks.
  // (The topology checks run on the rest-space surface; final.ply is the deformed one.)
  const SurfaceMesh final_surface = compact_surface(state.surface);
  const SurfaceStats stats = surface_stats(final_surface);
  uint64_t nonfinite = 0;
  for (const Vec3f& p : final_surface.positions) nonfinite += p.allFinite() ? 0 : 1;
  SurfaceMesh deformed_surface = final_surface;
  if (pbd) {
    nonfinite += count_nonfinite(*pbd);
    CutSurface deformed = state.surface;
    for (size_t slot = 0; slot < deformed.positions.size() && slot < pbd->deformed.size(); ++slot) {
      if (deformed.vertex_piece[slot] != CutSurface::kFreeKey) deformed.positions[slot] = pbd->deformed[slot];
    }
    deformed_surface = compact_surface(deformed);
  }

  // timings.csv
  std::ostringstream csv;
  csv << "step,cut_ms,surface_ms,deform_ms,total_ms,cut_voxels,edges_hit,edges_cut,voxels_divided,"
         "vertices_changed,triangles_changed,cutting,sim_voxels_cut\n";
  std::vector<double> cut_ms, surface_ms, total_ms, deform_ms, step_ms;
  for (const StepRow& r : rows) {
    if (pbd) deform_ms.push_back(r.deform_ms);
    step_ms.push_back(r.total_ms);
    csv << r.step << ',' << r.cut_ms << ',' << r.surface_ms << ',' << r.deform_ms << ',' << r.total_ms << ','
        << r.stats.voxels_cut << ','
        << r.stats.edges_hit << ',' << r.stats.edges_cut << ',' << r.stats.voxels_divided << ','
        << r.stats.vertices_changed << ',' << r.stats.triangles_changed << ',' << (r.cutting ? 1 : 0) << ','
        << r.sim_voxels_cut << '\n';
    if (r.stats.edges_hit > 0) {
      cut_ms.push_back(r.cut_ms);
      surface_ms.push_back(r.surface_ms);
      total_ms.push_back(r.total_ms);
    }
  }
  const std::filesystem::path out(options.out_dir);
  write_text_file((out / "timings.csv").string(), csv.str());
  // Per-phase time against step.
  {
    Plot plot;
    plot.title = "divvox replay: time per step";
    plot.x_label = "step";
    plot.y_label = "ms";
    PlotSeries cut{"cut", {}, {}, false, true}, surface{"surface", {}, {}, false, true},
        deform{"deform", {}, {}, false, true}, total{"total", {}, {}, false, true};
    for (const StepRow& r : rows) {
      for (PlotSeries* series : {&cut, &surface, &deform, &total}) series->x.push_back(r.step);
      cut.y.push_back(r.cut_ms);
      surface.y.push_back(r.surface_ms);
      deform.y.push_back(r.deform_ms);
      total.y.push_back(r.total_ms);
    }
    plot.series = {cut, surface};
    if (pbd) plot.series.push_back(deform);
    plot.series.push_back(total);
    write_text_file((out / "timings.svg").string(), plot_svg(plot));
  }
  // Per-frame timings of the render thread.
  std::vector<double> render_ms, interval_ms;
  if (!frames.empty()) {
    std::ostringstream f;
    f << "frame,step,upload_ms,draw_ms,readback_ms,frame_interval_ms,written\n";
    for (const FrameRow& r : frames) {
      f << r.frame << ',' << r.step << ',' << r.upload_ms << ',' << r.draw_ms << ',' << r.readback_ms << ','
        << r.interval_ms << ',' << (r.written ? 1 : 0) << '\n';
      render_ms.push_back(r.upload_ms + r.draw_ms + r.readback_ms);
      if (r.frame > 0) interval_ms.push_back(r.interval_ms);
    }
    write_text_file((out / "frame_timings.csv").string(), f.str());
  }
  save_ply((out / "final.ply").string(), deformed_surface);

  // summary.json (DESIGN §1 contract: the fields that apply without physics).
  nlohmann::json summary = {
      {"recording", options.recording},
      {"scene", scene_to_json(scene)},
      {"physics", bool(pbd)},
      {"workers", pbd ? pool->workers() : 1},
      {"steps", result.steps},
      {"dt", recording.dt},
      {"final_hash", result.final_hash},
      {"hash_checks",
       {{"checked", result.hash_checked},
        {"mismatched", result.hash_mismatched},
        {"first_mismatch_step", result.first_mismatch_step}}},
      {"timing_ms",
       {{"cut", percentiles(cut_ms)},
        {"surface", percentiles(surface_ms)},
        {"deform", percentiles(deform_ms)},
        {"total", percentiles(total_ms)},
        {"step", percentiles(step_ms)},
        {"render", percentiles(render_ms)},
        {"frame_interval", percentiles(interval_ms)}}},
      {"frames", {{"rendered", frames.size()}, {"written", result.frames_written}, {"size", {options.width, options.height}}}},
      {"interrupted", result.interrupted},
      {"wall_s", std::chrono::duration<double>(Clock::now() - start).count()},
      {"timing_note", "cut, surface, total: over steps whose blade sweep crossed lattice edges; deform and step: every step"},
      {"init_ms", init_ms},
      {"lattice", {model.lattice.nx, model.lattice.ny, model.lattice.nz}},
      {"cut",
       {{"voxels_cut", totals_voxels_cut},
        {"voxels_divided", state.divided.size()},
        {"edges_cut", state.edge_cuts.size()},
        {"sim_voxels_divided", pbd ? sim_voxels_divided(*pbd) : 0},
        {"explicit_bytes", cut_memory_bytes(state)}}},
      {"surface",
       {{"vertices", stats.vertices},
        {"triangles", stats.triangles},
        {"boundary_edges", stats.boundary_edges},
        {"nonmanifold_edges", stats.nonmanifold_edges},
        {"misoriented_edges", stats.misoriented_edges},
        {"components", stats.components},
        {"volume", stats.volume},
        {"initial_volume", initial.volume}}},
      {"nonfinite_values", nonfinite},
  };
  if (pbd) {
    summary["mass"] = {{"initial", initial_mass}, {"final", total_mass(*pbd)}};
    summary["kinetic_energy"] = kinetic_energy(*pbd);
    summary["particles"] = pbd->position.size() - pbd->free_particles.size();
    summary["shape_constraints"] = pbd->pieces.size();
    summary["stretch_constraints"] = pbd->stretch.size();
  }
  result.summary_path = (out / "summary.json").string();
  write_json_file(result.summary_path, summary);
  return result;
}

}  // namespace dvx
