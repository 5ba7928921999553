#include "engine/voxelize_job.h"
#include "engine/options.h"

#include "engine/errors.h"
#include "engine/resources.h"
#include "engine/scene.h"
#include "engine/stats.h"
#include "engine/timing.h"
#include "sim/contour.h"
#include "sim/voxelize.h"

#include <nlohmann/json.hpp>

#include <chrono>
#include <cstdio>
#include <cctype>
#include <cstdlib>
#include <limits>

namespace dvx {
void check_voxelize_memory(const std::string& file, const Aabb& box, uint64_t triangles, int resolution) {
  if (resolution < 1 || resolution > kMaxResolution) {
    throw_input(file, "resolution " + std::to_string(resolution) + " is outside [1, " +
                          std::to_string(kMaxResolution) + "]");
  }
  VoxelizeParams params;
  params.resolution = resolution;
  const uint64_t estimate = estimate_voxelize_bytes(box, triangles, params);
  if (estimate == std::numeric_limits<uint64_t>::max()) {
    Lattice lattice;
    make_lattice(box, resolution, params.padding, lattice);
    throw_input(file, "resolution " + std::to_string(resolution) + " needs a lattice of " +
                          std::to_string(lattice.node_count()) + " nodes, more than the " +
                          std::to_string(kMaxLatticeNodes) + " that 32-bit edge ids allow; use a lower resolution");
  }
  // The surface and the error measurement roughly double the peak of voxelization.
  const uint64_t needed = estimate + estimate / 2;
  // Budget: 80 % of the memory available now, or DIVVOX_MEMORY_LIMIT (bytes, or with a K/M/G suffix).
  uint64_t budget = available_memory_bytes() / 10 * 8;
  std::string budget_name = "80% of available memory";
  if (const uint64_t limit = read_env_options().memory_limit; limit != 0) {
    budget = limit;
    budget_name = "DIVVOX_MEMORY_LIMIT";
  }
  if (budget != 0 && needed > budget) {
    throw_input(file, "resolution " + std::to_string(resolution) + " needs about " + format_bytes(needed) +
                          " but the budget is " + format_bytes(budget) + " (" + budget_name +
                          "); use a lower resolution");
  }
}

VoxelizeJobResult run_voxelize(const VoxelizeJobOptions& options) {
  VoxelizeJobResult result;
  const Clock::time_point start = Clock::now();

  // Load and validate the input.
  Clock::time_point t = Clock::now();
  result.input = load_mesh(options.mesh_path, options.progress);
  result.ms.load = ms_between(t, Clock::now());
  const Aabb box = mesh_bounds(result.input.mesh);
  check_voxelize_memory(options.mesh_path, box, result.input.mesh.triangles.size(), options.resolution);

  // Signs and Hermite data.
  progress_line(options.progress, "voxelizing");
  t = Clock::now();
  VoxelizeParams params;
  params.resolution = options.resolution;
  std::string error;
  if (!voxelize(result.input.mesh, params, result.model, error)) throw_input(options.mesh_path, error);
  result.ms.voxelize = ms_between(t, Clock::now());
  if (result.model.occupied_voxels == 0 || result.model.crossings.empty()) {
    throw_input(options.mesh_path, "no lattice node lies inside the mesh at resolution " +
                                       std::to_string(options.resolution) +
                                       " (is it closed, or thinner than a voxel?)");
  }

  // Surface.
  progress_line(options.progress, "dual contouring");
  t = Clock::now();
  result.surface = dual_contour(result.model);
  result.ms.contour = ms_between(t, Clock::now());

  // Checks of the surface and of the input.
  t = Clock::now();
  result.stats = surface_stats(result.surface);
  result.input_volume = std::abs(signed_volume(result.input.mesh));
  result.input_watertight = is_watertight(result.input.mesh);
  result.ms.metrics = ms_between(t, Clock::now());

  // Two-sided sampled error, in voxel units.
  if (options.error_samples > 0) {
    progress_line(options.progress, "measuring error to the input");
    t = Clock::now();
    const ErrorStats e = two_sided_error(to_trimesh(result.surface), result.input.mesh, options.error_samples,
                                         options.seed);
    const double h = result.model.lattice.voxel_size;
    result.error = {e.max / h, e.mean / h, e.rms / h, e.samples};
    result.ms.error = ms_between(t, Clock::now());
  }
  result.ms.total = ms_between(start, Clock::now());
  return result;
}

nlohmann::json voxelize_report(const VoxelizeJobOptions& options, const VoxelizeJobResult& r) {
  const Lattice& l = r.model.lattice;
  const uint64_t model_bytes = r.model.memory_bytes();
  nlohmann::json report = {
      {"mesh", options.mesh_path},
      {"requested_resolution", options.resolution},
      {"resolution", {l.nx, l.ny, l.nz}},
      {"voxel_size", l.voxel_size},
      {"origin", {l.origin.x(), l.origin.y(), l.origin.z()}},
      {"occupied_voxels", r.model.occupied_voxels},
      {"crossing_edges", r.model.crossings.size()},
      {"model_bytes", model_bytes},
      {"bytes_per_occupied_voxel", r.model.occupied_voxels ? double(model_bytes) / r.model.occupied_voxels : 0.0},
      {"time_ms",
       {{"load", r.ms.load},
        {"voxelize", r.ms.voxelize},
        {"contour", r.ms.contour},
        {"metrics", r.ms.metrics},
        {"error", r.ms.error},
        {"total", r.ms.total}}},
      {"surface", surface_stats_json(r.stats)},
      {"input",
       {{"triangles", r.input.mesh.triangles.size()},
        {"vertices", r.input.mesh.positions.size()},
        {"dropped_degenerate_triangles", r.input.dropped_triangles},
        {"volume", r.input_volume},
        {"watertight", r.input_watertight}}},
      {"volume_relative_error", r.input_volume > 0 ? (r.stats.volume - r.input_volume) / r.input_volume : 0.0},
  };
  if (options.error_samples > 0) {
    report["error_to_input"] = {{"max", r.error.max},
                                {"mean", r.error.mean},
                                {"rms", r.error.rms},
                                {"samples", r.error.samples},
                                {"unit", "voxel"}};
  }
  return report;
}

}  // namespace dvx
