#include "bench/bench.h"
#include "bench/bench_common.h"
#include "engine/errors.h"
#include "engine/mesh_io.h"
#include "engine/output.h"
#include "engine/task_pool.h"
#include "engine/voxelize_job.h"
#include "harness/plot.h"
#include "sim/cut.h"
#include "sim/pbd.h"
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

// The voxel model and cut state of a scenario: uncut, or cut through by a vertical plane.
struct Scenario {
  VoxelModel model;
  CutState cut;
  Aabb box;
};

void make_scenario(const TriMesh& mesh, const std::string& path, int resolution, bool through_cut, Scenario& s) {
  s.box = mesh_bounds(mesh);
  voxelize_for_bench(mesh, path, resolution, s.model);
  init_cut_state(s.model, s.cut);
  if (through_cut) {
    // Blade along z at x = 55 % of the box, swept along y across the whole object.
    const Vec3d e = s.box.extent();
    const double x = s.box.min.x() + 0.55 * e.x(), m = 0.1 * e.maxCoeff();
    const int steps = 40;
    BladePose previous{Vec3d(x, s.box.min.y() - m, s.box.min.z() - m), Vec3d(x, s.box.min.y() - m, s.box.max.z() + m)};
    for (int i = 1; i <= steps; ++i) {
      const double y = s.box.min.y() - m + (e.y() + 2 * m) * i / steps;
      const BladePose next{Vec3d(x, y, s.box.min.z() - m), Vec3d(x, y, s.box.max.z() + m)};
      cut_step(s.model, s.cut, previous, next);
      previous = next;
    }
  }
}

PbdParams anchored_params(const Scenario& s, int resolution, int sim_resolution, int iterations, int substeps = 1) {
  PbdParams p;
  p.substeps = substeps;
  p.resolution = resolution;
  p.sim_resolution = sim_resolution;
  p.iterations = iterations;
  p.stretch_compliance = 1e-6;
  // Settles within the compared time, so the error measures the solution, not a phase of its swing.
  // Damping is per time step whatever the substeps (pbd_step), so the small-steps sweep compares
  // solvers, not damping.
  p.damping = 0.05;
  // Anchored on one side: the particles within 15 % of the box on the -x side.
  Aabb fixed = s.box;
  const Vec3d e = s.box.extent();
  fixed.min -= Vec3d::Constant(e.maxCoeff());
  fixed.max.x() = s.box.min.x() + 0.15 * e.x();
  fixed.max.y() += e.maxCoeff();
  fixed.max.z() += e.maxCoeff();
  p.fixed.push_back(fixed);
  return p;
}

// Runs `steps` steps; returns per-step times (ms) and leaves the deformed surface in `pbd`.
std::vector<double> simulate(const Scenario& s, const PbdParams& params, int steps, TaskPool& pool, PbdState& pbd) {
  std::string error;
  if (!init_pbd(s.model, s.cut, params, pbd.model, pbd.data, error)) throw std::runtime_error(error);
  std::vector<double> times;
  for (int i = 0; i < steps; ++i) {
    const Clock::time_point t0 = Clock::now();
    pbd_step(s.cut, pbd.model, pbd.data, pool.runner());
    times.push_back(ms_between(t0, Clock::now()));
  }
  return times;
}

// Relative L2 distance of the deformed surfaces: |p - ref| / |ref - rest| summed over live vertices.
double relative_error(const CutState& cut, const PbdData& run, const PbdData& ref) {
  double num = 0.0, den = 0.0;
  for (size_t v = 0; v < cut.surface.positions.size(); ++v) {
    if (cut.surface.vertex_piece[v] == CutSurface::kFreeKey) continue;
    num += (run.deformed[v] - ref.deformed[v]).cast<double>().squaredNorm();
    den += (ref.deformed[v] - cut.surface.positions[v]).cast<double>().squaredNorm();
  }
  return den > 0.0 ? std::sqrt(num / den) : 0.0;
}

