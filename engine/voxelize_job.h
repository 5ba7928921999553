// The voxelize job: load a mesh, voxelize it, dual-contour the surface, measure it against
// the input. Shared by `divvox voxelize`, `divvox bench voxelize` and the tests.
#pragma once

#include "engine/mesh_io.h"
#include "sim/mesh_distance.h"
#include "sim/surface_metrics.h"
#include "sim/voxel_model.h"

#include <nlohmann/json_fwd.hpp>

#include <cstdint>
#include <string>

namespace dvx {

struct VoxelizeJobOptions {
  std::string mesh_path;
  int resolution = 128;
  uint64_t error_samples = 100000;  // area samples per side for the two-sided error; 0 skips it
  uint64_t seed = 1;
  bool progress = false;            // phase lines on stderr
};

struct VoxelizeJobResult {
  LoadedMesh input;
  double input_volume = 0.0;  // |signed volume| of the input
  bool input_watertight = false;
  VoxelModel model;
  SurfaceMesh surface;
  SurfaceStats stats;
  ErrorStats error;  // in voxel units
  struct {
    double load = 0, voxelize = 0, contour = 0, metrics = 0, error = 0, total = 0;
  } ms;
};

// Refuses (InputError naming `file`, with the estimate) a resolution whose model would not
// fit in memory or cannot be indexed, before anything is allocated.
void check_voxelize_memory(const std::string& file, const Aabb& box, uint64_t triangles, int resolution);

// Runs the job; throws InputError for bad input.
VoxelizeJobResult run_voxelize(const VoxelizeJobOptions& options);

// report.json (DESIGN §1 contract, plus extra fields).
nlohmann::json voxelize_report(const VoxelizeJobOptions& options, const VoxelizeJobResult& result);

}  // namespace dvx
