// Triangle shape quality of a surface (paper Fig. 13): the smallest and largest interior angle of
// each triangle, as histograms and as the fractions of needle/cap-shaped triangles a remeshing cut
// tends to create. Used by `divvox bench quality` and by the peer (CGAL) comparison.
#pragma once

#include "sim/mesh.h"

#include <array>
#include <cstdint>
#include <vector>

namespace dvx {

struct AngleStats {
  static constexpr int kBins = 36;  // 5-degree bins over [0, 180]
  uint64_t triangles = 0;
  uint64_t degenerate = 0;                 // zero-area triangles (counted as 0 and 180 degrees)
  std::array<uint64_t, kBins> min_angle_histogram{};  // counts of the smallest angle per bin
  std::array<uint64_t, kBins> max_angle_histogram{};  // counts of the largest angle per bin
  double min_angle_deg = 180.0;            // smallest angle over all triangles
  double max_angle_deg = 0.0;              // largest angle over all triangles
  double mean_min_angle_deg = 0.0;
  double fraction_min_le_10 = 0.0;         // fraction of triangles with smallest angle <= 10 degrees
  double fraction_max_ge_160 = 0.0;        // fraction with largest angle >= 160 degrees
};

// Angle statistics of `triangles` over `positions`; with `subset`, only the listed triangle ids.
AngleStats angle_stats(const std::vector<Vec3d>& positions, const std::vector<Tri>& triangles,
                       const std::vector<uint32_t>* subset = nullptr);

// Smallest and largest interior angle of one triangle, in degrees; false for a zero-area triangle.
bool triangle_angles(const Vec3d& a, const Vec3d& b, const Vec3d& c, double& min_deg, double& max_deg);

}  // namespace dvx