// The kernel paths this CPU has (pbd_kernels.h: the same bits on each), by name.
typedef std::vector<std::pair<KernelIsa, const char*>> KernelPaths;
KernelPaths kernel_paths() {
  KernelPaths paths = {{KernelIsa::kBaseline, "baseline"}};
  if (kernel_isa() >= KernelIsa::kAvx2) paths.emplace_back(KernelIsa::kAvx2, "avx2");
  if (kernel_isa() >= KernelIsa::kAvx512) paths.emplace_back(KernelIsa::kAvx512, "avx512");
  return paths;
}

// A kernel timed on its scalar reference and on each path: the fastest pass of each (ms), ns per
// item on each path, and whether every path ended on the reference's positions.
struct PathTimes {
  double reference_ms = 1e300, solver_ms = 1e300;  // the scalar reference; the last path (the solver's)
  bool identical = true;
  nlohmann::json ns_by_path = nlohmann::json::object();
};

// `pass(path)` (-1: the scalar reference, else paths[path]) `repeats` times after `reset()`, per path.
template <class Reset, class Pass>
PathTimes time_paths(const PbdData& pbd, const KernelPaths& paths, int repeats, double ns_per_ms, Reset reset,
                     Pass pass) {
  PathTimes t;
  std::vector<Vec3d> reference_end;
  for (int path = -1; path < int(paths.size()); ++path) {
    reset();
    double best = 1e300;
    for (int r = 0; r < repeats; ++r) best = std::min(best, pass(path));
    if (path < 0) {
      t.reference_ms = best;
      reference_end = pbd.position;
      continue;
    }
    t.identical = t.identical && pbd.position == reference_end;
    t.ns_by_path[paths[size_t(path)].second] = best * ns_per_ms;
    t.solver_ms = best;
  }
  return t;
}

// The shape-matching kernel before and after issue 17 in one run, on a settled state of `pbd`:
// passes over every cluster, colour by colour, with the scalar kernel (solve_shape_matching from a
// rest frame: the solver's code before the blocks) and with the blocks (solve_shape_blocks) on each
// kernel path the CPU has (the solver's is the last, the best), from the same start. All must end on
// the same bits (checked: "identical"); time per cluster solve, the fastest pass of `repeats`.
nlohmann::json kernel_comparison(const PbdModel& model, PbdData& pbd, int repeats) {
  const std::vector<Vec3d> start = pbd.position;
  const std::vector<Eigen::Quaterniond> rotations = pbd.rotation;
  std::vector<ShapeRest> frames(model.pieces.size());
  uint64_t clusters = 0;
  for (const std::vector<uint32_t>& group : model.piece_groups) {
    for (const uint32_t slot : group) {
      double rest[24];
      for (int k = 0; k < 8; ++k) {
        for (int a = 0; a < 3; ++a) rest[3 * k + a] = model.rest[model.pieces[slot].particles[k]][a];
      }
      const uint32_t* particles = model.pieces[slot].particles;
      clusters += shape_matching_rest(model.inv_mass.data(), particles, rest, 8, frames[slot]) ? 1 : 0;
    }
  }
  const KernelPaths paths = kernel_paths();
  // One pass over every cluster, scalar (path < 0) or by the blocks on paths[path]; returns its time (ms).
  const auto pass = [&](int path) {
    double* x = pbd.position[0].data();
    const Clock::time_point t0 = Clock::now();
    for (int c = 0; c < kColourGroups; ++c) {
      if (path >= 0) {
        solve_shape_blocks(paths[size_t(path)].first, x, pbd.cache.shape_blocks[c].data(), 0,
                           uint32_t(pbd.cache.shape_blocks[c].size()), 1.0, pbd.rotation.data(), c != kOverflowColour);
        continue;
      }
      for (const uint32_t slot : model.piece_groups[c]) {
        if (frames[slot].count > 0) solve_shape_matching(x, model.pieces[slot].particles, frames[slot], 1.0, pbd.rotation[slot], 0);
      }
    }
    return ms_between(t0, Clock::now());
  };
  const double per = 1e6 / double(std::max<uint64_t>(1, clusters));  // ms -> ns per cluster
  const PathTimes shape = time_paths(
      pbd, paths, repeats, per,
      [&] {
        pbd.position = start;
        pbd.rotation = rotations;
      },
      pass);
  pbd.position = start;
  pbd.rotation = rotations;

  // The stretch rows the same way: one by one (the solver's rows before) and by the vector rows of
  // each path in the colour groups (solve_stretch_rows with disjoint groups), from the same start and
  // multipliers.
  uint64_t constraints = 0;
  for (int c = 0; c < kOverflowColour; ++c) constraints += pbd.cache.stretch_rows[c].size();
  const double alpha = model.params.stretch_compliance / (model.params.dt * model.params.dt);
  std::vector<std::vector<double>> lambdas(kColourGroups);
  const auto stretch_pass = [&](int path) {
    double* x = pbd.position[0].data();
    const Clock::time_point t0 = Clock::now();
    for (int c = 0; c < kOverflowColour; ++c) {
      solve_stretch_rows(path < 0 ? KernelIsa::kBaseline : paths[size_t(path)].first, x, pbd.cache.stretch_rows[c].data(),
                         lambdas[c].data(), 0, uint32_t(pbd.cache.stretch_rows[c].size()), alpha, path >= 0);
    }
    return ms_between(t0, Clock::now());
  };
  const double per_row = 1e6 / double(std::max<uint64_t>(1, constraints));
  const PathTimes stretch = time_paths(
      pbd, paths, repeats, per_row,
      [&] {
        pbd.position = start;
        for (int c = 0; c < kColourGroups; ++c) lambdas[c].assign(pbd.cache.stretch_rows[c].size(), 0.0);
      },
      stretch_pass);
  pbd.position = start;
  return {{"clusters", clusters},
          {"repeats", repeats},
          {"path", paths.back().second},
          {"shape_matching",
           {{"scalar_ns", shape.reference_ms * per},
            {"blocks_ns", shape.solver_ms * per},
            {"blocks_ns_by_path", shape.ns_by_path},
            {"speedup", shape.solver_ms > 0.0 ? shape.reference_ms / shape.solver_ms : 0.0},
            {"identical", shape.identical}}},
          {"stretch_constraints", constraints},
          {"stretch",
           {{"rows_ns", stretch.reference_ms * per_row},
            {"vector_ns", stretch.solver_ms * per_row},
            {"vector_ns_by_path", stretch.ns_by_path},
            {"speedup", stretch.solver_ms > 0.0 ? stretch.reference_ms / stretch.solver_ms : 0.0},
            {"identical", stretch.identical}}}};
}

}  // namespace

