#include "bench/bench_common.h"

#include "engine/errors.h"
#include "engine/voxelize_job.h"
#include "sim/voxelize.h"

#include <algorithm>
#include <cmath>
#include <filesystem>

namespace dvx {

std::string shared_or_bunny(const std::string& file_name) {
  const std::filesystem::path shared = std::filesystem::path(DIVVOX_SHARED_ASSETS_DEFAULT) / file_name;
  if (std::filesystem::exists(shared)) return shared.string();
  return (std::filesystem::path(DIVVOX_SOURCE_DIR_DEFAULT) / "assets/meshes/bunny_npm.obj").string();
}

BladePose cut_pose_at(const Aabb& box, double fraction, double height, int axis) {
  // The plane's normal axis n; the blade lies along n + 1 and moves along n + 2 (mod 3): for y, along z
  // moving along x.
  const int n = axis, along = (axis + 1) % 3, move = (axis + 2) % 3;
  const Vec3d e = box.extent();
  const double margin = 0.05 * e.maxCoeff();
  const double x = box.min[move] - margin + (e[move] + 2 * margin) * fraction;
  const double y = box.min[n] + height * e[n];
  Vec3d a, b;
  a[move] = b[move] = x;
  a[n] = b[n] = y;
  a[along] = box.min[along] - margin;
  b[along] = box.max[along] + margin;
  return {a, b};
}

BladePose cut_pose(const Aabb& box, int s, int steps, double height, int axis) {
  return cut_pose_at(box, double(s) / double(steps), height, axis);
}

void voxelize_for_bench(const TriMesh& mesh, const std::string& path, int resolution, VoxelModel& model) {
  check_voxelize_memory(path, mesh_bounds(mesh), mesh.triangles.size(), resolution);
  VoxelizeParams params;
  params.resolution = resolution;
  std::string error;
  if (!voxelize(mesh, params, model, error)) throw_input(path, error);
}

std::vector<CutStepSample> time_progressive_cut(const VoxelModel& model, const Aabb& box, int steps, int repeats,
                                                CutState& state, std::vector<double>* init_ms, int axis, const TaskRunner& tasks) {
  // Every repeat's phase times per step; the stats are the same in every repeat.
  const size_t n = size_t(steps);
  std::vector<CutStepSample> samples(n);
  std::vector<std::vector<double>> divide(n), surface(n), total(n);
  for (int r = 0; r < repeats; ++r) {
    const Clock::time_point t_init = Clock::now();
    init_cut_state(model, state, {}, tasks);
    if (init_ms) init_ms->push_back(ms_between(t_init, Clock::now()));
    for (int s = 0; s < steps; ++s) {
      CutStepSample& sample = samples[size_t(s)];
      sample.stats = CutStepStats{};
      const size_t divided_before = state.divided.size();
      const Clock::time_point t0 = Clock::now();
      cut_divide(model, state, cut_pose(box, s, steps, 0.55, axis), cut_pose(box, s + 1, steps, 0.55, axis), sample.stats);
      const Clock::time_point t1 = Clock::now();
      cut_update_surface(model, state, sample.stats, tasks);
      const Clock::time_point t2 = Clock::now();
      divide[size_t(s)].push_back(ms_between(t0, t1));
      surface[size_t(s)].push_back(ms_between(t1, t2));
      total[size_t(s)].push_back(ms_between(t0, t2));
      sample.newly_divided = uint32_t(state.divided.size() - divided_before);
    }
  }
  for (size_t s = 0; s < samples.size(); ++s) {
    samples[s].divide_ms = quantile(divide[s], 0.5);
    samples[s].surface_ms = quantile(surface[s], 0.5);
    samples[s].total_ms = quantile(total[s], 0.5);
  }
  return samples;
}

LineFit fit_line(const std::vector<double>& x, const std::vector<double>& y) {
  LineFit fit;
  const size_t n = std::min(x.size(), y.size());
  fit.samples = n;
  if (n < 2) return fit;
  double mx = 0, my = 0;
  for (size_t i = 0; i < n; ++i) mx += x[i], my += y[i];
  mx /= double(n);
  my /= double(n);
  double sxx = 0, sxy = 0, syy = 0;
  for (size_t i = 0; i < n; ++i) {
    sxx += (x[i] - mx) * (x[i] - mx);
    sxy += (x[i] - mx) * (y[i] - my);
    syy += (y[i] - my) * (y[i] - my);
  }
  if (sxx <= 0) return fit;
  fit.slope = sxy / sxx;
  fit.intercept = my - fit.slope * mx;
  double residual = 0;
  for (size_t i = 0; i < n; ++i) {
    const double r = y[i] - (fit.intercept + fit.slope * x[i]);
    residual += r * r;
  }
  fit.r2 = syy > 0 ? 1.0 - residual / syy : 1.0;
  return fit;
}

}  // namespace dvx
