// The task interface sim/ runs its parallel loops through (sim/ owns no threads: the engine's pool,
// or a test's runner, implements it). Public: the engine includes it; colouring.h builds on it.
#pragma once

#include <cstdint>
#include <type_traits>

namespace dvx {

// One batch of a phased job (TaskRunner::run_batches): `count` items, in chunks of at least `grain`
// items (grain >= count: one chunk, run by one thread).
struct TaskBatch {
  uint32_t count;
  uint32_t grain;
};

// The task interface. parallel_for: run fn(begin, end, user) over chunks of [0, count), possibly
// concurrently, and return when all are done. run_batches: the same for `batches` batches in order
// with a barrier between them (every chunk of batch b is done before any of b + 1 starts),
// fn(batch, begin, end, user) per chunk: one wake-up of the workers for a whole solver step instead
// of one per colour group. Null parallel_for: serial; null run_batches: parallel_for per batch.
struct TaskRunner {
  void* context = nullptr;
  void (*parallel_for)(void* context, uint32_t count, uint32_t grain,
                       void (*fn)(uint32_t begin, uint32_t end, void* user), void* user) = nullptr;
  void (*run_batches)(void* context, const TaskBatch* batches, uint32_t batch_count,
                      void (*fn)(uint32_t batch, uint32_t begin, uint32_t end, void* user), void* user) = nullptr;
};


// Runs f(i) for i in [0, count) through the task runner (chunks of `grain`).
template <typename F>
void parallel(const TaskRunner& tasks, uint32_t count, uint32_t grain, F&& f) {
  if (count == 0) return;
  if (tasks.parallel_for == nullptr) {
    for (uint32_t i = 0; i < count; ++i) f(i);
    return;
  }
  tasks.parallel_for(
      tasks.context, count, grain,
      [](uint32_t begin, uint32_t end, void* user) {
        F& fn = *static_cast<F*>(user);
        for (uint32_t i = begin; i < end; ++i) fn(i);
      },
      &f);
}

// Runs f(batch, begin, end) over the chunks of batches [0, batch_count) in order, a barrier between
// batches (TaskRunner::run_batches; without it, parallel_for per batch; without that, serially).
template <typename F>
void run_batches(const TaskRunner& tasks, const TaskBatch* batches, uint32_t batch_count, F&& f) {
  if (batch_count == 0) return;
  using Fn = std::remove_reference_t<F>;
  if (tasks.run_batches != nullptr) {
    tasks.run_batches(
        tasks.context, batches, batch_count,
        [](uint32_t batch, uint32_t begin, uint32_t end, void* user) { (*static_cast<Fn*>(user))(batch, begin, end); },
        const_cast<void*>(static_cast<const void*>(&f)));
    return;
  }
  for (uint32_t b = 0; b < batch_count; ++b) {
    const uint32_t count = batches[b].count;
    if (count == 0) continue;
    if (tasks.parallel_for == nullptr || batches[b].grain >= count) {
      f(b, 0u, count);
      continue;
    }
    struct Call {
      Fn* fn;
      uint32_t batch;
    } call{&f, b};
    tasks.parallel_for(
        tasks.context, count, batches[b].grain,
        [](uint32_t begin, uint32_t end, void* user) {
          Call& c = *static_cast<Call*>(user);
          (*c.fn)(c.batch, begin, end);
        },
        &call);
  }
}

}  // namespace dvx
