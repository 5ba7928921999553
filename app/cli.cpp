#include "app/cli.h"

#include "bench/bench.h"
#include "engine/errors.h"
#include "engine/mesh_io.h"
#include "engine/output.h"
#include "engine/replay.h"
#include "engine/resources.h"
#include "engine/scene.h"
#include "engine/voxelize_job.h"
#ifdef DIVVOX_HAS_UI
#include "ui/app.h"
#endif

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <cstdio>
#include <filesystem>
#include <string>

namespace dvx {
namespace {

constexpr const char* kDefaultScene = "assets/scenes/bunny.json";

// The default scene: relative to the working directory, else to the source tree.
std::string default_scene_path() {
  if (std::filesystem::exists(kDefaultScene)) return kDefaultScene;
  return (std::filesystem::path(DIVVOX_SOURCE_DIR_DEFAULT) / kDefaultScene).string();
}

// `divvox voxelize`: flags as parsed.
struct VoxelizeArgs {
  std::string mesh;
  std::string scene;
  int resolution = 0;  // 0: from the scene, else 128
  std::string out = "out/voxelize";
  uint64_t error_samples = 100000;
  uint64_t seed = 1;
};

int run_voxelize_command(const VoxelizeArgs& args) {
  VoxelizeJobOptions options;
  options.error_samples = args.error_samples;
  options.seed = args.seed;
  options.progress = stderr_is_tty();
  options.resolution = 128;
  if (!args.scene.empty() || args.mesh.empty()) {
    const Scene scene = load_scene(args.scene.empty() ? default_scene_path() : args.scene);
    options.mesh_path = scene.mesh_path;
    options.resolution = scene.resolution;
  }
  if (!args.mesh.empty()) options.mesh_path = args.mesh;
  if (args.resolution != 0) options.resolution = args.resolution;

  make_output_dir(args.out);
  const VoxelizeJobResult result = run_voxelize(options);
  const std::filesystem::path out(args.out);
  write_json_file((out / "report.json").string(), voxelize_report(options, result));
  save_ply((out / "surface.ply").string(), result.surface);

  const Lattice& l = result.model.lattice;
  std::printf("voxelized %s: %d x %d x %d voxels (size %g), %u occupied, %zu crossing edges\n",
              options.mesh_path.c_str(), l.nx, l.ny, l.nz, l.voxel_size, result.model.occupied_voxels,
              result.model.crossings.size());
  std::printf("surface: %u vertices, %u triangles, %u boundary edges, %u components, volume %g (input %g)\n",
              result.stats.vertices, result.stats.triangles, result.stats.boundary_edges, result.stats.components,
              result.stats.volume, result.input_volume);
  if (options.error_samples > 0) {
    std::printf("error to input (voxels): max %.3f mean %.3f rms %.3f\n", result.error.max, result.error.mean,
                result.error.rms);
  }
  std::printf("time: load %.1f ms, voxelize %.1f ms, contour %.1f ms, total %.1f ms\n", result.ms.load,
              result.ms.voxelize, result.ms.contour, result.ms.total);
  std::printf("wrote %s and %s\n", (out / "report.json").c_str(), (out / "surface.ply").c_str());
  return kExitOk;
}

// Turns a comma-separated flag into integers ("64,128,256").
std::vector<int> parse_int_list(const std::string& flag, const std::string& text) {
  std::vector<int> values;
  size_t start = 0;
  while (start <= text.size()) {
    const size_t end = std::min(text.find(',', start), text.size());
    const std::string item = text.substr(start, end - start);
    try {
      size_t used = 0;
      const int value = std::stoi(item, &used);
      if (used != item.size() || value < 1 || value > kMaxResolution) throw std::invalid_argument(item);
      values.push_back(value);
    } catch (const std::exception&) {
      throw_input(flag, "'" + item + "' is not a resolution in [1, " + std::to_string(kMaxResolution) + "]");
    }
    start = end + 1;
  }
  return values;
}

}  // namespace

int run_cli(int argc, char** argv) {
  CLI::App app{"divvox: interactive cutting of deformable objects with Divided Voxels"};
  app.require_subcommand(0, 1);  // none: the interactive window
  app.set_version_flag("--version", "divvox 0.1.0");
  app.footer("Exit codes: 0 success, 2 bad input (file, flag or value), 1 internal failure.");

  // divvox [SCENE.json]: the window (no subcommand).
  std::string window_scene, window_record, window_play, window_screenshot, window_size = "1280x720";
  int window_frames = 0;
  app.add_option("scene", window_scene, "Scene to open in the window (default: assets/scenes/bunny.json)");
  app.add_option("--record", window_record, "Record the window's session (from step 0) to this recording");
  app.add_option("--play", window_play, "Drive the window from a recording (prints its final hash after its last step)");
  app.add_option("--exit-after-frames", window_frames,
                 "Close the window after N frames of a loaded scene (with --play: not before its last step)")
      ->check(CLI::Range(1, 100000000));
  app.add_option("--screenshot", window_screenshot, "Write the last frame as PNG to this path");
  app.add_option("--size", window_size, "Window size WxH")->capture_default_str();

  // divvox voxelize
  VoxelizeArgs vox;
  CLI::App* voxelize = app.add_subcommand(
      "voxelize",
      "Voxelize a mesh, dual-contour its surface and measure it against the input.\n"
      "Writes DIR/report.json (lattice, occupied voxels, per-phase times, surface counts incl. boundary\n"
      "and non-manifold edges, components, enclosed volume, input triangles/volume/watertight, and the\n"
      "two-sided sampled error to the input in voxel units: max, mean, rms) and DIR/surface.ply.\n"
      "With no MESH, the mesh and resolution of the scene (default: assets/scenes/bunny.json).");
  voxelize->add_option("mesh", vox.mesh, "Mesh file (OBJ, PLY, STL, glTF/GLB)");
  voxelize->add_option("--scene", vox.scene, "Scene file whose mesh and resolution to use");
  voxelize->add_option("--resolution,-r", vox.resolution, "Finest voxels along the longest axis (default 128)")
      ->check(CLI::Range(1, kMaxResolution));
  voxelize->add_option("--out,-o", vox.out, "Output folder")->capture_default_str();
  voxelize->add_option("--error-samples", vox.error_samples, "Area samples per side for the error (0: skip)")
      ->capture_default_str();
  voxelize->add_option("--seed", vox.seed, "Seed of the error sampling")->capture_default_str();

  // divvox bench voxelize
  CLI::App* bench = app.add_subcommand("bench", "Benchmarks (CSV + JSON outputs)");
  bench->require_subcommand(1);
  BenchVoxelizeOptions bench_vox;
  bench_vox.out_dir = "out/bench";
  std::string bench_resolutions = "64,128,256";
  CLI::App* bench_voxelize_cmd = bench->add_subcommand(
      "voxelize", "Load + voxelize + contour over meshes and resolutions: per-phase medians, occupied voxels,\n"
                  "model bytes per occupied voxel and peak memory (each configuration in its own process).");
  bench_voxelize_cmd->add_option("--mesh", bench_vox.meshes,
                                 "Mesh file (repeatable; default: bunny, armadillo, liver from ../shared/assets)");
  bench_voxelize_cmd->add_option("--resolutions", bench_resolutions, "Comma-separated resolutions")
      ->capture_default_str();
  bench_voxelize_cmd->add_option("--repeats", bench_vox.repeats, "Runs per configuration (median reported)")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  bench_voxelize_cmd->add_option("--error-samples", bench_vox.error_samples,
                                 "Area samples per side of the error to the input (0: not measured)")
      ->check(CLI::Range(uint64_t(0), uint64_t(100000000)))
      ->capture_default_str();
  bench_voxelize_cmd->add_option("--out,-o", bench_vox.out_dir, "Output folder")->capture_default_str();

  // divvox replay
  ReplayOptions replay_options;
  bool headless = false, no_physics = false;
  CLI::App* replay = app.add_subcommand(
      "replay",
      "Replay a recording (JSON Lines) headlessly: blade poses and grab commands drive the cutter and\n"
      "the PBD model step by step.\n"
      "Writes DIR/summary.json (steps, dt, scene, final_hash, hash_checks, timing_ms per phase with\n"
      "mean/p50/p95/p99/max over cutting steps, cut counts, final surface counts incl. boundary edges and\n"
      "components, mass, nonfinite_values), DIR/timings.csv (one row per step) and DIR/final.ply (deformed).\n"
      "A state hash mismatch with the recording exits 1 naming the first differing step.");
  replay->add_option("recording", replay_options.recording, "Recording file (.jsonl)")->required();
  replay->add_flag("--headless", headless, "Run without a window (the only mode in this build)");
  replay->add_flag("--no-physics", no_physics, "Cut only: no deformation (geometry-only replay)");
  replay->add_option("--workers", replay_options.workers, "Threads for the PBD loops (results do not depend on it)")
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  replay->add_option("--out,-o", replay_options.out_dir, "Output folder")->capture_default_str();
  std::string frame_size = "1280x720", speed = "max";
  replay->add_option("--frames", replay_options.frames_every, "Write DIR/frames/frame_NNNNN.png every N steps (EGL)");
  replay->add_option("--meshes", replay_options.meshes_every,
                     "Write DIR/meshes/mesh_NNNNN.ply every N steps and after the last: the deformed surface in world "
                     "space, binary PLY with a face property `uchar cut` (1 on cut faces)");
  replay->add_option("--size", frame_size, "Frame size WxH")->capture_default_str();
  replay->add_flag("--render", replay_options.render, "Render every step offscreen (frame timings) without writing PNGs");
  replay->add_flag("--wireframe", replay_options.wireframe, "Overlay the triangle edges in frames");
  replay->add_option("--speed", speed, "max (as fast as possible) or realtime (one step per dt)")
      ->check(CLI::IsMember({"max", "realtime"}))
      ->capture_default_str();
  replay->add_option("--record", replay_options.record_path,
                     "Also write the replayed session (poses + state hashes) to this recording");
  replay->add_option("--hash-every", replay_options.hash_every, "With --record: a state hash every N steps")
      ->check(CLI::Range(1u, 1000000u))
      ->capture_default_str();

  // divvox bench cut
  BenchCutOptions bench_cut_options;
  bench_cut_options.out_dir = "out/bench";
  std::string bench_cut_resolutions = "64,128,256";
  CLI::App* bench_cut_cmd = bench->add_subcommand(
      "cut", "The same planar cut across the whole object at several resolutions (paper Fig. 8/10): per-step\n"
             "p50/p99 of divide + surface update, time per newly cut voxel, explicit bytes per divided voxel.");
  bench_cut_cmd->add_option("--mesh", bench_cut_options.mesh, "Mesh file (default: armadillo from ../shared/assets)");
  bench_cut_cmd->add_option("--resolutions", bench_cut_resolutions, "Comma-separated resolutions")
      ->capture_default_str();
  bench_cut_cmd->add_option("--steps", bench_cut_options.steps, "Blade poses across the object")
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
  bench_cut_cmd->add_option("--repeats", bench_cut_options.repeats, "Whole cuts per resolution (median per step)")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  bench_cut_cmd->add_option("--out,-o", bench_cut_options.out_dir, "Output folder")->capture_default_str();

  // divvox bench deform
  BenchDeformOptions bench_deform_options;
  bench_deform_options.out_dir = "out/bench";
  CLI::App* bench_deform_cmd = bench->add_subcommand(
      "deform", "Speed against error of the PBD deformation: simulation resolution x iterations on a liver anchored\n"
                "on one side (and a through-cut copy); plus the per-step time of PBD + embedding on a large surface.");
  bench_deform_cmd->add_option("--mesh", bench_deform_options.mesh, "Mesh (default: liver from ../shared/assets)");
  bench_deform_cmd->add_option("--resolution", bench_deform_options.resolution, "Fine resolution")->capture_default_str();
  bench_deform_cmd->add_option("--sim-resolutions", bench_deform_options.sim_resolutions, "Simulation resolutions")
      ->delimiter(',')
      ->capture_default_str();
  bench_deform_cmd->add_option("--iterations", bench_deform_options.iterations, "Iteration counts")
      ->delimiter(',')
      ->capture_default_str();
  bench_deform_cmd->add_option("--seconds", bench_deform_options.seconds, "Simulated time compared")->capture_default_str();
  bench_deform_cmd->add_option("--workers", bench_deform_options.workers, "Threads")->check(CLI::Range(1, 64))->capture_default_str();
  bench_deform_cmd->add_option("--target-mesh", bench_deform_options.target_mesh, "Mesh of the speed target (default: armadillo)");
  bench_deform_cmd->add_option("--target-resolution", bench_deform_options.target_resolution, "Resolution of the speed target")
      ->capture_default_str();
  bench_deform_cmd->add_option("--out,-o", bench_deform_options.out_dir, "Output folder")->capture_default_str();

  // divvox bench scaling (Experiment 1)
  BenchScalingOptions bench_scaling_options;
  bench_scaling_options.out_dir = "out/bench";
  std::string bench_scaling_resolutions = "64,128,256,512";
  CLI::App* bench_scaling_cmd = bench->add_subcommand(
      "scaling", "Experiment 1 (paper Table 1, Fig. 8): the same cut with physics through each mesh at increasing\n"
                 "resolutions: cut/surface/deform/total ms per cutting step, peak memory, bytes per occupied voxel.");
  bench_scaling_cmd->add_option("--mesh", bench_scaling_options.meshes,
                                "Mesh file (repeatable; default: bunny, armadillo, liver from ../shared/assets)");
  bench_scaling_cmd->add_option("--resolutions", bench_scaling_resolutions, "Comma-separated resolutions")
      ->capture_default_str();
  bench_scaling_cmd->add_option("--sim-resolution", bench_scaling_options.sim_resolution, "Simulation resolution")
      ->check(CLI::Range(1, 4096))
      ->capture_default_str();
  bench_scaling_cmd->add_option("--iterations", bench_scaling_options.iterations, "Solver iterations")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  bench_scaling_cmd->add_option("--workers", bench_scaling_options.workers, "Threads")->check(CLI::Range(1, 64))->capture_default_str();
  bench_scaling_cmd->add_option("--steps", bench_scaling_options.steps, "Blade poses along the path")
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
  bench_scaling_cmd->add_option("--out,-o", bench_scaling_options.out_dir, "Output folder")->capture_default_str();

  // divvox bench cut-length (Experiment 2)
  BenchCutLengthOptions bench_length_options;
  bench_length_options.out_dir = "out/bench";
  CLI::App* bench_length_cmd = bench->add_subcommand(
      "cut-length", "Experiment 2 (paper Fig. 9-10): time against the number of cut voxels, for one-step cuts of\n"
                    "increasing length and for the steps of a progressive cut, with least-squares lines (slope, R^2).");
  bench_length_cmd->add_option("--mesh", bench_length_options.mesh, "Mesh file (default: armadillo)");
  bench_length_cmd->add_option("--resolution", bench_length_options.resolution, "Resolution")
      ->check(CLI::Range(1, kMaxResolution))
      ->capture_default_str();
  bench_length_cmd->add_option("--lengths", bench_length_options.lengths, "Cut lengths (fractions 1/n .. n/n)")
      ->check(CLI::Range(2, 1000))
      ->capture_default_str();
  bench_length_cmd->add_option("--steps", bench_length_options.steps, "Steps of the progressive cut")
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
  bench_length_cmd->add_option("--repeats", bench_length_options.repeats, "Repeats (median)")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  bench_length_cmd->add_option("--out,-o", bench_length_options.out_dir, "Output folder")->capture_default_str();

  // divvox bench quality (Fig. 13)
  BenchQualityOptions bench_quality_options;
  bench_quality_options.out_dir = "out/bench";
  std::string bench_quality_resolutions = "64,128,256";
  CLI::App* bench_quality_cmd = bench->add_subcommand(
      "quality", "Cut-surface mesh quality (paper Fig. 13): min/max angle histograms of the cut faces after a\n"
                 "through-cut by the plane divvox_peers clips with, and the time of that cut (progressive, one step).");
  bench_quality_cmd->add_option("--mesh", bench_quality_options.mesh, "Mesh file (default: armadillo)");
  bench_quality_cmd->add_option("--resolutions", bench_quality_resolutions, "Comma-separated resolutions")
      ->capture_default_str();
  bench_quality_cmd->add_option("--height", bench_quality_options.height, "Cut plane height (fraction of the box)")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  bench_quality_cmd->add_option("--steps", bench_quality_options.steps, "Steps of the progressive cut")
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
  bench_quality_cmd->add_option("--repeats", bench_quality_options.repeats, "Repeats (median)")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  bench_quality_cmd->add_option("--out,-o", bench_quality_options.out_dir, "Output folder")->capture_default_str();

  // divvox bench replay (determinism and throughput)
  BenchReplayOptions bench_replay_options;
  bench_replay_options.out_dir = "out/bench";
  CLI::App* bench_replay_cmd = bench->add_subcommand(
      "replay", "Determinism and throughput: replays recordings with 1 and N workers several times; all final\n"
                "hashes must agree. Reports speed against real time. Exit 1 when replays diverged.");
  bench_replay_cmd->add_option("--recording", bench_replay_options.recordings,
                               "Recording (repeatable; default: the shipped recordings)");
  bench_replay_cmd->add_option("--workers", bench_replay_options.workers, "Threads of the second set of runs")
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  bench_replay_cmd->add_option("--repeats", bench_replay_options.repeats, "Runs per worker count")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  bench_replay_cmd->add_option("--out,-o", bench_replay_options.out_dir, "Output folder")->capture_default_str();

  // divvox bench report
  BenchReportOptions bench_report_options;
  CLI::App* bench_report_cmd = bench->add_subcommand(
      "report", "Writes REPORT.md (and SVG plots beside the results) from the JSON results of the benchmarks above\n"
                "and of divvox_peers. tools/bench_report.sh runs everything and then this.");
  bench_report_cmd->add_option("--results", bench_report_options.results_dir, "Folder of bench_*.json, peers_*.json")
      ->capture_default_str();
  bench_report_cmd->add_option("--out,-o", bench_report_options.report_path, "Report file")->capture_default_str();
  bench_report_cmd->add_option("--mode", bench_report_options.mode, "Mode named in the report")
      ->check(CLI::IsMember({"quick", "full"}))
      ->capture_default_str();

  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "divvox: error: %s (see divvox --help)\n", e.what());
    return kExitBadInput;
  }

  try {
    if (app.get_subcommands().empty()) {
      // A mistyped subcommand reads as a scene path: name both.
      if (!window_scene.empty() && !std::filesystem::exists(window_scene) &&
          window_scene.find_first_of("./") == std::string::npos) {
        throw_input(window_scene, "not a subcommand (voxelize, replay, bench) nor a scene file");
      }
#ifdef DIVVOX_HAS_UI
      WindowOptions window;
      window.scene_path = window_scene.empty() ? default_scene_path() : window_scene;
      window.record_path = window_record;
      window.play_path = window_play;
      window.exit_after_frames = window_frames;
      window.screenshot_path = window_screenshot;
      int w = 0, h = 0;
      char x = 0, extra = 0;
      if (std::sscanf(window_size.c_str(), "%d%c%d%c", &w, &x, &h, &extra) != 3 || (x != 'x' && x != 'X') || w < 16 ||
          h < 16 || w > 8192 || h > 8192) {
        throw_input("--size", "'" + window_size + "' is not WxH with 16 <= W, H <= 8192");
      }
      window.width = w;
      window.height = h;
      if (!window_play.empty() && !window_scene.empty()) {
        throw_input("--play", "the recording holds its own scene; drop " + window_scene);
      }
      return run_window(window);
#else
      std::fprintf(stderr, "divvox: error: this build has no window (GLFW/imgui missing); use a subcommand (see divvox --help)\n");
      return kExitBadInput;
#endif
    }
    if (voxelize->parsed()) return run_voxelize_command(vox);
    if (replay->parsed()) {
      replay_options.physics = !no_physics;
      replay_options.realtime = speed == "realtime";
      {
        int w = 0, h = 0;
        char x = 0, extra = 0;
        if (std::sscanf(frame_size.c_str(), "%d%c%d%c", &w, &x, &h, &extra) != 3 || (x != 'x' && x != 'X') || w < 16 ||
            h < 16 || w > 8192 || h > 8192) {
          throw_input("--size", "'" + frame_size + "' is not WxH with 16 <= W, H <= 8192");
        }
        replay_options.width = w;
        replay_options.height = h;
      }
      replay_options.progress = stderr_is_tty();
      const ReplayResult r = run_replay(replay_options);
      std::printf("replayed %u steps: final hash %s, %u hash checks, %u mismatched\n", r.steps, r.final_hash.c_str(),
                  r.hash_checked, r.hash_mismatched);
      const bool plotted = std::filesystem::exists(std::filesystem::path(replay_options.out_dir) / "timings.svg");
      std::printf("wrote %s, timings.csv, %sfinal.ply in %s\n", r.summary_path.c_str(),
                  plotted ? "timings.svg, timings.png and " : "", replay_options.out_dir.c_str());
      if (r.frames_written > 0) {
        std::printf("wrote %u frames in %s/frames\n", r.frames_written, replay_options.out_dir.c_str());
      }
      if (r.interrupted) {
        std::fprintf(stderr, "divvox: interrupted after %u steps; outputs cover them\n", r.steps);
        return 130;
      }
      if (r.hash_mismatched > 0) {
        std::fprintf(stderr, "divvox: error: %s: replay diverged from the recording at step %lld\n",
                     replay_options.recording.c_str(), static_cast<long long>(r.first_mismatch_step));
        return kExitInternal;
      }
      return kExitOk;
    }
    if (bench_scaling_cmd->parsed()) {
      bench_scaling_options.resolutions = parse_int_list("--resolutions", bench_scaling_resolutions);
      bench_scaling_options.progress = stderr_is_tty();
      std::printf("wrote %s\n", bench_scaling(bench_scaling_options).c_str());
      return kExitOk;
    }
    if (bench_length_cmd->parsed()) {
      bench_length_options.progress = stderr_is_tty();
      std::printf("wrote %s\n", bench_cut_length(bench_length_options).c_str());
      return kExitOk;
    }
    if (bench_quality_cmd->parsed()) {
      bench_quality_options.resolutions = parse_int_list("--resolutions", bench_quality_resolutions);
      bench_quality_options.progress = stderr_is_tty();
      std::printf("wrote %s\n", bench_quality(bench_quality_options).c_str());
      return kExitOk;
    }
    if (bench_replay_cmd->parsed()) {
      bench_replay_options.progress = stderr_is_tty();
      std::printf("wrote %s\n", bench_replay(bench_replay_options).c_str());
      return kExitOk;
    }
    if (bench_report_cmd->parsed()) {
      std::printf("wrote %s\n", bench_report(bench_report_options).c_str());
      return kExitOk;
    }
    if (bench_deform_cmd->parsed()) {
      bench_deform_options.progress = stderr_is_tty();
      std::printf("wrote %s\n", bench_deform(bench_deform_options).c_str());
      return kExitOk;
    }
    if (bench_cut_cmd->parsed()) {
      bench_cut_options.resolutions = parse_int_list("--resolutions", bench_cut_resolutions);
      bench_cut_options.progress = stderr_is_tty();
      std::printf("wrote %s\n", bench_cut(bench_cut_options).c_str());
      return kExitOk;
    }
    if (bench_voxelize_cmd->parsed()) {
      bench_vox.resolutions = parse_int_list("--resolutions", bench_resolutions);
      bench_vox.progress = stderr_is_tty();
      const std::string csv = bench_voxelize(bench_vox);
      std::printf("wrote %s\n", csv.c_str());
      return kExitOk;
    }
  } catch (const InputError& e) {
    std::fprintf(stderr, "divvox: error: %s\n", e.what());
    return kExitBadInput;
  } catch (const std::bad_alloc&) {
    std::fprintf(stderr, "divvox: error: out of memory\n");
    return kExitInternal;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "divvox: internal error: %s\n", e.what());
    return kExitInternal;
  }
  return kExitInternal;
}

}  // namespace dvx
