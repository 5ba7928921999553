// JSON forms of benchmark statistics shared by `divvox bench` and the peer comparison
// (tools/peers), so the report reads one shape from both.
#pragma once

#include "sim/triangle_quality.h"

#include <nlohmann/json.hpp>

namespace dvx {

// {"triangles", "degenerate", "min_angle_deg", "max_angle_deg", "mean_min_angle_deg",
//  "fraction_min_le_10", "fraction_max_ge_160", "min_angle_histogram": [36], "max_angle_histogram": [36]}
// (histograms: counts per 5-degree bin from 0 to 180 degrees).
inline nlohmann::json angle_stats_json(const AngleStats& s) {
  return {{"triangles", s.triangles},
          {"degenerate", s.degenerate},
          {"min_angle_deg", s.min_angle_deg},
          {"max_angle_deg", s.max_angle_deg},
          {"mean_min_angle_deg", s.mean_min_angle_deg},
          {"fraction_min_le_10", s.fraction_min_le_10},
          {"fraction_max_ge_160", s.fraction_max_ge_160},
          {"min_angle_histogram", s.min_angle_histogram},
          {"max_angle_histogram", s.max_angle_histogram}};
}

}  // namespace dvx
