#include "engine/task_pool.h"

#include <algorithm>
#include <chrono>
#include <ctime>

#include <pthread.h>

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

// Pauses a barrier watches before it starts yielding: a few tens of microseconds, longer than a
// normal wait at a barrier (a chunk is a few microseconds), shorter than a time slice.
constexpr uint32_t kBarrierSpins = 4096;
constexpr uint64_t kLongWaitNs = 1000000;

// First chunk of thread t's home range among the n chunks of a stage (n / workers a thread; the
// caller, thread 0, has the one chunk of a one-chunk stage).
inline uint32_t home_begin(uint32_t t, uint32_t n, uint32_t workers) { return n == 1 ? std::min(t, 1u) : t * (n / workers); }
// The thread whose home range holds chunk i of a stage's n.
inline uint32_t chunk_owner(uint32_t i, uint32_t n, uint32_t workers) { return n == 1 ? 0 : i / (n / workers); }

// Pauses a thread that has run out of chunks watches another that is still claiming its own before
// it takes one of them: a few of its chunks' time.
constexpr uint32_t kStealPatience = 256;

}  // namespace

TaskPool::TaskPool(int workers) : counters_(new Counters[size_t(std::max(1, workers))]) {
  for (int i = 1; i < std::max(1, workers); ++i) threads_.emplace_back([this, i] { work_loop(i); });
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

TaskPoolStats TaskPool::stats() const {
  TaskPoolStats s;
  s.jobs = jobs_.load(std::memory_order_relaxed);
  s.wakeups = wakeups_.load(std::memory_order_relaxed);
  s.stages = stages_.load(std::memory_order_relaxed);
  s.late_workers = late_workers_.load(std::memory_order_relaxed);
  for (int t = 0; t < workers(); ++t) {
    const Counters& c = counters_[size_t(t)];
    TaskPoolThreadStats out;
    out.jobs = c.jobs.load(std::memory_order_relaxed);
    out.chunks = c.chunks.load(std::memory_order_relaxed);
    out.stolen = c.stolen.load(std::memory_order_relaxed);
    out.waits = c.waits.load(std::memory_order_relaxed);
    out.long_waits = c.long_waits.load(std::memory_order_relaxed);
    out.wait_ms = 1e-6 * double(c.wait_ns.load(std::memory_order_relaxed));
    clockid_t clock;
    timespec ts;
    if (t > 0 && pthread_getcpuclockid(const_cast<std::thread&>(threads_[size_t(t - 1)]).native_handle(), &clock) == 0 &&
        clock_gettime(clock, &ts) == 0) {
      out.cpu_s = double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
    }
    s.threads.push_back(out);
  }
  return s;
}

// Spins, then yields (the machine may have fewer free cores than threads). A waiting thread holds
// no chunk, so yielding delays nobody but itself.
void TaskPool::wait_done(uint32_t target, Counters& counters) const {
  if (done_.load(std::memory_order_acquire) >= target) return;
  const auto start = std::chrono::steady_clock::now();
  for (uint32_t spin = 0; done_.load(std::memory_order_acquire) < target; ++spin) {
    if (spin < kBarrierSpins) {
      cpu_relax();
    } else {
      std::this_thread::yield();
    }
  }
  const uint64_t ns = uint64_t(std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - start).count());
  counters.waits.fetch_add(1, std::memory_order_relaxed);
  counters.wait_ns.fetch_add(ns, std::memory_order_relaxed);
  if (ns > kLongWaitNs) counters.long_waits.fetch_add(1, std::memory_order_relaxed);
}

// Takes a chunk for thread t (its flag: t + 1, so the others see whether its owner has started).
bool TaskPool::claim(uint32_t chunk, uint32_t t) {
  std::atomic<uint32_t>& flag = claimed_[chunk];
  return flag.load(std::memory_order_relaxed) == 0 && flag.exchange(t + 1, std::memory_order_relaxed) == 0;
}

void TaskPool::run_chunk(const Chunk& c) const {
  if (c.batch_end == c.batch + 1) {
    fn_(c.batch, c.begin, c.end, user_);
    return;
  }
  for (uint32_t b = c.batch; b < c.batch_end; ++b) {
    if (batches_[b].count > 0) fn_(b, 0, batches_[b].count, user_);
  }
}

// Cuts the job into stages and chunks (see the header); true when a stage is worth sharing.
bool TaskPool::plan(const TaskBatch* batches, uint32_t batch_count) {
  const uint32_t workers = uint32_t(threads_.size()) + 1;
  batches_.assign(batches, batches + batch_count);
  chunks_.clear();
  stage_first_.clear();
  bool parallel = false;
  for (uint32_t b = 0; b < batch_count; ++b) {
    const uint32_t count = batches[b].count;
    if (count == 0) continue;
    const uint32_t grain = std::max<uint32_t>(batches[b].grain, 1);
    // Worth sharing: at least `workers` chunks of `grain` items; then kChunksPerThread chunks a
    // thread, fewer where they would be under `grain`, the same number for each thread (so every
    // thread's home range is the same share of every batch).
    const uint32_t per_thread = std::min<uint32_t>(count / grain / workers, kChunksPerThread);
    const uint32_t n = per_thread * workers;
    if (per_thread == 0 || workers == 1) {
      // One chunk: joins the stage before when that is a run of whole batches too.
      const bool joins = !chunks_.empty() && stage_first_.back() + 1 == chunks_.size() && chunks_.back().begin == 0 &&
                         chunks_.back().end == batches_[chunks_.back().batch].count;
      if (joins) {
        chunks_.back().batch_end = b + 1;
      } else {
        stage_first_.push_back(uint32_t(chunks_.size()));
        chunks_.push_back(Chunk{b, b + 1, 0, count});
      }
      continue;
    }
    // n chunks of about equal size (each at least `grain`).
    parallel = true;
    stage_first_.push_back(uint32_t(chunks_.size()));
    for (uint32_t c = 0; c < n; ++c) {
      chunks_.push_back(Chunk{b, b + 1, uint32_t(uint64_t(count) * c / n), uint32_t(uint64_t(count) * (c + 1) / n)});
    }
  }
  stage_first_.push_back(uint32_t(chunks_.size()));
  if (claimed_capacity_ < chunks_.size()) {
    claimed_capacity_ = std::max(chunks_.size(), 2 * claimed_capacity_);
    claimed_.reset(new std::atomic<uint32_t>[claimed_capacity_]);
  }
  for (size_t c = 0; c < chunks_.size(); ++c) claimed_[c].store(0, std::memory_order_relaxed);
  return parallel;
}

