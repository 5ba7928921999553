#include "bench/bench.h"
#include "bench/bench_common.h"
#include "engine/errors.h"
#include "engine/mesh_io.h"
#include "engine/output.h"
#include "engine/task_pool.h"
#include "engine/voxelize_job.h"
#include "harness/plot.h"
#include "sim/cut.h"
#include "sim/surface_metrics.h"
#include "sim/voxelize.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <sstream>

namespace dvx {

std::string bench_cut(const BenchCutOptions& options) {
  const std::string mesh_path = options.mesh.empty() ? shared_or_bunny("armadillo_100k.obj") : options.mesh;
  make_output_dir(options.out_dir);
  const LoadedMesh input = load_mesh(mesh_path);
  const Aabb box = mesh_bounds(input.mesh);
  const std::string name = std::filesystem::path(mesh_path).filename().string();

  std::ostringstream rows_csv, steps_csv;
  rows_csv << "mesh,resolution,nx,ny,nz,occupied_voxels,steps,cutting_steps,init_ms,step_p50_ms,step_p99_ms,"
              "step_max_ms,divide_p50_ms,surface_p50_ms,voxels_cut,edges_cut,us_per_cut_voxel,divided_voxels,"
              "explicit_bytes,bytes_per_divided_voxel,components,boundary_edges,newly_divided,us_per_newly_divided_voxel,"
              "direction,divide_p99_ms,surface_p99_ms,surface_max_ms,us_per_cut_voxel_surface\n";
  steps_csv << "mesh,resolution,step,divide_ms,surface_ms,total_ms,voxels_cut,edges_cut,triangles_changed,direction\n";
  nlohmann::json json_rows = nlohmann::json::array();

  TaskPool pool(options.workers);  // the surface update runs over the workers, as in a session
  for (int resolution : options.resolutions) {
    VoxelModel model;
    voxelize_for_bench(input.mesh, mesh_path, resolution, model);
   // One row per direction (the cut plane's normal axis: the blade along the next axis, moving along
   // the one after; y is the cut the peers clip with).
   for (int axis : options.directions) {
    const char direction[2] = {char('x' + axis), 0};
    if (options.progress) std::fprintf(stderr, "divvox bench cut: %s at %d, plane normal %s\n", name.c_str(), resolution, direction);

    // Repeat the whole cut on a fresh state: per-step medians; statistics over the steps that cut.
    std::vector<double> init_ms;
    CutState state;
    const std::vector<CutStepSample> samples =
        time_progressive_cut(model, box, options.steps, options.repeats, state, &init_ms, axis, pool.runner());
    std::vector<double> totals, divides, surfaces;
    double sum_surface = 0.0;
    double sum_total = 0.0;
    uint64_t sum_voxels = 0, sum_edges = 0, sum_new = 0;
    for (int s = 0; s < options.steps; ++s) {
      const CutStepSample& step = samples[size_t(s)];
      steps_csv << name << ',' << resolution << ',' << s + 1 << ',' << step.divide_ms << ',' << step.surface_ms << ','
                << step.total_ms << ',' << step.stats.voxels_cut << ',' << step.stats.edges_cut << ','
                << step.stats.triangles_changed << ',' << direction << '\n';
      if (step.stats.voxels_cut == 0) continue;
      totals.push_back(step.total_ms);
      divides.push_back(step.divide_ms);
      surfaces.push_back(step.surface_ms);
      sum_total += step.total_ms;
      sum_surface += step.surface_ms;
      sum_voxels += step.stats.voxels_cut;
      sum_new += step.newly_divided;
      sum_edges += step.stats.edges_cut;
    }
    const SurfaceStats stats = surface_stats(compact_surface(state.surface));
    const uint64_t explicit_bytes = cut_memory_bytes(state);
    const double us_per_voxel = sum_voxels ? 1000.0 * sum_total / double(sum_voxels) : 0.0;
    const double us_per_new = sum_new ? 1000.0 * sum_total / double(sum_new) : 0.0;
    const double us_per_voxel_surface = sum_voxels ? 1000.0 * sum_surface / double(sum_voxels) : 0.0;
    const double bytes_per_divided = state.divided.empty() ? 0.0 : double(explicit_bytes) / double(state.divided.size());
    const Lattice& l = model.lattice;
    rows_csv << name << ',' << resolution << ',' << l.nx << ',' << l.ny << ',' << l.nz << ',' << model.occupied_voxels
             << ',' << options.steps << ',' << totals.size() << ',' << quantile(init_ms, 0.5) << ','
             << quantile(totals, 0.5) << ',' << quantile(totals, 0.99) << ',' << quantile(totals, 1.0) << ','
             << quantile(divides, 0.5) << ',' << quantile(surfaces, 0.5) << ',' << sum_voxels << ',' << sum_edges
             << ',' << us_per_voxel << ',' << state.divided.size() << ',' << explicit_bytes << ','
             << bytes_per_divided << ',' << stats.components << ',' << stats.boundary_edges << ',' << sum_new << ','
             << us_per_new << ',' << direction << ',' << quantile(divides, 0.99) << ',' << quantile(surfaces, 0.99) << ','
             << quantile(surfaces, 1.0) << ',' << us_per_voxel_surface << '\n';
    json_rows.push_back({{"mesh", name},
                         {"resolution", resolution},
                         {"lattice", {l.nx, l.ny, l.nz}},
                         {"occupied_voxels", model.occupied_voxels},
                         {"init_ms", quantile(init_ms, 0.5)},
                         {"step_ms", percentiles_json(totals)},
                         {"divide_ms_p50", quantile(divides, 0.5)},
                         {"surface_ms_p50", quantile(surfaces, 0.5)},
                         {"voxels_cut", sum_voxels},
                         {"edges_cut", sum_edges},
                         {"us_per_cut_voxel", us_per_voxel},
                         {"newly_divided_voxels", sum_new},
                         {"us_per_newly_divided_voxel", us_per_new},
                         {"divided_voxels", state.divided.size()},
                         {"explicit_bytes", explicit_bytes},
                         {"bytes_per_divided_voxel", bytes_per_divided},
                         {"components", stats.components},
                         {"boundary_edges", stats.boundary_edges},
                         {"direction", direction},
                         {"divide_ms", percentiles_json(divides)},
                         {"surface_ms", percentiles_json(surfaces)},
                         {"us_per_cut_voxel_surface", us_per_voxel_surface}});
   }
  }
  nlohmann::json directions_json = nlohmann::json::array();
  for (int axis : options.directions) directions_json.push_back(std::string(1, char('x' + axis)));
  const std::filesystem::path out(options.out_dir);
  write_text_file((out / "bench_cut.csv").string(), rows_csv.str());
  write_text_file((out / "bench_cut_steps.csv").string(), steps_csv.str());
  write_json_file((out / "bench_cut.json").string(),
                  {{"benchmark", "cut"}, {"machine", machine_summary()}, {"mesh", name}, {"steps", options.steps}, {"repeats", options.repeats}, {"workers", options.workers},
                   {"directions", directions_json},
                   {"statistic", "per-step median over repeats; p50/p99 over steps that cut"}, {"rows", json_rows}});
  return (out / "bench_cut.csv").string();
}

}  // namespace dvx
