#include "engine/bench.h"
#include "engine/bench_common.h"
#include "engine/errors.h"
#include "engine/mesh_io.h"
#include "engine/output.h"
#include "engine/voxelize_job.h"
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
namespace {

using Clock = BenchClock;

// One step's measurements (medians over repeats).
struct StepTiming {
  double divide_ms = 0, surface_ms = 0, total_ms = 0;
  uint32_t voxels_cut = 0, edges_cut = 0, triangles_changed = 0;
  uint32_t newly_divided = 0;  // voxels that became divided in this step
};

}  // namespace

std::string bench_cut(const BenchCutOptions& options) {
  const std::string mesh_path = options.mesh.empty() ? shared_or_bunny("armadillo_100k.obj") : options.mesh;
  make_output_dir(options.out_dir);
  const LoadedMesh input = load_mesh(mesh_path);
  const Aabb box = mesh_bounds(input.mesh);
  const std::string name = std::filesystem::path(mesh_path).filename().string();

  std::ostringstream rows_csv, steps_csv;
  rows_csv << "mesh,resolution,nx,ny,nz,occupied_voxels,steps,cutting_steps,init_ms,step_p50_ms,step_p99_ms,"
              "step_max_ms,divide_p50_ms,surface_p50_ms,voxels_cut,edges_cut,us_per_cut_voxel,divided_voxels,"
              "explicit_bytes,bytes_per_divided_voxel,components,boundary_edges,newly_divided,us_per_newly_divided_voxel\n";
  steps_csv << "mesh,resolution,step,divide_ms,surface_ms,total_ms,voxels_cut,edges_cut,triangles_changed\n";
  nlohmann::json json_rows = nlohmann::json::array();

  for (int resolution : options.resolutions) {
    if (options.progress) std::fprintf(stderr, "divvox bench cut: %s at %d\n", name.c_str(), resolution);
    check_voxelize_memory(mesh_path, box, input.mesh.triangles.size(), resolution);
    VoxelModel model;
    VoxelizeParams params;
    params.resolution = resolution;
    std::string error;
    if (!voxelize(input.mesh, params, model, error)) throw_input(mesh_path, error);

    // Repeat the whole cut on a fresh state; keep every step's samples.
    std::vector<std::vector<StepTiming>> runs(size_t(options.repeats));
    std::vector<double> init_ms;
    CutState state;
    for (int r = 0; r < options.repeats; ++r) {
      const Clock::time_point t_init = Clock::now();
      init_cut_state(model, state);
      init_ms.push_back(ms_between(t_init, Clock::now()));
      std::vector<StepTiming>& run = runs[size_t(r)];
      for (int s = 1; s <= options.steps; ++s) {
        CutStepStats stats;
        const size_t divided_before = state.divided.size();
        const Clock::time_point t0 = Clock::now();
        cut_divide(model, state, cut_pose(box, s - 1, options.steps), cut_pose(box, s, options.steps), stats);
        const Clock::time_point t1 = Clock::now();
        cut_update_surface(model, state, stats);
        const Clock::time_point t2 = Clock::now();
        run.push_back({ms_between(t0, t1), ms_between(t1, t2), ms_between(t0, t2), stats.voxels_cut, stats.edges_cut,
                       stats.triangles_changed, uint32_t(state.divided.size() - divided_before)});
      }
    }

    // Per-step medians over repeats; statistics over the steps that cut something.
    std::vector<double> totals, divides, surfaces;
    double sum_total = 0.0;
    uint64_t sum_voxels = 0, sum_edges = 0, sum_new = 0;
    for (int s = 0; s < options.steps; ++s) {
      std::vector<double> t, d, u;
      for (const auto& run : runs) {
        t.push_back(run[size_t(s)].total_ms);
        d.push_back(run[size_t(s)].divide_ms);
        u.push_back(run[size_t(s)].surface_ms);
      }
      const StepTiming& first = runs[0][size_t(s)];
      const double total = quantile(t, 0.5), divide = quantile(d, 0.5), surface = quantile(u, 0.5);
      steps_csv << name << ',' << resolution << ',' << s + 1 << ',' << divide << ',' << surface << ',' << total << ','
                << first.voxels_cut << ',' << first.edges_cut << ',' << first.triangles_changed << '\n';
      if (first.voxels_cut == 0) continue;
      totals.push_back(total);
      divides.push_back(divide);
      surfaces.push_back(surface);
      sum_total += total;
      sum_voxels += first.voxels_cut;
      sum_new += first.newly_divided;
      sum_edges += first.edges_cut;
    }
    const SurfaceStats stats = surface_stats(compact_surface(state.surface));
    const uint64_t explicit_bytes = cut_memory_bytes(state);
    const double us_per_voxel = sum_voxels ? 1000.0 * sum_total / double(sum_voxels) : 0.0;
    const double us_per_new = sum_new ? 1000.0 * sum_total / double(sum_new) : 0.0;
    const double bytes_per_divided = state.divided.empty() ? 0.0 : double(explicit_bytes) / double(state.divided.size());
    const Lattice& l = model.lattice;
    rows_csv << name << ',' << resolution << ',' << l.nx << ',' << l.ny << ',' << l.nz << ',' << model.occupied_voxels
             << ',' << options.steps << ',' << totals.size() << ',' << quantile(init_ms, 0.5) << ','
             << quantile(totals, 0.5) << ',' << quantile(totals, 0.99) << ',' << quantile(totals, 1.0) << ','
             << quantile(divides, 0.5) << ',' << quantile(surfaces, 0.5) << ',' << sum_voxels << ',' << sum_edges
             << ',' << us_per_voxel << ',' << state.divided.size() << ',' << explicit_bytes << ','
             << bytes_per_divided << ',' << stats.components << ',' << stats.boundary_edges << ',' << sum_new << ','
             << us_per_new << '\n';
    json_rows.push_back({{"mesh", name},
                         {"resolution", resolution},
                         {"lattice", {l.nx, l.ny, l.nz}},
                         {"occupied_voxels", model.occupied_voxels},
                         {"init_ms", quantile(init_ms, 0.5)},
                         {"step_ms", {{"p50", quantile(totals, 0.5)}, {"p99", quantile(totals, 0.99)}, {"max", quantile(totals, 1.0)}}},
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
                         {"boundary_edges", stats.boundary_edges}});
  }
  const std::filesystem::path out(options.out_dir);
  write_text_file((out / "bench_cut.csv").string(), rows_csv.str());
  write_text_file((out / "bench_cut_steps.csv").string(), steps_csv.str());
  write_json_file((out / "bench_cut.json").string(),
                  {{"benchmark", "cut"}, {"mesh", name}, {"steps", options.steps}, {"repeats", options.repeats},
                   {"statistic", "per-step median over repeats; p50/p99 over steps that cut"}, {"rows", json_rows}});
  return (out / "bench_cut.csv").string();
}

}  // namespace dvx
