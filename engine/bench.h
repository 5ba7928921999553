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
