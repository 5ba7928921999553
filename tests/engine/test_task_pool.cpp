// The task pool behind sim's TaskRunner: every index runs exactly once, for any worker count, grain
// and job size, job after job.
#include "engine/task_pool.h"

#include <doctest/doctest.h>

#include <atomic>
#include <vector>

using namespace dvx;

namespace {

struct Counts {
  std::vector<std::atomic<int>> hits;
  explicit Counts(uint32_t n) : hits(n) {}
};

void count_range(uint32_t begin, uint32_t end, void* user) {
  Counts& c = *static_cast<Counts*>(user);
  for (uint32_t i = begin; i < end; ++i) c.hits[i].fetch_add(1);
}

}  // namespace

TEST_SUITE("task_pool") {
  TEST_CASE("every index runs exactly once for any worker count, grain and size") {
    for (int workers : {1, 2, 4}) {
      TaskPool pool(workers);
      CHECK(pool.workers() == workers);
      const TaskRunner runner = pool.runner();
      for (uint32_t count : {0u, 1u, 7u, 1000u, 4099u}) {
        for (uint32_t grain : {1u, 16u, 5000u}) {
          CAPTURE(workers);
          CAPTURE(count);
          CAPTURE(grain);
          Counts c(count);
          runner.parallel_for(runner.context, count, grain, count_range, &c);
          int wrong = 0;
          for (uint32_t i = 0; i < count; ++i) wrong += c.hits[i].load() != 1;
          CHECK(wrong == 0);
        }
      }
    }
  }

  TEST_CASE("many small jobs in a row all complete") {
    TaskPool pool(3);
    const TaskRunner runner = pool.runner();
    Counts c(64);
    for (int job = 0; job < 2000; ++job) runner.parallel_for(runner.context, 64, 4, count_range, &c);
    int wrong = 0;
    for (uint32_t i = 0; i < 64; ++i) wrong += c.hits[i].load() != 2000;
    CHECK(wrong == 0);
  }
}
