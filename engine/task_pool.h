// A small pool of worker threads behind sim's TaskRunner interface (sim owns no threads).
// parallel_for splits [0, count) into chunks that workers and the calling thread take from an
// atomic counter; it returns when every chunk is done. Which thread runs a chunk never changes
// a result: the sim only hands it loops whose iterations are independent.
#pragma once

#include "sim/pbd.h"

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

  TaskRunner runner() { return TaskRunner{this, &TaskPool::dispatch}; }
  int workers() const { return int(threads_.size()) + 1; }

 private:
  static void dispatch(void* context, uint32_t count, uint32_t grain, void (*fn)(uint32_t, uint32_t, void*),
                       void* user);
  void run(uint32_t count, uint32_t grain, void (*fn)(uint32_t, uint32_t, void*), void* user);
  void work_loop();
  void take_chunks();

  std::vector<std::thread> threads_;
  std::mutex mutex_;
  std::condition_variable wake_, done_;
  uint64_t generation_ = 0;  // bumped for every job (guarded by mutex_)
  bool stopping_ = false;
  // The current job (written under mutex_ before the generation bump).
  void (*fn_)(uint32_t, uint32_t, void*) = nullptr;
  void* user_ = nullptr;
  uint32_t count_ = 0, chunk_ = 1, chunks_ = 0;
  std::atomic<uint32_t> next_chunk_{0};
  std::atomic<uint32_t> finished_chunks_{0};
  int busy_workers_ = 0;  // workers inside the current job (guarded by mutex_)
};

}  // namespace dvx