std::string bench_deform(const BenchDeformOptions& options) {
  make_output_dir(options.out_dir);
  const std::string mesh_path = options.mesh.empty() ? shared_or_bunny("liver_sofa_smooth.obj") : options.mesh;
  const LoadedMesh input = load_mesh(mesh_path);
  const std::string name = std::filesystem::path(mesh_path).filename().string();
  TaskPool pool(options.workers);
  const double dt = 1.0 / 60.0;
  const int steps = std::max(1, int(std::lround(options.seconds / dt)));

  std::ostringstream csv;
  csv << "mesh,scenario,resolution,sim_resolution,iterations,steps,step_p50_ms,step_p99_ms,relative_error,particles,"
         "shape_constraints,stretch_constraints,substeps\n";
  nlohmann::json rows = nlohmann::json::array(), target_json, kernels_json;
  for (const bool through : {false, true}) {
    const std::string scenario = through ? "through_cut" : "anchored";
    Scenario s;
    make_scenario(input.mesh, mesh_path, options.resolution, through, s);
    // The reference: the finest simulation level with the most iterations.
    const int finest = *std::max_element(options.sim_resolutions.begin(), options.sim_resolutions.end());
    const int most = *std::max_element(options.iterations.begin(), options.iterations.end());
    PbdState reference;
    simulate(s, anchored_params(s, options.resolution, finest, most), steps, pool, reference);
    // The kernels before and after (issue 17), on the uncut scenario's settled reference state.
    if (!through) kernels_json = kernel_comparison(reference.model, reference.data, 20);
    // One run: a CSV row and a JSON row.
    const auto measure = [&](int sim, int iterations, int substeps) {
      if (options.progress) {
        std::fprintf(stderr, "divvox bench deform: %s sim %d iterations %d substeps %d\n", scenario.c_str(), sim,
                     iterations, substeps);
      }
      PbdState run;
      const std::vector<double> times =
          simulate(s, anchored_params(s, options.resolution, sim, iterations, substeps), steps, pool, run);
      const double error = relative_error(s.cut, run.data, reference.data);
      const double p50 = quantile(times, 0.5);
      csv << name << ',' << scenario << ',' << options.resolution << ',' << sim << ',' << iterations << ',' << steps
          << ',' << p50 << ',' << quantile(times, 0.99) << ',' << error << ',' << live_particles(run.model) << ','
          << live_pieces(run.model) << ',' << stretch_count(run.model) << ',' << substeps << '\n';
      rows.push_back({{"scenario", scenario}, {"sim_resolution", sim}, {"iterations", iterations},
                      {"substeps", substeps}, {"step_p50_ms", p50}, {"step_p99_ms", quantile(times, 0.99)},
                      {"relative_error", error},
                      {"particles", run.data.position.size() - run.model.free_particles.size()}});
    };
    for (int sim : options.sim_resolutions) {
      for (int iterations : options.iterations) measure(sim, iterations, 1);
      // Small steps at equal cost: substeps x iterations = budget.
      for (int budget : options.substep_budgets) {
        for (int substeps = 2; substeps <= budget; ++substeps) {
          if (budget % substeps == 0) measure(sim, budget / substeps, substeps);
        }
      }
    }
  }
  const std::filesystem::path out(options.out_dir);
  write_text_file((out / "bench_deform.csv").string(), csv.str());

  // The speed target: PBD + embedding per step on a large surface.
  std::string target = options.target_mesh;
  if (target.empty()) {
    const std::filesystem::path shared = std::filesystem::path(DIVVOX_SHARED_ASSETS_DEFAULT) / "armadillo_100k.obj";
    if (std::filesystem::exists(shared)) target = shared.string();
  }
  if (!target.empty()) {
    if (options.progress) std::fprintf(stderr, "divvox bench deform: target %s at %d\n", target.c_str(), options.target_resolution);
    const LoadedMesh big = load_mesh(target);
    Scenario s;
    make_scenario(big.mesh, target, options.target_resolution, false, s);
    PbdState run;
    const std::vector<double> times = simulate(
        s, anchored_params(s, options.target_resolution, options.target_sim_resolution, options.target_iterations),
        options.target_steps, pool, run);
    std::ostringstream t;
    t << "mesh,resolution,sim_resolution,iterations,workers,steps,surface_vertices,particles,step_p50_ms,step_p99_ms,"
         "step_max_ms\n";
    t << std::filesystem::path(target).filename().string() << ',' << options.target_resolution << ','
      << options.target_sim_resolution << ',' << options.target_iterations << ',' << pool.workers() << ','
      << options.target_steps << ',' << s.cut.surface.live_vertices() << ','
      << run.data.position.size() - run.model.free_particles.size() << ',' << quantile(times, 0.5) << ','
      << quantile(times, 0.99) << ',' << quantile(times, 1.0) << '\n';
    write_text_file((out / "bench_deform_target.csv").string(), t.str());
    target_json = {{"mesh", std::filesystem::path(target).filename().string()},
                   {"resolution", options.target_resolution},
                   {"sim_resolution", options.target_sim_resolution},
                   {"iterations", options.target_iterations},
                   {"workers", pool.workers()},
                   {"surface_vertices", s.cut.surface.live_vertices()},
                   {"step_ms", percentiles_json(times)}};
  }
  const nlohmann::json results = {{"benchmark", "deform"},
                   {"machine", machine_summary()},
                   {"mesh", name},
                   {"resolution", options.resolution},
                   {"seconds", options.seconds},
                   {"workers", pool.workers()},
                   {"error", "relative L2 distance of the surface vertices to the finest, most converged run, over the "
                             "reference's mean displacement"},
                   {"rows", rows},
                   {"kernels", kernels_json},
                   {"target", target_json}};
  write_json_file((out / "bench_deform.json").string(), results);
  std::string error;
  if (draw_bench_plot(results, out.string(), error).empty()) std::fprintf(stderr, "divvox: bench_deform.svg skipped: %s\n", error.c_str());
  return (out / "bench_deform.csv").string();
}

}  // namespace dvx
