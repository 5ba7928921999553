#include "engine/bench_common.h"

#include <algorithm>
#include <cmath>
#include <filesystem>

namespace dvx {

double quantile(std::vector<double> values, double q) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  const double rank = std::ceil(std::clamp(q, 0.0, 1.0) * double(values.size()));
  return values[std::min(values.size() - 1, size_t(std::max(rank, 1.0)) - 1)];
}

std::string shared_or_bunny(const std::string& file_name) {
  const std::filesystem::path shared = std::filesystem::path(DIVVOX_SHARED_ASSETS_DEFAULT) / file_name;
  if (std::filesystem::exists(shared)) return shared.string();
  return (std::filesystem::path(DIVVOX_SOURCE_DIR_DEFAULT) / "assets/meshes/bunny_npm.obj").string();
}

BladePose cut_pose_at(const Aabb& box, double fraction, double height) {
  const Vec3d e = box.extent();
  const double margin = 0.05 * e.maxCoeff();
  const double x = box.min.x() - margin + (e.x() + 2 * margin) * fraction;
  const double y = box.min.y() + height * e.y();
  return {Vec3d(x, y, box.min.z() - margin), Vec3d(x, y, box.max.z() + margin)};
}

BladePose cut_pose(const Aabb& box, int s, int steps, double height) {
  return cut_pose_at(box, double(s) / double(steps), height);
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
