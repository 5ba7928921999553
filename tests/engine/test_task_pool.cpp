// The task pool behind sim's TaskRunner: every index runs exactly once, for any worker count, grain
// and job size, job after job.
#include "engine/task_pool.h"

#include <doctest/doctest.h>

#include <atomic>
#include <chrono>
#include <thread>
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

// A phased job: batch b writes value[b][i] = 1 + (sum of batch b - 1's values), so an item that started
// before every item of the batch before it finished writes a wrong value. The sums grow geometrically
// over many batches: unsigned, so they wrap (defined) instead of overflowing.
struct Phased {
  std::vector<TaskBatch> batches;
  std::vector<std::vector<std::atomic<uint64_t>>> value;
  std::atomic<int> calls_out_of_range{0};
  explicit Phased(const std::vector<TaskBatch>& b) : batches(b), value(b.size()) {
    for (size_t i = 0; i < b.size(); ++i) value[i] = std::vector<std::atomic<uint64_t>>(b[i].count);
  }
  uint64_t sum(uint32_t batch) const {
    uint64_t total = 0;
    for (const std::atomic<uint64_t>& v : value[batch]) total += v.load();
    return total;
  }
};

void phased_chunk(uint32_t batch, uint32_t begin, uint32_t end, void* user) {
  Phased& p = *static_cast<Phased*>(user);
  if (batch >= p.batches.size() || begin >= end || end > p.batches[batch].count) {
    p.calls_out_of_range.fetch_add(1);
    return;
  }
  // The first chunk of a batch sleeps, so that another thread reaches the next batch before this
  // one is done (a missing barrier shows as a wrong sum).
  if (begin == 0 && end < p.batches[batch].count) std::this_thread::sleep_for(std::chrono::microseconds(300));
  const uint64_t before = batch == 0 ? 0 : p.sum(batch - 1);
  for (uint32_t i = begin; i < end; ++i) p.value[batch][i].fetch_add(1 + before);
}

// What a correct run of the job writes: batch b's items are 1 + sum of batch b - 1 (skipping nothing:
// an empty batch sums to 0).
std::vector<uint64_t> expected_sums(const std::vector<TaskBatch>& batches) {
  std::vector<uint64_t> sums;
  uint64_t previous = 0;
  for (const TaskBatch& b : batches) {
    sums.push_back(uint64_t(b.count) * (1 + previous));
    previous = sums.back();
  }
  return sums;
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

  TEST_CASE("run_batches: every item once, each batch after the whole batch before it, for any worker count") {
    // Big parallel batches, one-chunk batches (merged into runs), empty batches, a serial overflow.
    const std::vector<TaskBatch> job = {{1000, 16}, {3, 1024}, {0, 16}, {5, 1024}, {257, 8}, {1, ~0u},
                                        {64, 1},   {0, 1},    {2, 1024}, {4099, 64}, {7, 1}};
    const std::vector<uint64_t> want = expected_sums(job);
    for (int workers : {1, 2, 4}) {
      TaskPool pool(workers);
      const TaskRunner runner = pool.runner();
      REQUIRE((runner.run_batches != nullptr));
      for (int repeat = 0; repeat < 20; ++repeat) {
        CAPTURE(workers);
        CAPTURE(repeat);
        Phased p(job);
        runner.run_batches(runner.context, job.data(), uint32_t(job.size()), phased_chunk, &p);
        CHECK(p.calls_out_of_range.load() == 0);
        for (uint32_t b = 0; b < job.size(); ++b) {
          CAPTURE(b);
          CHECK(p.sum(b) == want[b]);
        }
      }
    }
  }

  TEST_CASE("run_batches wakes the workers once per job, and not at all when no batch is worth sharing") {
    TaskPool pool(2);
    const TaskRunner runner = pool.runner();
    const std::vector<TaskBatch> parallel_job(40, TaskBatch{512, 16});
    const std::vector<TaskBatch> serial_job(40, TaskBatch{512, 1024});
    for (int job = 0; job < 10; ++job) {
      Phased p(parallel_job);
      runner.run_batches(runner.context, parallel_job.data(), uint32_t(parallel_job.size()), phased_chunk, &p);
      CHECK(p.sum(39) == expected_sums(parallel_job)[39]);
    }
    CHECK(pool.wakeups() == 10);
    Phased p(serial_job);
    runner.run_batches(runner.context, serial_job.data(), uint32_t(serial_job.size()), phased_chunk, &p);
    CHECK(p.sum(39) == expected_sums(serial_job)[39]);
    CHECK(pool.wakeups() == 10);
  }

  TEST_CASE("run_batches through the sim helper without run_batches (parallel_for per batch) and serially") {
    const std::vector<TaskBatch> job = {{100, 8}, {0, 8}, {9, 1}, {1, 1}, {300, 1000}};
    const std::vector<uint64_t> want = expected_sums(job);
    TaskPool pool(3);
    TaskRunner only_parallel_for = pool.runner();
    only_parallel_for.run_batches = nullptr;
    for (const TaskRunner& runner : {only_parallel_for, TaskRunner{}}) {
      Phased p(job);
      run_batches(runner, job.data(), uint32_t(job.size()),
                  [&](uint32_t batch, uint32_t begin, uint32_t end) { phased_chunk(batch, begin, end, &p); });
      for (uint32_t b = 0; b < job.size(); ++b) CHECK(p.sum(b) == want[b]);
    }
  }

  TEST_CASE("jobs the caller runs alone between shared ones: a worker that wakes late runs none of their items") {
    // A shared job wakes the workers; the one-chunk job after it must not be joined by a worker that
    // is only now waking for the first (it would run the chunk a second time).
    for (int workers : {2, 4}) {
      TaskPool pool(workers);
      const TaskRunner runner = pool.runner();
      Counts shared(256), alone(64);
      for (int job = 0; job < 500; ++job) {
        runner.parallel_for(runner.context, 256, 1, count_range, &shared);
        runner.parallel_for(runner.context, 64, 1000, count_range, &alone);
      }
      int wrong = 0;
      for (uint32_t i = 0; i < 256; ++i) wrong += shared.hits[i].load() != 500;
      for (uint32_t i = 0; i < 64; ++i) wrong += alone.hits[i].load() != 500;
      CAPTURE(workers);
      CHECK(wrong == 0);
    }
  }

  TEST_CASE("the pool's counters add up: every chunk counted once, stages per job, workers' CPU time") {
    TaskPool pool(2);
    const TaskRunner runner = pool.runner();
    // 3 shared batches (8 chunks each with 2 workers), then 2 one-chunk batches merged into one stage.
    const std::vector<TaskBatch> job = {{4096, 16}, {4096, 16}, {4096, 16}, {5, 100}, {7, 100}};
    for (int repeat = 0; repeat < 50; ++repeat) {
      Phased p(job);
      runner.run_batches(runner.context, job.data(), uint32_t(job.size()), phased_chunk, &p);
      CHECK(p.sum(4) == expected_sums(job)[4]);
    }
    const TaskPoolStats stats = pool.stats();
    REQUIRE(stats.threads.size() == 2);
    CHECK(stats.jobs == 50);
    CHECK(stats.wakeups == 50);
    CHECK(stats.stages == 50 * 4);
    const uint64_t per_job = 3 * 2 * TaskPool::kChunksPerThread + 1;
    CHECK(stats.threads[0].chunks + stats.threads[1].chunks == 50 * per_job);
    CHECK(stats.threads[0].stolen <= stats.threads[0].chunks);
    CHECK(stats.threads[1].cpu_s >= 0.0);
    CHECK(stats.threads[0].cpu_s == 0.0);
  }
}
