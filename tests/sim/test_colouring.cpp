// Constraint colouring: race-free groups, an overflow colour instead of a cap, and the same result
// for any number of workers.
#include "sim/colouring.h"
#include "sim/pbd_kernels.h"
#include "sim/random.h"

#include <doctest/doctest.h>

#include <algorithm>
#include <thread>
#include <vector>

using namespace dvx;

namespace {

// A task runner over std::thread (sim owns none).
struct ThreadRunner {
  int workers = 2;
  static void run(void* context, uint32_t count, uint32_t grain, void (*fn)(uint32_t, uint32_t, void*), void* user) {
    const int workers = static_cast<ThreadRunner*>(context)->workers;
    const uint32_t chunk = std::max<uint32_t>(std::min<uint32_t>(grain, 4), (count + uint32_t(workers) - 1) / uint32_t(workers));
    std::vector<std::thread> threads;
    for (uint32_t begin = chunk; begin < count; begin += chunk) threads.emplace_back(fn, begin, std::min(count, begin + chunk), user);
    fn(0, std::min(count, chunk), user);
    for (std::thread& t : threads) t.join();
  }
  TaskRunner runner() { return TaskRunner{this, &ThreadRunner::run}; }
};

struct Edge {
  uint32_t a, b;
  double rest, lambda;
};

// A star: 100 distance constraints on particle 0 (more than the 63 parallel colours), plus a ring.
struct Star {
  std::vector<double> x;  // (particles x 3)
  std::vector<double> w;
  std::vector<Edge> groups[kColourGroups];
  std::vector<uint64_t> busy;
};

Star make_star(int arms) {
  Star s;
  SplitMix64 random{12};
  s.x.assign(3 * size_t(arms + 1), 0.0);
  s.w.assign(size_t(arms + 1), 1.0);
  s.busy.assign(size_t(arms + 1), 0);
  for (int i = 1; i <= arms; ++i) {
    for (int a = 0; a < 3; ++a) s.x[3 * size_t(i) + a] = random.uniform(-1, 1);
  }
  const auto add = [&](uint32_t a, uint32_t b) {
    const uint32_t ends[2] = {a, b};
    const uint8_t c = take_colour(s.busy.data(), ends, 2);
    s.groups[c].push_back({a, b, 0.5, 0.0});
  };
  for (int i = 1; i <= arms; ++i) add(0, uint32_t(i));
  for (int i = 1; i <= arms; ++i) add(uint32_t(i), uint32_t(i % arms + 1));
  return s;
}

void solve(Star& s, const TaskRunner& tasks) {
  for (int it = 0; it < 20; ++it) {
    solve_colour_groups(tasks, 1, [&](uint8_t c) { return uint32_t(s.groups[c].size()); }, [&](uint8_t c, uint32_t i) {
      Edge& e = s.groups[c][i];
      solve_distance(s.x.data(), s.w.data(), e.a, e.b, e.rest, 1e-6, 1.0 / 60.0, e.lambda);
    });
  }
}

}  // namespace

TEST_SUITE("colouring") {
  TEST_CASE("more than 64 constraints on one particle: race-free groups, overflow solved serially, same for 1 and 2 workers") {
    Star one = make_star(100), two = make_star(100);
    // Groups share no particle, except the overflow group; nothing was dropped.
    size_t total = 0;
    for (int c = 0; c < kColourGroups; ++c) {
      std::vector<int> seen(101, 0);
      for (const Edge& e : one.groups[c]) {
        if (c != kOverflowColour) {
          CHECK(seen[e.a]++ == 0);
          CHECK(seen[e.b]++ == 0);
        }
      }
      total += one.groups[c].size();
    }
    CHECK(total == 200);
    CHECK(one.groups[kOverflowColour].size() >= 100 - 63);
    // The same result for one and two workers, bit for bit.
    ThreadRunner runner;
    solve(one, TaskRunner{});
    solve(two, runner.runner());
    CHECK(one.x == two.x);
    // Released colours are taken again.
    const uint32_t ends[2] = {0, 1};
    release_colour(one.busy.data(), ends, 2, 0);
    CHECK(take_colour(one.busy.data(), ends, 2) == 0);
  }
}
