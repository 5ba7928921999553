#include "engine/stats.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>

namespace dvx {

double quantile(std::vector<double> values, double q) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  const double rank = std::ceil(std::clamp(q, 0.0, 1.0) * double(values.size()));
  return values[std::min(values.size() - 1, size_t(std::max(rank, 1.0)) - 1)];
}

nlohmann::json percentiles_json(const std::vector<double>& values) {
  if (values.empty()) return {{"mean", 0.0}, {"p50", 0.0}, {"p95", 0.0}, {"p99", 0.0}, {"max", 0.0}, {"count", 0}};
  std::vector<double> sorted = values;
  std::sort(sorted.begin(), sorted.end());
  double sum = 0.0;
  for (double v : sorted) sum += v;
  return {{"mean", sum / double(sorted.size())},
          {"p50", quantile(sorted, 0.50)},
          {"p95", quantile(sorted, 0.95)},
          {"p99", quantile(sorted, 0.99)},
          {"max", sorted.back()},
          {"count", sorted.size()}};
}

nlohmann::json surface_stats_json(const SurfaceStats& s) {
  return {{"vertices", s.vertices},
          {"triangles", s.triangles},
          {"boundary_edges", s.boundary_edges},
          {"nonmanifold_edges", s.nonmanifold_edges},
          {"misoriented_edges", s.misoriented_edges},
          {"components", s.components},
          {"euler", s.euler},
          {"volume", s.volume},
          {"area", s.area}};
}

}  // namespace dvx
