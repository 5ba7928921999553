// Statistics shared by replay, voxelize and the benchmarks: one quantile, one percentile shape, one
// JSON form of a surface's counts.
#pragma once

#include "sim/surface_metrics.h"

#include <nlohmann/json_fwd.hpp>

#include <vector>

namespace dvx {

// Nearest-rank quantile of a sample: the smallest value with at least q * n values at or below it
// (q clamped to [0, 1]; q = 0 gives the minimum, q = 1 the maximum); 0 for an empty sample.
double quantile(std::vector<double> values, double q);

// The percentile shape every JSON output uses for a sample of times (README "Percentiles"):
// {"mean", "p50", "p95", "p99", "max", "count"}, nearest-rank quantiles; all zero for an empty sample.
nlohmann::json percentiles_json(const std::vector<double>& values);

// A surface's counts as the JSON outputs write them ("surface" in report.json and summary.json):
// {"vertices", "triangles", "boundary_edges", "nonmanifold_edges", "misoriented_edges", "components",
//  "euler", "volume", "area"}.
nlohmann::json surface_stats_json(const SurfaceStats& stats);

}  // namespace dvx
