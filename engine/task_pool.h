// A small pool of worker threads behind sim's TaskRunner interface (sim owns no threads).
// A job is a list of batches run in order with a barrier between them (parallel_for is a job of one
// batch); a whole solver step is one job, so one wake-up of the workers. The job is cut into
// *stages*: a batch worth sharing is one stage of several chunks, and a run of consecutive batches
// that are not (one chunk each) is one stage of one chunk that runs them in order on one thread (no
// barrier between them). The chunks are numbered in order; stage s may start once every chunk
// before it is done (one atomic count of finished chunks: a barrier is that count reaching a number).
//
// Why this shape (measured on the default recording, issue 17; README "Task pool"):
// - A thread claims a chunk only once the chunk may run. A thread that claimed work and then waited
//   for the barrier (the former ticket scheme) held its chunk while it was descheduled, and the
//   other thread waited a whole time slice (the 2-20 ms spikes on a loaded machine). Now a waiting
//   thread holds nothing: a descheduled worker only means the caller does its chunks.
// - Each thread has a home range in every stage (chunks [t n / W, (t + 1) n / W), rounded up), runs
//   it first, in order, then takes what is left from the far end of the others'. The constraints of
//   a colour are stored roughly in space order, so a thread keeps working on the same particles
//   from colour to colour and only the lines at the range boundaries move between the cores.
// - kChunksPerThread chunks a thread per stage: enough that a thread that arrives late, or runs
//   slower, is made up for by the other taking its last chunks; few enough that the claims (one
//   atomic exchange a chunk) and the stolen lines stay small.
// Which thread runs a chunk never changes a result: the sim only hands it batches whose items are
// independent, and the chunk bounds depend only on the batch and the worker count.
#pragma once

#include "sim/tasks.h"

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

namespace dvx {

// Counters since the pool was made (benchmarks and tests read them; summary.json "pool").
struct TaskPoolThreadStats {
  uint64_t jobs = 0;        // jobs this thread took part in
  uint64_t chunks = 0;      // chunks it ran
  uint64_t stolen = 0;      // of those, outside its home range
  uint64_t waits = 0;       // barriers it reached before they opened
  uint64_t long_waits = 0;  // of those, waits over 1 ms (the other thread was descheduled in a chunk)
  double wait_ms = 0.0;     // wall time in those waits
  double cpu_s = 0.0;       // the thread's CPU time (workers; the caller's thread: 0, it does other work too)
};
struct TaskPoolStats {
  uint64_t jobs = 0;         // run_batches / parallel_for calls
  uint64_t wakeups = 0;      // jobs that woke the workers (the others ran on the caller alone)
  uint64_t stages = 0;       // stages of all jobs (barriers + jobs)
  uint64_t late_workers = 0; // jobs that had to wait for a worker still leaving the job before
  std::vector<TaskPoolThreadStats> threads;  // [0] the caller, then the workers
};

class TaskPool {
 public:
  // `workers` threads in all, counting the caller (1: everything runs on the caller).
  explicit TaskPool(int workers);
  ~TaskPool();
  TaskPool(const TaskPool&) = delete;
  TaskPool& operator=(const TaskPool&) = delete;

  TaskRunner runner() { return TaskRunner{this, &TaskPool::dispatch, &TaskPool::dispatch_batches}; }
  int workers() const { return int(threads_.size()) + 1; }
  // Jobs that woke the workers since construction (tests and benchmarks count dispatches).
  uint64_t wakeups() const { return wakeups_.load(std::memory_order_relaxed); }
  TaskPoolStats stats() const;

  static constexpr uint32_t kChunksPerThread = 4;

 private:
  using BatchFn = void (*)(uint32_t batch, uint32_t begin, uint32_t end, void* user);
  // [begin, end) of batch `batch`, or (batch_end > batch + 1) the whole batches [batch, batch_end).
  struct Chunk {
    uint32_t batch, batch_end, begin, end;
  };
  // One thread's counters: written by that thread only (relaxed atomics so others may read them),
  // a cache line each.
  struct alignas(64) Counters {
    std::atomic<uint64_t> jobs{0}, chunks{0}, stolen{0}, waits{0}, long_waits{0}, wait_ns{0};
  };

  static void dispatch(void* context, uint32_t count, uint32_t grain, void (*fn)(uint32_t, uint32_t, void*),
                       void* user);
  static void dispatch_batches(void* context, const TaskBatch* batches, uint32_t batch_count, BatchFn fn,
                               void* user);
  void run(const TaskBatch* batches, uint32_t batch_count, BatchFn fn, void* user);
  bool plan(const TaskBatch* batches, uint32_t batch_count);
  void run_chunk(const Chunk& c) const;
  void work_loop(int self);
  void take_part(int self);
  bool claim(uint32_t chunk, uint32_t t);
  void wait_done(uint32_t target, Counters& counters) const;

  std::vector<std::thread> threads_;
  std::mutex mutex_;
  std::condition_variable wake_, idle_;
  uint64_t generation_ = 0;  // bumped for every job that wakes the workers (guarded by mutex_)
  // Every job, and the last that woke the workers (guarded by mutex_): a worker that wakes late
  // joins the current job only when it is one for the workers (a job the caller runs alone claims
  // no chunk).
  uint64_t job_id_ = 0, wake_job_ = 0;
  std::atomic<uint64_t> published_{0};  // generation_, readable without the mutex (a spinning worker's hint)
  static constexpr int kWakeSpins = 2000;  // pauses a worker watches for the next job before sleeping
  bool stopping_ = false;
  int busy_workers_ = 0;  // workers inside the current job (guarded by mutex_)
  std::atomic<uint64_t> wakeups_{0}, jobs_{0}, stages_{0}, late_workers_{0};
  std::unique_ptr<Counters[]> counters_;  // per thread, [0] the caller
  // The current job (written under mutex_ while no worker is inside a job, before the bump).
  BatchFn fn_ = nullptr;
  void* user_ = nullptr;
  std::vector<TaskBatch> batches_;
  std::vector<Chunk> chunks_;
  std::vector<uint32_t> stage_first_;  // first chunk of each stage, then the chunk count
  std::unique_ptr<std::atomic<uint32_t>[]> claimed_;  // per chunk: taken by a thread
  size_t claimed_capacity_ = 0;
  std::atomic<uint32_t> done_{0};  // chunks finished
};

}  // namespace dvx
