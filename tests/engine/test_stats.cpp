// Sample statistics: the nearest-rank quantile and the percentile shape of every JSON output.
#include "engine/stats.h"

#include <doctest/doctest.h>
#include <nlohmann/json.hpp>

using namespace dvx;

TEST_SUITE("stats") {
  TEST_CASE("nearest-rank quantiles: the minimum at 0, the maximum at 1, no wrap-around") {
    CHECK(quantile({}, 0.5) == 0.0);
    CHECK(quantile({3, 1, 2}, 0.0) == 1.0);
    CHECK(quantile({3, 1, 2}, 0.5) == 2.0);
    CHECK(quantile({3, 1, 2}, 1.0) == 3.0);
    CHECK(quantile({3, 1, 2}, -1.0) == 1.0);
    CHECK(quantile({3, 1, 2}, 2.0) == 3.0);
    std::vector<double> hundred;
    for (int i = 1; i <= 100; ++i) hundred.push_back(101 - i);
    CHECK(quantile(hundred, 0.95) == 95.0);
    CHECK(quantile(hundred, 0.99) == 99.0);
    CHECK(quantile(hundred, 0.01) == 1.0);
  }

  TEST_CASE("the percentile shape: mean, p50, p95, p99, max, count, zeros when empty") {
    const nlohmann::json empty = percentiles_json({});
    for (const char* key : {"mean", "p50", "p95", "p99", "max", "count"}) {
      CAPTURE(key);
      REQUIRE(empty.contains(key));
      CHECK(empty[key] == 0);
    }
    std::vector<double> v;
    for (int i = 0; i < 200; ++i) v.push_back(double((i * 7) % 200 + 1));  // 1 .. 200, shuffled
    const nlohmann::json p = percentiles_json(v);
    CHECK(p.size() == 6);
    CHECK(p["count"] == 200);
    CHECK(p["mean"].get<double>() == doctest::Approx(100.5));
    CHECK(p["p50"] == 100.0);
    CHECK(p["p95"] == 190.0);
    CHECK(p["p99"] == 198.0);
    CHECK(p["max"] == 200.0);
  }
}
