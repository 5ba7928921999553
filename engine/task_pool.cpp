#include "engine/task_pool.h"

#include <algorithm>

namespace dvx {

namespace {

inline void cpu_relax() {
#if defined(__x86_64__) || defined(__i386__)
  __builtin_ia32_pause();
#endif
}

// parallel_for as a job of one batch.
struct PlainCall {
  void (*fn)(uint32_t, uint32_t, void*);
  void* user;
};

void plain_batch(uint32_t, uint32_t begin, uint32_t end, void* user) {
  const PlainCall& c = *static_cast<const PlainCall*>(user);
  c.fn(begin, end, c.user);
}

}  // namespace

TaskPool::TaskPool(int workers) {
  for (int i = 1; i < std::max(1, workers); ++i) threads_.emplace_back([this] { work_loop(); });
}

TaskPool::~TaskPool() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  for (std::thread& t : threads_) t.join();
}

void TaskPool::dispatch(void* context, uint32_t count, uint32_t grain, void (*fn)(uint32_t, uint32_t, void*),
                        void* user) {
  PlainCall call{fn, user};
  const TaskBatch batch{count, grain};
  static_cast<TaskPool*>(context)->run(&batch, 1, plain_batch, &call);
}

void TaskPool::dispatch_batches(void* context, const TaskBatch* batches, uint32_t batch_count, BatchFn fn,
                                void* user) {
  static_cast<TaskPool*>(context)->run(batches, batch_count, fn, user);
}

// Spins briefly, then yields (the machine may have fewer free cores than workers).
void TaskPool::wait_finished(uint32_t target) const {
  for (uint32_t spin = 0; finished_.load(std::memory_order_acquire) < target; ++spin) {
    if (spin < 512) {
      cpu_relax();
    } else {
      std::this_thread::yield();
    }
  }
}

// Takes tickets of the current job until none is left.
void TaskPool::take_tickets() {
  const uint32_t count = uint32_t(tickets_.size());
  while (true) {
    const uint32_t t = next_ticket_.fetch_add(1, std::memory_order_relaxed);
    if (t >= count) return;
    const Ticket& ticket = tickets_[t];
    wait_finished(ticket.wait);
    if (ticket.batch_end == ticket.batch + 1) {
      fn_(ticket.batch, ticket.begin, ticket.end, user_);
    } else {
      for (uint32_t b = ticket.batch; b < ticket.batch_end; ++b) {
        if (batches_[b].count > 0) fn_(b, 0, batches_[b].count, user_);
      }
    }
    finished_.fetch_add(1, std::memory_order_acq_rel);
  }
}

void TaskPool::run(const TaskBatch* batches, uint32_t batch_count, BatchFn fn, void* user) {
  if (batch_count == 0) return;
  const uint32_t workers = uint32_t(threads_.size()) + 1;
  // A worker that woke late for the previous job may still be reading it: wait for it.
  std::unique_lock<std::mutex> lock(mutex_);
  idle_.wait(lock, [&] { return busy_workers_ == 0; });
  // Tickets: chunks of at least `grain` items, about one per thread; runs of one-chunk batches merged.
  batches_.assign(batches, batches + batch_count);
  tickets_.clear();
  bool parallel = false;
  for (uint32_t b = 0; b < batch_count; ++b) {
    const uint32_t count = batches[b].count;
    if (count == 0) continue;
    const uint32_t chunk = std::max<uint32_t>(std::max<uint32_t>(batches[b].grain, 1), (count + workers - 1) / workers);
    const uint32_t wait = uint32_t(tickets_.size());
    if (chunk >= count) {
      // After a ticket of whole batches (one-chunk batches, or a run of them): joins its run.
      Ticket* last = tickets_.empty() ? nullptr : &tickets_.back();
      if (last != nullptr && last->begin == 0 && last->end == batches_[last->batch].count) {
        last->batch_end = b + 1;
      } else {
        tickets_.push_back(Ticket{b, b + 1, 0, count, wait});
      }
      continue;
    }
    parallel = true;
    for (uint32_t begin = 0; begin < count; begin += chunk) {
      tickets_.push_back(Ticket{b, b + 1, begin, std::min(count, begin + chunk), wait});
    }
  }
  fn_ = fn;
  user_ = user;
  next_ticket_.store(0, std::memory_order_relaxed);
  finished_.store(0, std::memory_order_relaxed);
  const bool wake = !threads_.empty() && parallel;  // else everything on the caller, no wake-up
  if (wake) {
    ++generation_;
    published_.store(generation_, std::memory_order_relaxed);
    wakeups_.fetch_add(1, std::memory_order_relaxed);
  }
  lock.unlock();
  if (wake) wake_.notify_all();
  take_tickets();
  // A worker woken for an earlier job may have joined this one and hold a ticket: wait for it too.
  wait_finished(uint32_t(tickets_.size()));
}

void TaskPool::work_loop() {
  uint64_t seen = 0;
  std::unique_lock<std::mutex> lock(mutex_);
  while (true) {
    // A job often follows within microseconds (the surface embedding after a solver step): watch
    // for it a little before sleeping (a condition-variable wake-up costs tens of microseconds).
    // Only a hint: the job is taken under the mutex as below.
    if (generation_ == seen && !stopping_) {
      lock.unlock();
      for (int spin = 0; spin < kWakeSpins && published_.load(std::memory_order_relaxed) == seen; ++spin) cpu_relax();
      lock.lock();
    }
    wake_.wait(lock, [&] { return stopping_ || generation_ != seen; });
    if (stopping_) return;
    seen = generation_;
    ++busy_workers_;
    lock.unlock();
    take_tickets();
    lock.lock();
    --busy_workers_;
    idle_.notify_all();
  }
}

}  // namespace dvx
