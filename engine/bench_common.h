// Pieces every `divvox bench` experiment shares: sample statistics, the default meshes, the cut
// path (one path in scene units for every resolution), the least-squares line of Experiment 2.
#pragma once

#include "sim/cut.h"
#include "sim/mesh.h"

#include <chrono>
#include <string>
#include <vector>

namespace dvx {

using BenchClock = std::chrono::steady_clock;

inline double ms_between(BenchClock::time_point a, BenchClock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

// Nearest-rank quantile (q in [0, 1]) of a sample; 0 for an empty sample.
double quantile(std::vector<double> values, double q);

// A shared mesh from ../shared/assets when present, else the shipped bunny.
std::string shared_or_bunny(const std::string& file_name);

// The benchmark cut's blade at step s of `steps`: along z across the whole box, at `height` (fraction
// of the box's y extent), moving along x from 5 % of the box before it to 5 % after it. The blade
// sweeps the plane y = box.min.y + height * extent.y (tools/peers clips with the same plane).
BladePose cut_pose(const Aabb& box, int s, int steps, double height = 0.55);

// The blade pose with its x at `fraction` of the way along the same path (0: before the box).
BladePose cut_pose_at(const Aabb& box, double fraction, double height = 0.55);

// Least-squares line y = intercept + slope * x and its coefficient of determination.
struct LineFit {
  double slope = 0, intercept = 0, r2 = 0;
  size_t samples = 0;
};
LineFit fit_line(const std::vector<double>& x, const std::vector<double>& y);

}  // namespace dvx
