// A small pool of worker threads behind sim's TaskRunner interface (sim owns no threads).
// A job is a list of batches run in order with a barrier between them (parallel_for is a job of one
// batch). Each batch is cut into chunks; the chunks of the whole job are numbered in order as
// *tickets* that the workers and the calling thread take from one atomic counter, and a ticket
// starts once every ticket of the earlier batches is done (one atomic count of finished tickets).
// So a whole solver step is one wake-up of the workers, a barrier costs two atomic operations, and a
// thread that is descheduled holds up the others only while it holds a ticket (it never has to
// "arrive" at a barrier: a late thread finds the tickets gone and leaves). Consecutive one-chunk
// batches share one ticket (no barrier between them: they run on one thread in order). Which thread
// runs a ticket never changes a result: the sim only hands it batches whose items are independent.
#pragma once

#include "sim/colouring.h"

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <thread>
#include <vector>

namespace dvx {

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

 private:
  using BatchFn = void (*)(uint32_t batch, uint32_t begin, uint32_t end, void* user);
  // A chunk [begin, end) of batch `batch`, or (batch_end > batch + 1) the whole batches
  // [batch, batch_end) one after the other; it starts when `wait` tickets are finished.
  struct Ticket {
    uint32_t batch, batch_end, begin, end, wait;
  };

  static void dispatch(void* context, uint32_t count, uint32_t grain, void (*fn)(uint32_t, uint32_t, void*),
                       void* user);
  static void dispatch_batches(void* context, const TaskBatch* batches, uint32_t batch_count, BatchFn fn,
                               void* user);
  void run(const TaskBatch* batches, uint32_t batch_count, BatchFn fn, void* user);
  void work_loop();
  void take_tickets();
  void wait_finished(uint32_t target) const;

  std::vector<std::thread> threads_;
  std::mutex mutex_;
  std::condition_variable wake_, idle_;
  uint64_t generation_ = 0;  // bumped for every job that wakes the workers (guarded by mutex_)
  std::atomic<uint64_t> published_{0};  // generation_, readable without the mutex (a spinning worker's hint)
  static constexpr int kWakeSpins = 2000;  // pauses a worker watches for the next job before sleeping
  bool stopping_ = false;
  int busy_workers_ = 0;     // workers inside the current job (guarded by mutex_)
  std::atomic<uint64_t> wakeups_{0};
  // The current job (written under mutex_ while no worker is inside a job, before the bump).
  BatchFn fn_ = nullptr;
  void* user_ = nullptr;
  std::vector<TaskBatch> batches_;
  std::vector<Ticket> tickets_;
  std::atomic<uint32_t> next_ticket_{0};
  std::atomic<uint32_t> finished_{0};
};

}  // namespace dvx
