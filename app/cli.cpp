#include "app/cli.h"

#include "engine/errors.h"
#include "engine/mesh_io.h"
#include "engine/options.h"
#include "engine/output.h"
#include "engine/resources.h"
#include "engine/scene.h"
#include "engine/voxelize_job.h"
#include "harness/replay_outputs.h"

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <string>
#include <utility>

namespace dvx {
namespace {

constexpr const char* kDefaultScene = "assets/scenes/bunny.json";
// The window opens the liver on its tray (the headless jobs keep the bunny).
constexpr const char* kDefaultWindowScene = "assets/scenes/liver.json";

// The default scene: relative to the working directory, else to the source tree.
std::string default_scene_path(const char* scene = kDefaultScene) {
  if (std::filesystem::exists(scene)) return scene;
  return (std::filesystem::path(DIVVOX_SOURCE_DIR_DEFAULT) / scene).string();
}

// Flags parsed as text and turned into typed options after parsing (parse_size, parse_int_list,
// the replay's switches).
struct RawFlags {
  std::string window_size = "1280x720";
  std::string frame_size = "1280x720", speed = "max";
  bool headless = false, no_physics = false;
  std::string bench_voxelize_resolutions = "64,128,256", bench_cut_resolutions = "64,128,256";
  std::string bench_scaling_resolutions = "64,128,256,512", bench_quality_resolutions = "64,128,256";
  std::string bench_cut_directions = "x,y,z";
};

// A comma-separated list of axes (x, y, z) as 0, 1, 2, in the order given; repeats are refused.
std::vector<int> parse_axis_list(const std::string& flag, const std::string& text) {
  std::vector<int> axes;
  size_t start = 0;
  while (start <= text.size()) {
    const size_t end = std::min(text.find(',', start), text.size());
    const std::string item = text.substr(start, end - start);
    const int axis = item == "x" ? 0 : item == "y" ? 1 : item == "z" ? 2 : -1;
    if (axis < 0) throw_input(flag, "'" + item + "' is not one of x, y, z");
    if (std::find(axes.begin(), axes.end(), axis) != axes.end()) throw_input(flag, "'" + item + "' is given twice");
    axes.push_back(axis);
    start = end + 1;
  }
  return axes;
}

// The subcommands, to tell which one was parsed.
struct Subcommands {
  CLI::App *voxelize = nullptr, *replay = nullptr;
  CLI::App *bench_voxelize = nullptr, *bench_cut = nullptr, *bench_deform = nullptr, *bench_elastic = nullptr, *bench_scaling = nullptr,
           *bench_cut_length = nullptr, *bench_quality = nullptr, *bench_replay = nullptr, *bench_report = nullptr,
           *bench_contact = nullptr;
};

// divvox [SCENE.json]: the window (no subcommand).
void add_window(CLI::App& app, CliCommand& c, RawFlags& raw) {
  WindowOptions& w = c.window;
  app.add_option("scene", w.scene_path, "Scene to open in the window (default: assets/scenes/liver.json)");
  app.add_option("--record", w.record_path, "Record the window's session (from step 0) to this recording");
  app.add_option("--play", w.play_path, "Drive the window from a recording (prints its final hash after its last step)");
  app.add_option("--exit-after-frames", w.exit_after_frames,
                 "Close the window after N frames of a loaded scene (with --play: not before its last step)")
      ->check(CLI::Range(1, 100000000));
  app.add_option("--screenshot", w.screenshot_path, "Write the last frame as PNG to this path");
  app.add_option("--size", raw.window_size, "Window size WxH")->capture_default_str();
}

// divvox voxelize
CLI::App* add_voxelize(CLI::App& app, VoxelizeArgs& vox) {
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
  return voxelize;
}

// divvox replay
CLI::App* add_replay(CLI::App& app, ReplayOptions& o, RawFlags& raw) {
  CLI::App* replay = app.add_subcommand(
      "replay",
      "Replay a recording (JSON Lines) headlessly: blade poses and grab commands drive the cutter and\n"
      "the PBD model step by step.\n"
      "Writes DIR/summary.json (steps, dt, scene, final_hash, hash_checks, timing_ms per phase with\n"
      "mean/p50/p95/p99/max over cutting steps, cut counts, final surface counts incl. boundary edges and\n"
      "components, mass, nonfinite_values), DIR/timings.csv (one row per step) and DIR/final.ply (deformed).\n"
      "A state hash mismatch with the recording exits 1 naming the first differing step.");
  replay->add_option("recording", o.recording, "Recording file (.jsonl)")->required();
  replay->add_flag("--headless", raw.headless, "Run without a window (the only mode in this build)");
  replay->add_flag("--no-physics", raw.no_physics, "Cut only: no deformation (geometry-only replay)");
  replay->add_option("--workers", o.workers, "Threads for the PBD loops (results do not depend on it)")
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  replay->add_option("--out,-o", o.out_dir, "Output folder")->capture_default_str();
  replay->add_option("--frames", o.frames_every, "Write DIR/frames/frame_NNNNN.png every N steps (EGL)");
  replay->add_option("--meshes", o.meshes_every,
                     "Write DIR/meshes/mesh_NNNNN.ply every N steps and after the last: the deformed surface in world "
                     "space, binary PLY with a face property `uchar cut` (1 on cut faces)");
  replay->add_option("--size", raw.frame_size, "Frame size WxH")->capture_default_str();
  replay->add_flag("--render", o.render, "Render every step offscreen (frame timings) without writing PNGs");
  replay->add_flag("--wireframe", o.wireframe, "Overlay the triangle edges in frames");
  replay->add_option("--speed", raw.speed, "max (as fast as possible) or realtime (one step per dt)")
      ->check(CLI::IsMember({"max", "realtime"}))
      ->capture_default_str();
  replay->add_option("--record", o.record_path, "Also write the replayed session (poses + state hashes) to this recording");
  replay->add_option("--hash-every", o.hash_every, "With --record: a state hash every N steps")
      ->check(CLI::Range(1u, 1000000u))
      ->capture_default_str();
  return replay;
}

// divvox bench voxelize, cut, deform
void add_bench_geometry(CLI::App& bench, CliCommand& c, RawFlags& raw, Subcommands& sub) {
  BenchVoxelizeOptions& v = c.bench_voxelize;
  sub.bench_voxelize = bench.add_subcommand(
      "voxelize", "Load + voxelize + contour over meshes and resolutions: per-phase medians, occupied voxels,\n"
                  "model bytes per occupied voxel and peak memory (each configuration in its own process).");
  sub.bench_voxelize->add_option("--mesh", v.meshes, "Mesh file (repeatable; default: bunny, armadillo, liver from ../shared/assets)");
  sub.bench_voxelize->add_option("--resolutions", raw.bench_voxelize_resolutions, "Comma-separated resolutions")
      ->capture_default_str();
  sub.bench_voxelize->add_option("--repeats", v.repeats, "Runs per configuration (median reported)")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  sub.bench_voxelize->add_option("--error-samples", v.error_samples, "Area samples per side of the error to the input (0: not measured)")
      ->check(CLI::Range(uint64_t(0), uint64_t(100000000)))
      ->capture_default_str();
  sub.bench_voxelize->add_option("--out,-o", v.out_dir, "Output folder")->capture_default_str();

  BenchCutOptions& k = c.bench_cut;
  sub.bench_cut = bench.add_subcommand(
      "cut", "The same planar cut across the whole object at several resolutions (paper Fig. 8/10): per-step\n"
             "p50/p99 of divide + surface update, time per newly cut voxel, explicit bytes per divided voxel.");
  sub.bench_cut->add_option("--mesh", k.mesh, "Mesh file (default: armadillo from ../shared/assets)");
  sub.bench_cut->add_option("--resolutions", raw.bench_cut_resolutions, "Comma-separated resolutions")->capture_default_str();
  sub.bench_cut->add_option("--directions", raw.bench_cut_directions,
                            "Comma-separated normal axes of the cut planes (x, y, z; y: the plane the peers clip with)")
      ->capture_default_str();
  sub.bench_cut->add_option("--steps", k.steps, "Blade poses across the object")->check(CLI::Range(1, 100000))->capture_default_str();
  sub.bench_cut->add_option("--repeats", k.repeats, "Whole cuts per resolution (median per step)")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  sub.bench_cut->add_option("--workers", k.workers, "Threads of the surface update")->check(CLI::Range(1, 64))->capture_default_str();
  sub.bench_cut->add_option("--out,-o", k.out_dir, "Output folder")->capture_default_str();

  BenchDeformOptions& d = c.bench_deform;
  sub.bench_deform = bench.add_subcommand(
      "deform", "Speed against a self-referenced error of the PBD deformation (the error is the distance to the same\n"
                "solver's most refined run, not to physics: see `bench elastic`): simulation resolution x iterations on a\n"
                "liver anchored on one side (and a through-cut copy); plus the per-step time of PBD + embedding on a large surface.");
  sub.bench_deform->add_option("--mesh", d.mesh, "Mesh (default: liver from ../shared/assets)");
  sub.bench_deform->add_option("--resolution", d.resolution, "Fine resolution")->capture_default_str();
  sub.bench_deform->add_option("--sim-resolutions", d.sim_resolutions, "Simulation resolutions")->delimiter(',')->capture_default_str();
  sub.bench_deform->add_option("--iterations", d.iterations, "Iteration counts")->delimiter(',')->capture_default_str();
  sub.bench_deform->add_option("--substep-budgets", d.substep_budgets, "Substeps x iterations budgets of the small-steps sweep")
      ->delimiter(',')
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  sub.bench_deform->add_option("--seconds", d.seconds, "Simulated time compared")->capture_default_str();
  sub.bench_deform->add_option("--workers", d.workers, "Threads")->check(CLI::Range(1, 64))->capture_default_str();
  sub.bench_deform->add_option("--target-mesh", d.target_mesh, "Mesh of the speed target (default: armadillo)");
  sub.bench_deform->add_option("--target-resolution", d.target_resolution, "Resolution of the speed target")->capture_default_str();
  sub.bench_deform->add_option("--out,-o", d.out_dir, "Output folder")->capture_default_str();

  BenchElasticOptions& e = c.bench_elastic;
  sub.bench_elastic = bench.add_subcommand(
      "elastic", "Speed against error, for real: divvox's elasticity against CalculiX (ccx, Debian calculix-ccx) on the\n"
                 "same geometry, anchors, gravity and material, over models x simulation resolution x substeps x\n"
                 "iterations. Cases: cantilever (small strain), soft_bar (NLGEOM), cube, liver (0.2 m, E 5.4 kPa),\n"
                 "bar_cut_half, bar_cut_through; plus the cantilever's first frequency against Euler-Bernoulli.\n"
                 "Writes DIR/bench_elastic.csv, .json and .svg/.png (Pareto front, shipped and chosen settings marked).");
  sub.bench_elastic->add_option("--cases", e.cases, "Cases (default: all)")->delimiter(',')
      ->check(CLI::IsMember(elastic_case_names()));
  sub.bench_elastic->add_option("--sweep-cases", e.sweep_cases, "Cases swept over substeps x iterations (the others: shipped solver only)")
      ->delimiter(',')->check(CLI::IsMember(elastic_case_names()))->capture_default_str();
  sub.bench_elastic->add_option("--models", e.models, "Elastic models")->delimiter(',')
      ->check(CLI::IsMember({"neo_hookean", "global", "paper"}))->capture_default_str();
  sub.bench_elastic->add_option("--sim-resolutions", e.sim_resolutions, "Simulation resolutions")->delimiter(',')
      ->check(CLI::Range(1, 1024))->capture_default_str();
  sub.bench_elastic->add_option("--substeps", e.substeps, "Substeps")->delimiter(',')->check(CLI::Range(1, 1000))->capture_default_str();
  sub.bench_elastic->add_option("--iterations", e.iterations, "Iterations")->delimiter(',')->check(CLI::Range(1, 10000))->capture_default_str();
  sub.bench_elastic->add_option("--resolution", e.resolution, "Fine resolution of every case (0: each case's, 64; cube 32)")
      ->check(CLI::Range(0, 1024))->capture_default_str();
  sub.bench_elastic->add_option("--ref-scale", e.ref_scale, "Reference cells per axis x this")->check(CLI::Range(0.25, 8.0))->capture_default_str();
  sub.bench_elastic->add_option("--ccx-timeout", e.ccx_timeout, "Seconds each CalculiX solve may run")
      ->check(CLI::Range(1.0, 86400.0))->capture_default_str();
  sub.bench_elastic->add_option("--workers", e.workers, "Threads")->check(CLI::Range(1, 64))->capture_default_str();
  sub.bench_elastic->add_option("--keep-ccx", e.keep_ccx, "Keep each case's CalculiX deck, .dat and log in DIR/CASE");
  sub.bench_elastic->add_option("--out,-o", e.out_dir, "Output folder")->capture_default_str();
}

// divvox bench scaling, cut-length, quality (the paper's experiments 1, 2 and Fig. 13)
void add_bench_paper(CLI::App& bench, CliCommand& c, RawFlags& raw, Subcommands& sub) {
  BenchScalingOptions& s = c.bench_scaling;
  sub.bench_scaling = bench.add_subcommand(
      "scaling", "Experiment 1 (paper Table 1, Fig. 8): the same cut with physics through each mesh at increasing\n"
                 "resolutions: cut/surface/deform/total ms per cutting step, peak memory, bytes per occupied voxel.");
  sub.bench_scaling->add_option("--mesh", s.meshes, "Mesh file (repeatable; default: bunny, armadillo, liver from ../shared/assets)");
  sub.bench_scaling->add_option("--resolutions", raw.bench_scaling_resolutions, "Comma-separated resolutions")->capture_default_str();
  sub.bench_scaling->add_option("--sim-resolution", s.sim_resolution, "Simulation resolution")
      ->check(CLI::Range(1, 4096))
      ->capture_default_str();
  sub.bench_scaling->add_option("--iterations", s.iterations, "Solver iterations")->check(CLI::Range(1, 1000))->capture_default_str();
  sub.bench_scaling->add_option("--workers", s.workers, "Threads")->check(CLI::Range(1, 64))->capture_default_str();
  sub.bench_scaling->add_option("--steps", s.steps, "Blade poses along the path")->check(CLI::Range(1, 100000))->capture_default_str();
  sub.bench_scaling->add_option("--out,-o", s.out_dir, "Output folder")->capture_default_str();

  BenchCutLengthOptions& l = c.bench_cut_length;
  sub.bench_cut_length = bench.add_subcommand(
      "cut-length", "Experiment 2 (paper Fig. 9-10): time against the number of cut voxels, for one-step cuts of\n"
                    "increasing length and for the steps of a progressive cut, with least-squares lines (slope, R^2).");
  sub.bench_cut_length->add_option("--mesh", l.mesh, "Mesh file (default: armadillo)");
  sub.bench_cut_length->add_option("--resolution", l.resolution, "Resolution")->check(CLI::Range(1, kMaxResolution))->capture_default_str();
  sub.bench_cut_length->add_option("--lengths", l.lengths, "Cut lengths (fractions 1/n .. n/n)")->check(CLI::Range(2, 1000))->capture_default_str();
  sub.bench_cut_length->add_option("--steps", l.steps, "Steps of the progressive cut")->check(CLI::Range(1, 100000))->capture_default_str();
  sub.bench_cut_length->add_option("--repeats", l.repeats, "Repeats (median)")->check(CLI::Range(1, 1000))->capture_default_str();
  sub.bench_cut_length->add_option("--out,-o", l.out_dir, "Output folder")->capture_default_str();

  BenchQualityOptions& q = c.bench_quality;
  sub.bench_quality = bench.add_subcommand(
      "quality", "Cut-surface mesh quality (paper Fig. 13): min/max angle histograms of the cut faces after a\n"
                 "through-cut by the plane divvox_peers clips with, and the time of that cut (progressive, one step).");
  sub.bench_quality->add_option("--mesh", q.mesh, "Mesh file (default: armadillo)");
  sub.bench_quality->add_option("--resolutions", raw.bench_quality_resolutions, "Comma-separated resolutions")->capture_default_str();
  sub.bench_quality->add_option("--height", q.height, "Cut plane height (fraction of the box)")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  sub.bench_quality->add_option("--steps", q.steps, "Steps of the progressive cut")->check(CLI::Range(1, 100000))->capture_default_str();
  sub.bench_quality->add_option("--repeats", q.repeats, "Repeats (median)")->check(CLI::Range(1, 1000))->capture_default_str();
  sub.bench_quality->add_option("--out,-o", q.out_dir, "Output folder")->capture_default_str();
}

// divvox bench replay, report
void add_bench_replay_report(CLI::App& bench, CliCommand& c, Subcommands& sub) {
  BenchReplayOptions& r = c.bench_replay;
  sub.bench_replay = bench.add_subcommand(
      "replay", "Determinism and throughput: replays recordings with 1 and N workers several times; all final\n"
                "hashes must agree. Reports speed against real time. Exit 1 when replays diverged.");
  sub.bench_replay->add_option("--recording", r.recordings, "Recording (repeatable; default: the shipped recordings)");
  sub.bench_replay->add_option("--workers", r.workers, "Threads of the second set of runs")->check(CLI::Range(1, 64))->capture_default_str();
  sub.bench_replay->add_option("--repeats", r.repeats, "Runs per worker count")->check(CLI::Range(1, 1000))->capture_default_str();
  sub.bench_replay->add_option("--out,-o", r.out_dir, "Output folder")->capture_default_str();

  BenchContactOptions& k = c.bench_contact;
  sub.bench_contact = bench.add_subcommand(
      "contact", "Contact cost: deform step time (p50/p99) with and without contact on the default recording and on\n"
                 "the liver scene cut through, and the contacts solved per step.");
  sub.bench_contact->add_option("--recording", k.recording, "Recording (default: assets/recordings/bunny_cut.jsonl)");
  sub.bench_contact->add_option("--liver-scene", k.liver_scene, "Liver scene (default: assets/scenes/liver.json)");
  sub.bench_contact->add_option("--liver-resolution", k.liver_resolution, "Override the liver scene's resolution (0: keep)")
      ->check(CLI::Range(0, kMaxResolution))->capture_default_str();
  sub.bench_contact->add_option("--liver-cut-steps", k.liver_cut_steps, "Steps of the liver's cut")->check(CLI::Range(0, 100000))->capture_default_str();
  sub.bench_contact->add_option("--liver-rest-steps", k.liver_rest_steps, "Steps after it (cut + rest = 0: no liver)")
      ->check(CLI::Range(0, 100000))->capture_default_str();
  sub.bench_contact->add_option("--sever-scene", k.sever_scene, "Scene sliced for the sever steps (default: assets/scenes/bunny.json)");
  sub.bench_contact->add_option("--sever-resolution", k.sever_resolution,
                                "Resolution of the scene sliced for the sever steps (0: skipped)")
      ->check(CLI::Range(0, kMaxResolution))
      ->capture_default_str();
  sub.bench_contact->add_option("--sever-strokes", k.sever_strokes, "Vertical through-cuts of the sliced liver")
      ->check(CLI::Range(0, 8))
      ->capture_default_str();
  sub.bench_contact->add_option("--sever-stroke-steps", k.sever_stroke_steps, "Steps of each such stroke")
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
  sub.bench_contact->add_option("--sever-rest-steps", k.sever_rest_steps, "Steps at rest after each stroke")
      ->check(CLI::Range(0, 100000))
      ->capture_default_str();
  sub.bench_contact->add_option("--workers", k.workers, "Threads")->check(CLI::Range(1, 64))->capture_default_str();
  sub.bench_contact->add_option("--out,-o", k.out_dir, "Output folder")->capture_default_str();

  BenchReportOptions& p = c.bench_report;
  sub.bench_report = bench.add_subcommand(
      "report", "Writes REPORT.md (and SVG plots beside the results) from the JSON results of the benchmarks above\n"
                "and of divvox_peers. tools/bench_report.sh runs everything and then this.");
  sub.bench_report->add_option("--results", p.results_dir, "Folder of bench_*.json, peers_*.json")->capture_default_str();
  sub.bench_report->add_option("--out,-o", p.report_path, "Report file")->capture_default_str();
  sub.bench_report->add_option("--mode", p.mode, "Mode named in the report")
      ->check(CLI::IsMember({"quick", "full"}))
      ->capture_default_str();
}

// Which command was parsed, with the options CLI11 could not type turned into theirs.
void finish_parse(const Subcommands& sub, const RawFlags& raw, CliCommand& c) {
  // Typed for every command (the defaults are valid): only the parsed one runs.
  for (bool* progress : {&c.replay.progress, &c.bench_voxelize.progress, &c.bench_cut.progress,
                         &c.bench_deform.progress, &c.bench_elastic.progress, &c.bench_scaling.progress, &c.bench_cut_length.progress,
                         &c.bench_quality.progress, &c.bench_replay.progress, &c.bench_contact.progress}) {
    *progress = stderr_is_tty();
  }
  c.bench_voxelize.resolutions = parse_int_list("--resolutions", raw.bench_voxelize_resolutions, 1, kMaxResolution);
  c.bench_cut.resolutions = parse_int_list("--resolutions", raw.bench_cut_resolutions, 1, kMaxResolution);
  c.bench_cut.directions = parse_axis_list("--directions", raw.bench_cut_directions);
  c.bench_scaling.resolutions = parse_int_list("--resolutions", raw.bench_scaling_resolutions, 1, kMaxResolution);
  c.bench_quality.resolutions = parse_int_list("--resolutions", raw.bench_quality_resolutions, 1, kMaxResolution);
  c.replay.physics = !raw.no_physics;
  c.replay.realtime = raw.speed == "realtime";

  const std::pair<const CLI::App*, CliCommand::Kind> commands[] = {
      {sub.voxelize, CliCommand::kVoxelize},           {sub.replay, CliCommand::kReplay},
      {sub.bench_voxelize, CliCommand::kBenchVoxelize}, {sub.bench_cut, CliCommand::kBenchCut},
      {sub.bench_deform, CliCommand::kBenchDeform},     {sub.bench_elastic, CliCommand::kBenchElastic},     {sub.bench_scaling, CliCommand::kBenchScaling},
      {sub.bench_cut_length, CliCommand::kBenchCutLength}, {sub.bench_quality, CliCommand::kBenchQuality},
      {sub.bench_replay, CliCommand::kBenchReplay},     {sub.bench_contact, CliCommand::kBenchContact},     {sub.bench_report, CliCommand::kBenchReport}};
  c.kind = CliCommand::kWindow;  // no subcommand
  for (const auto& [command, kind] : commands) {
    if (command->parsed()) c.kind = kind;
  }
  if (c.kind == CliCommand::kReplay) parse_size("--size", raw.frame_size, c.replay.width, c.replay.height);
  if (c.kind != CliCommand::kWindow) return;

  // The window. A mistyped subcommand reads as a scene path: name both.
  WindowOptions& w = c.window;
  if (!w.scene_path.empty() && !std::filesystem::exists(w.scene_path) &&
      w.scene_path.find_first_of("./") == std::string::npos) {
    throw_input(w.scene_path, "not a subcommand (voxelize, replay, bench) nor a scene file");
  }
  parse_size("--size", raw.window_size, w.width, w.height);
  if (!w.play_path.empty() && !w.scene_path.empty()) {
    throw_input("--play", "the recording holds its own scene; drop " + w.scene_path);
  }
  if (w.scene_path.empty()) w.scene_path = default_scene_path(kDefaultWindowScene);
}

// `divvox voxelize`: the job, its two files and a summary on stdout.
int run_voxelize_command(const VoxelizeArgs& args) {
  VoxelizeJobOptions options;
  options.error_samples = args.error_samples;
  options.seed = args.seed;
  options.progress = stderr_is_tty();
  options.resolution = 128;
  if (!args.scene.empty() || args.mesh.empty()) {
    const Scene scene = load_scene(args.scene.empty() ? default_scene_path() : args.scene);
    options.mesh_path = scene.mesh_path;
    options.resolution = scene.pbd.resolution;
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

// `divvox replay`: the replay and what it found; exit 1 when it diverged from the recording.
int run_replay_command(const ReplayOptions& options) {
  const ReplayResult r = run_replay(options);
  std::printf("replayed %u steps: final hash %s, %u hash checks, %u mismatched\n", r.steps, r.final_hash.c_str(),
              r.hash_checked, r.hash_mismatched);
  const bool plotted = std::filesystem::exists(std::filesystem::path(options.out_dir) / "timings.svg");
  std::printf("wrote %s, timings.csv, %sfinal.ply in %s\n", r.summary_path.c_str(),
              plotted ? "timings.svg, timings.png and " : "", options.out_dir.c_str());
  if (r.frames_written > 0) std::printf("wrote %u frames in %s/frames\n", r.frames_written, options.out_dir.c_str());
  if (r.interrupted) {
    std::fprintf(stderr, "divvox: interrupted after %u steps; outputs cover them\n", r.steps);
    return 130;
  }
  if (r.hash_mismatched > 0) {
    std::fprintf(stderr, "divvox: error: %s: replay diverged from the recording at step %lld\n",
                 options.recording.c_str(), static_cast<long long>(r.first_mismatch_step));
    return kExitInternal;
  }
  return kExitOk;
}

// The window, when this build has one.
int run_window_command(const WindowOptions& options) {
#ifdef DIVVOX_HAS_UI
  return run_window(options);
#else
  (void)options;
  std::fprintf(stderr, "divvox: error: this build has no window (GLFW/imgui missing); use a subcommand (see divvox --help)\n");
  return kExitBadInput;
#endif
}

// Names the file a benchmark wrote.
int wrote(const std::string& path) {
  std::printf("wrote %s\n", path.c_str());
  return kExitOk;
}

}  // namespace

void parse_size(const std::string& flag, const std::string& text, int& width, int& height) {
  int w = 0, h = 0;
  char x = 0, extra = 0;
  if (std::sscanf(text.c_str(), "%d%c%d%c", &w, &x, &h, &extra) != 3 || (x != 'x' && x != 'X') || w < 16 || h < 16 ||
      w > 8192 || h > 8192) {
    throw_input(flag, "'" + text + "' is not WxH with 16 <= W, H <= 8192");
  }
  width = w;
  height = h;
}

CliCommand parse_cli(int argc, char** argv) {
  CliCommand c;
  for (std::string* out : {&c.bench_voxelize.out_dir, &c.bench_cut.out_dir, &c.bench_deform.out_dir, &c.bench_elastic.out_dir,
                           &c.bench_scaling.out_dir, &c.bench_cut_length.out_dir, &c.bench_quality.out_dir,
                           &c.bench_replay.out_dir, &c.bench_contact.out_dir}) {
    *out = "out/bench";
  }
  RawFlags raw;
  Subcommands sub;
  CLI::App app{"divvox: interactive cutting of deformable objects with Divided Voxels"};
  app.require_subcommand(0, 1);  // none: the interactive window
  app.set_version_flag("--version", "divvox 0.1.0");
  app.footer("Exit codes: 0 success, 2 bad input (file, flag or value), 1 internal failure.");
  add_window(app, c, raw);
  sub.voxelize = add_voxelize(app, c.voxelize);
  CLI::App* bench = app.add_subcommand("bench", "Benchmarks (CSV + JSON outputs)");
  bench->require_subcommand(1);
  add_bench_geometry(*bench, c, raw, sub);
  sub.replay = add_replay(app, c.replay, raw);
  add_bench_paper(*bench, c, raw, sub);
  add_bench_replay_report(*bench, c, sub);

  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    c.exit_code = app.exit(e);
    return c;
  } catch (const CLI::CallForAllHelp& e) {
    c.exit_code = app.exit(e);
    return c;
  } catch (const CLI::CallForVersion& e) {
    c.exit_code = app.exit(e);
    return c;
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "divvox: error: %s (see divvox --help)\n", e.what());
    c.exit_code = kExitBadInput;
    return c;
  }
  finish_parse(sub, raw, c);
  return c;
}

int run_command(const CliCommand& c) {
  switch (c.kind) {
    case CliCommand::kExit: return c.exit_code;
    case CliCommand::kWindow: return run_window_command(c.window);
    case CliCommand::kVoxelize: return run_voxelize_command(c.voxelize);
    case CliCommand::kReplay: return run_replay_command(c.replay);
    case CliCommand::kBenchVoxelize: return wrote(bench_voxelize(c.bench_voxelize));
    case CliCommand::kBenchCut: return wrote(bench_cut(c.bench_cut));
    case CliCommand::kBenchDeform: return wrote(bench_deform(c.bench_deform));
    case CliCommand::kBenchElastic: return wrote(bench_elastic(c.bench_elastic));
    case CliCommand::kBenchScaling: return wrote(bench_scaling(c.bench_scaling));
    case CliCommand::kBenchCutLength: return wrote(bench_cut_length(c.bench_cut_length));
    case CliCommand::kBenchQuality: return wrote(bench_quality(c.bench_quality));
    case CliCommand::kBenchReplay: return wrote(bench_replay(c.bench_replay));
    case CliCommand::kBenchContact: return wrote(bench_contact(c.bench_contact));
    case CliCommand::kBenchReport: return wrote(bench_report(c.bench_report));
  }
  return kExitInternal;
}

int run_cli(int argc, char** argv) {
  try {
    read_env_options();  // a malformed DIVVOX_* switch exits 2 before any work (nothing is lost later)
    return run_command(parse_cli(argc, argv));
  } catch (...) {
    return exit_for_current_exception("divvox");
  }
}

}  // namespace dvx
