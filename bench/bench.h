// `divvox bench ...`: benchmarks that write CSV/JSON (never timed unit tests).
#pragma once

#include <nlohmann/json_fwd.hpp>

#include <string>
#include <vector>

namespace dvx {

struct BenchVoxelizeOptions {
  std::vector<std::string> meshes;  // mesh paths; empty: bunny, armadillo, liver from ../shared/assets
  std::vector<int> resolutions = {64, 128, 256};
  int repeats = 3;                  // runs per configuration; medians are reported
  uint64_t error_samples = 100000;  // area samples per side of the error to the input (0: not measured)
  std::string out_dir;
  bool progress = false;
};

// Runs every (mesh, resolution) in a child process (so peak memory is per configuration),
// writes DIR/bench_voxelize.csv and DIR/bench_voxelize.json. Returns the CSV path.
std::string bench_voxelize(const BenchVoxelizeOptions& options);

// Default benchmark meshes: the shared assets that exist, else the shipped bunny.
std::vector<std::string> default_bench_meshes();

}  // namespace dvx

namespace dvx {

struct BenchCutOptions {
  std::string mesh;                 // default: armadillo from ../shared/assets, else the shipped bunny
  std::vector<int> resolutions = {64, 128, 256};
  int steps = 100;                  // blade poses across the object
  int repeats = 3;                  // whole cuts per resolution; per-step medians are reported
  // The cut planes' normal axes (0 x, 1 y, 2 z; cut_pose in bench_common.h), one row each: y is the
  // plane the peers clip with, x and z sweep across the other ways.
  std::vector<int> directions = {0, 1, 2};
  int workers = 2;                  // threads of the surface update (as a session runs it)
  std::string out_dir;
  bool progress = false;
};

// The paper's Fig. 8 / Fig. 10 experiment: the same planar cut (in scene units) across the whole
// object at each resolution and direction, timed per step (divide, surface update). Writes DIR/bench_cut.csv (one
// row per resolution and direction: p50/p99 per step, time per newly cut voxel, explicit bytes per divided voxel),
// DIR/bench_cut_steps.csv (one row per step and resolution) and DIR/bench_cut.json.
std::string bench_cut(const BenchCutOptions& options);

}  // namespace dvx

namespace dvx {

struct BenchDeformOptions {
  std::string mesh;  // default: liver_sofa_smooth from ../shared/assets, else the shipped bunny
  int resolution = 64;
  std::vector<int> sim_resolutions = {8, 16, 32};
  std::vector<int> iterations = {1, 2, 5, 10, 20, 50};
  // Small steps (Macklin et al. 2019) at equal cost: for each budget B, every substeps s > 1 dividing
  // B runs with B / s iterations, next to the iterations sweep (s = 1).
  std::vector<int> substep_budgets = {10};
  double seconds = 2.0;  // simulated time at which the surfaces are compared
  int workers = 2;
  // The speed target: PBD + embedding per step on a large surface.
  std::string target_mesh;  // default: armadillo from ../shared/assets ("" and absent: skipped)
  int target_resolution = 256, target_sim_resolution = 16, target_iterations = 10, target_steps = 120;
  std::string out_dir;
  bool progress = false;
};

// Speed against error of the deformation: sweeps simulation resolution x iterations on a mesh
// anchored on one side under gravity (and on a through-cut copy). Error: relative L2 distance of the
// surface vertices after `seconds` to the most refined, most converged run, divided by the
// reference's mean displacement norm. Writes DIR/bench_deform.csv, bench_deform.svg (step time
// against error) and bench_deform_target.csv (p50/p99 of PBD + embedding per step on the target).
std::string bench_deform(const BenchDeformOptions& options);

}  // namespace dvx

namespace dvx {

// Experiment 1 (paper Table 1, Fig. 8): the same cut path (scene units) through each mesh at
// increasing resolutions, with the physics running: cut, surface, deform and total ms per cutting
// step (p50/p99), peak memory, bytes per occupied voxel, surface triangles. Each (mesh, resolution)
// runs in its own process; a configuration refused for memory becomes a row with that status.
struct BenchScalingOptions {
  std::vector<std::string> meshes;  // default: default_bench_meshes()
  std::vector<int> resolutions = {64, 128, 256, 512};
  int sim_resolution = 16, iterations = 10, workers = 2;
  int steps = 100;  // blade poses along the path
  std::string out_dir;
  bool progress = false;
};
// Writes DIR/bench_scaling.csv and .json; returns the CSV path.
std::string bench_scaling(const BenchScalingOptions& options);

// Experiment 2 (paper Fig. 9-10): at one resolution, cuts of increasing length each made in one step
// on a fresh state, and the per-step samples of a progressive cut: time against cut voxels with a
// least-squares line (slope in microseconds per voxel, R^2).
struct BenchCutLengthOptions {
  std::string mesh;  // default: armadillo
  int resolution = 256;
  int lengths = 10;  // cut lengths 1/n, 2/n, ... n/n of the path
  int steps = 100;   // steps of the progressive cut
  int repeats = 3;
  std::string out_dir;
  bool progress = false;
};
// Writes DIR/bench_cut_length.csv (one row per sample), bench_cut_length.json (with the fits) and
// bench_cut_length.svg; returns the CSV path.
std::string bench_cut_length(const BenchCutLengthOptions& options);

// Mesh quality of the cut surface (paper Fig. 13): min/max angle histograms of the triangles on the
// cut faces after a through-cut by the plane tools/peers clips with (CGAL), the time of the cut made
// progressively and in one step, and the same statistics for the whole surface.
struct BenchQualityOptions {
  std::string mesh;  // default: armadillo
  std::vector<int> resolutions = {64, 128, 256};
  double height = 0.55;  // the cut plane, as a fraction of the box's height
  int steps = 100;
  int repeats = 3;
  std::string out_dir;
  bool progress = false;
};
// Writes DIR/bench_quality.csv and .json; returns the CSV path.
std::string bench_quality(const BenchQualityOptions& options);

// Experiment 6: determinism and throughput of headless replay. Each recording is replayed `repeats`
// times with 1 and with `workers` threads; every run's final hash must agree and every recorded hash
// check must pass. Reports steps per second and the speed against real time.
struct BenchReplayOptions {
  std::vector<std::string> recordings;  // default: the shipped recordings
  int workers = 2;
  int repeats = 3;
  std::string out_dir;
  bool progress = false;
};
// Writes DIR/bench_replay.csv and .json; returns the CSV path. Throws when a replay diverged.
std::string bench_replay(const BenchReplayOptions& options);

// Writes the report: REPORT.md at `report_path` (and its SVG plots beside it) from the JSON results in
// `results_dir` (whichever of bench_*.json and peers_*.json exist there). Returns the report's path.
struct BenchReportOptions {
  std::string results_dir = "bench/results";
  std::string report_path = "bench/REPORT.md";
  std::string mode = "full";  // quick | full: named in the report
};
std::string bench_report(const BenchReportOptions& options);

}  // namespace dvx

namespace dvx {

// The plot of a benchmark's JSON results ("cut_length": time against cut voxels with the fits;
// "deform": step time against error, Pareto front and the scene defaults marked): DIR/bench_NAME.svg
// and .png, drawn by gnuplot. The benchmark draws it when it runs; `bench report` redraws it from the
// JSON. Returns the SVG's file name; "" with `error` when it was not drawn (gnuplot missing).
std::string draw_bench_plot(const nlohmann::json& results, const std::string& dir, std::string& error);

}  // namespace dvx
