#include "sim/triangle_quality.h"

#include <doctest/doctest.h>

#include <cmath>

using namespace dvx;

TEST_CASE("triangle angles of an equilateral, a right and a needle triangle") {
  double lo = 0, hi = 0;
  REQUIRE(triangle_angles(Vec3d(0, 0, 0), Vec3d(1, 0, 0), Vec3d(0.5, std::sqrt(3.0) / 2, 0), lo, hi));
  CHECK(lo == doctest::Approx(60.0).epsilon(1e-9));
  CHECK(hi == doctest::Approx(60.0).epsilon(1e-9));
  REQUIRE(triangle_angles(Vec3d(0, 0, 0), Vec3d(1, 0, 0), Vec3d(0, 1, 0), lo, hi));
  CHECK(lo == doctest::Approx(45.0));
  CHECK(hi == doctest::Approx(90.0));
  // A needle: 1e-6 high over a unit base; its largest angle is near 180 degrees, resolved by atan2.
  REQUIRE(triangle_angles(Vec3d(0, 0, 0), Vec3d(1, 0, 0), Vec3d(0.5, 1e-6, 0), lo, hi));
  CHECK(lo < 1e-3);
  CHECK(hi > 179.99);
  CHECK_FALSE(triangle_angles(Vec3d(0, 0, 0), Vec3d(1, 0, 0), Vec3d(2, 0, 0), lo, hi));
}

TEST_CASE("angle statistics: histograms, fractions and subsets") {
  const std::vector<Vec3d> p = {Vec3d(0, 0, 0), Vec3d(1, 0, 0), Vec3d(0, 1, 0), Vec3d(0.5, 1e-3, 0), Vec3d(3, 0, 0)};
  const std::vector<Tri> t = {{0, 1, 2}, {0, 1, 3}, {0, 1, 4}};  // right, needle, degenerate
  const AngleStats all = angle_stats(p, t);
  CHECK(all.triangles == 3);
  CHECK(all.degenerate == 1);
  CHECK(all.fraction_min_le_10 == doctest::Approx(2.0 / 3.0));
  CHECK(all.fraction_max_ge_160 == doctest::Approx(2.0 / 3.0));
  uint64_t total = 0;
  for (uint64_t c : all.min_angle_histogram) total += c;
  CHECK(total == 3);
  CHECK(all.min_angle_histogram[9] == 1);   // 45 degrees
  CHECK(all.max_angle_histogram[18] == 1);  // 90 degrees
  CHECK(all.max_angle_histogram[35] == 2);  // ~180 degrees and the degenerate one
  const std::vector<uint32_t> right = {0};
  const AngleStats one = angle_stats(p, t, &right);
  CHECK(one.triangles == 1);
  CHECK(one.fraction_min_le_10 == 0.0);
  CHECK(one.mean_min_angle_deg == doctest::Approx(45.0));
}
