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