// One thread's part of the current job: every stage in order, its home chunks first, then what is
// left of the others' from the far end; the finished chunks counted once per stage.
void TaskPool::take_part(int self) {
  Counters& counters = counters_[size_t(self)];
  counters.jobs.fetch_add(1, std::memory_order_relaxed);
  const uint32_t workers = uint32_t(threads_.size()) + 1;
  const uint32_t t = uint32_t(self);
  const uint32_t stages = uint32_t(stage_first_.size()) - 1;
  for (uint32_t s = 0; s < stages; ++s) {
    const uint32_t first = stage_first_[s], end = stage_first_[s + 1];
    if (done_.load(std::memory_order_acquire) >= end) continue;  // a late thread: done without it
    wait_done(first, counters);
    const uint32_t n = end - first;
    const uint32_t own_begin = first + home_begin(t, n, workers), own_end = first + home_begin(t + 1, n, workers);
    uint32_t mine = 0, stolen = 0;
    for (uint32_t c = own_begin; c < own_end; ++c) {
      if (!claim(c, t)) break;  // the others have reached my range from its end: the rest is theirs
      run_chunk(chunks_[c]);
      ++mine;
    }
    // Then the chunks left, the last first: at once those of a thread that has not started this
    // stage (asleep, descheduled, late); those of one that has, only once it has claimed nothing new
    // for kStealPatience pauses (its lines are in its cache: a chunk taken from it runs slower here
    // than there, and holds up the barrier, unless it is stuck).
    uint32_t watched_front = ~0u, spins = 0;
    while (true) {
      uint32_t c = end;
      while (c > first && claimed_[c - 1].load(std::memory_order_relaxed) != 0) --c;
      if (c == first) break;
      const uint32_t chunk = c - 1;
      const uint32_t owner = chunk_owner(chunk - first, n, workers);
      const uint32_t victim_begin = first + home_begin(owner, n, workers);
      if (owner != t && claimed_[victim_begin].load(std::memory_order_relaxed) == owner + 1) {
        uint32_t front = victim_begin;
        while (front < chunk && claimed_[front].load(std::memory_order_relaxed) != 0) ++front;
        if (front != watched_front) {
          watched_front = front;
          spins = 0;
        }
        if (spins++ < kStealPatience) {
          cpu_relax();
          continue;
        }
      }
      if (!claim(chunk, t)) continue;
      run_chunk(chunks_[chunk]);
      ++mine;
      stolen += owner != t ? 1 : 0;
      watched_front = ~0u;
    }
    if (mine > 0) {
      // The counters before the count of finished chunks: the caller reads them once it saw all done.
      counters.chunks.fetch_add(mine, std::memory_order_relaxed);
      counters.stolen.fetch_add(stolen, std::memory_order_relaxed);
      done_.fetch_add(mine, std::memory_order_acq_rel);
    }
  }
}

void TaskPool::run(const TaskBatch* batches, uint32_t batch_count, BatchFn fn, void* user) {
  if (batch_count == 0) return;
  jobs_.fetch_add(1, std::memory_order_relaxed);
  // A worker that woke late for the previous job may still be reading it: wait for it.
  std::unique_lock<std::mutex> lock(mutex_);
  if (busy_workers_ != 0) {
    late_workers_.fetch_add(1, std::memory_order_relaxed);
    idle_.wait(lock, [&] { return busy_workers_ == 0; });
  }
  const bool parallel = plan(batches, batch_count);
  stages_.fetch_add(stage_first_.size() - 1, std::memory_order_relaxed);
  fn_ = fn;
  user_ = user;
  done_.store(0, std::memory_order_relaxed);
  const bool wake = !threads_.empty() && parallel;  // else everything on the caller, no wake-up
  ++job_id_;
  if (!wake) {
    lock.unlock();
    Counters& counters = counters_[0];
    counters.jobs.fetch_add(1, std::memory_order_relaxed);
    counters.chunks.fetch_add(chunks_.size(), std::memory_order_relaxed);
    for (const Chunk& c : chunks_) run_chunk(c);
    return;
  }
  ++generation_;
  wake_job_ = job_id_;
  published_.store(generation_, std::memory_order_relaxed);
  wakeups_.fetch_add(1, std::memory_order_relaxed);
  lock.unlock();
  wake_.notify_all();
  take_part(0);
  // The workers may still be running their last chunks.
  wait_done(uint32_t(chunks_.size()), counters_[0]);
}

void TaskPool::work_loop(int self) {
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
    if (job_id_ != wake_job_) continue;  // woke late: the job now is the caller's alone
    ++busy_workers_;
    lock.unlock();
    take_part(self);
    lock.lock();
    --busy_workers_;
    idle_.notify_all();
  }
}

}  // namespace dvx
