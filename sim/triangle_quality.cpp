#include "sim/triangle_quality.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>

namespace dvx {

bool triangle_angles(const Vec3d& a, const Vec3d& b, const Vec3d& c, double& min_deg, double& max_deg) {
  // Angles from atan2(|u x v|, u . v): accurate near 0 and 180 degrees, where acos is not.
  const Vec3d p[3] = {a, b, c};
  if ((b - a).cross(c - a).squaredNorm() == 0.0) return false;
  constexpr double kDegrees = 180.0 / 3.14159265358979323846;
  min_deg = 180.0;
  max_deg = 0.0;
  for (int i = 0; i < 3; ++i) {
    const Vec3d u = p[(i + 1) % 3] - p[i], v = p[(i + 2) % 3] - p[i];
    const double angle = std::atan2(u.cross(v).norm(), u.dot(v)) * kDegrees;
    min_deg = std::min(min_deg, angle);
    max_deg = std::max(max_deg, angle);
  }
  return true;
}

AngleStats angle_stats(const std::vector<Vec3d>& positions, const std::vector<Tri>& triangles,
                       const std::vector<uint32_t>* subset) {
  AngleStats s;
  const size_t n = subset ? subset->size() : triangles.size();
  double sum_min = 0.0;
  uint64_t small = 0, large = 0;
  auto bin = [](double deg) { return std::clamp(int(deg / 5.0), 0, AngleStats::kBins - 1); };
  for (size_t k = 0; k < n; ++k) {
    const Tri& t = triangles[subset ? (*subset)[k] : k];
    double lo = 0.0, hi = 180.0;
    if (!triangle_angles(positions[t[0]], positions[t[1]], positions[t[2]], lo, hi)) {
      lo = 0.0;
      hi = 180.0;
      ++s.degenerate;
    }
    ++s.triangles;
    ++s.min_angle_histogram[size_t(bin(lo))];
    ++s.max_angle_histogram[size_t(bin(hi))];
    s.min_angle_deg = std::min(s.min_angle_deg, lo);
    s.max_angle_deg = std::max(s.max_angle_deg, hi);
    sum_min += lo;
    small += lo <= 10.0;
    large += hi >= 160.0;
  }
  if (s.triangles) {
    s.mean_min_angle_deg = sum_min / double(s.triangles);
    s.fraction_min_le_10 = double(small) / double(s.triangles);
    s.fraction_max_ge_160 = double(large) / double(s.triangles);
  } else {
    s.min_angle_deg = 0.0;
  }
  return s;
}

}  // namespace dvx
