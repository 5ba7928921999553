// `divvox bench ...`: benchmarks that write CSV/JSON (never timed unit tests).
#pragma once

#include <string>
#include <vector>

namespace dvx {

struct BenchVoxelizeOptions {
  std::vector<std::string> meshes;  // mesh paths; empty: bunny, armadillo, liver from ../shared/assets
  std::vector<int> resolutions = {64, 128, 256};
  int repeats = 3;                  // runs per configuration; medians are reported
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
  std::string out_dir;
  bool progress = false;
};

// The paper's Fig. 8 / Fig. 10 experiment: the same planar cut (in scene units) across the whole
// object at each resolution, timed per step (divide, surface update). Writes DIR/bench_cut.csv (one
// row per resolution: p50/p99 per step, time per newly cut voxel, explicit bytes per divided voxel),
// DIR/bench_cut_steps.csv (one row per step and resolution) and DIR/bench_cut.json.
std::string bench_cut(const BenchCutOptions& options);

}  // namespace dvx

namespace dvx {

struct BenchDeformOptions {
  std::string mesh;  // default: liver_sofa_smooth from ../shared/assets, else the shipped bunny
  int resolution = 64;
  std::vector<int> sim_resolutions = {8, 16, 32};
  std::vector<int> iterations = {1, 2, 5, 10, 20, 50};
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
