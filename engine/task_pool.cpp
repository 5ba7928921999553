#include "engine/task_pool.h"

#include <algorithm>

namespace dvx {

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
  static_cast<TaskPool*>(context)->run(count, grain, fn, user);
}

// Takes chunks of the current job until none is left.
void TaskPool::take_chunks() {
  while (true) {
    const uint32_t chunk = next_chunk_.fetch_add(1, std::memory_order_relaxed);
    if (chunk >= chunks_) return;
    const uint32_t begin = chunk * chunk_;
    fn_(begin, std::min(count_, begin + chunk_), user_);
    finished_chunks_.fetch_add(1, std::memory_order_acq_rel);
  }
}

void TaskPool::run(uint32_t count, uint32_t grain, void (*fn)(uint32_t, uint32_t, void*), void* user) {
  if (count == 0) return;
  const uint32_t workers = uint32_t(threads_.size()) + 1;
  const uint32_t chunk = std::max<uint32_t>(std::max<uint32_t>(grain, 1), (count + workers - 1) / workers);
  if (threads_.empty() || chunk >= count) {
    fn(0, count, user);
    return;
  }
  {
    // A worker that woke late for the previous job may still be reading it: wait for it.
    std::unique_lock<std::mutex> lock(mutex_);
    done_.wait(lock, [&] { return busy_workers_ == 0; });
    fn_ = fn;
    user_ = user;
    count_ = count;
    chunk_ = chunk;
    chunks_ = (count + chunk - 1) / chunk;
    next_chunk_.store(0, std::memory_order_relaxed);
    finished_chunks_.store(0, std::memory_order_relaxed);
    ++generation_;
  }
  wake_.notify_all();
  take_chunks();
  // Wait until every chunk is done and no worker still reads the job.
  std::unique_lock<std::mutex> lock(mutex_);
  done_.wait(lock, [&] { return finished_chunks_.load(std::memory_order_acquire) == chunks_ && busy_workers_ == 0; });
}

void TaskPool::work_loop() {
  uint64_t seen = 0;
  std::unique_lock<std::mutex> lock(mutex_);
  while (true) {
    wake_.wait(lock, [&] { return stopping_ || generation_ != seen; });
    if (stopping_) return;
    seen = generation_;
    ++busy_workers_;
    lock.unlock();
    take_chunks();
    lock.lock();
    --busy_workers_;
    done_.notify_all();
  }
}

}  // namespace dvx
