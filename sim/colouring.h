// Constraint colouring for parallel Gauss-Seidel: constraints of one colour share no particle, so a
// colour group can be solved by any number of workers with bit-identical results. Greedy over a
// 63-bit per-particle mask of colours taken; a constraint that finds all 63 taken goes to the
// overflow colour, solved serially after the others (never a silent cap, never a race). Used by the
// PBD solver (sim/pbd.h) for stretching and shape matching, and reusable for contact constraints.
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

// Colours 0..62 are parallel groups; kOverflowColour is solved serially.
constexpr uint8_t kOverflowColour = 63;
constexpr int kColourGroups = 64;

inline uint64_t colour_bit(uint8_t colour) { return colour == kOverflowColour ? 0 : uint64_t(1) << colour; }

// The first colour none of `count` particles has taken (busy: per-particle masks), else the overflow
// colour; marks it taken on them.
inline uint8_t take_colour(uint64_t* busy, const uint32_t* particles, int count) {
  uint64_t taken = 0;
  for (int i = 0; i < count; ++i) taken |= busy[particles[i]];
  const uint64_t free_bits = ~taken & ((uint64_t(1) << kOverflowColour) - 1);
  const uint8_t colour = free_bits == 0 ? kOverflowColour : uint8_t(__builtin_ctzll(free_bits));
  for (int i = 0; i < count; ++i) busy[particles[i]] |= colour_bit(colour);
  return colour;
}

// Gives a constraint's colour back (its particles may take it again).
inline void release_colour(uint64_t* busy, const uint32_t* particles, int count, uint8_t colour) {
  for (int i = 0; i < count; ++i) busy[particles[i]] &= ~colour_bit(colour);
}

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

// Solves colour groups in order: group c has size(c) members; f(c, i) solves member i of group c.
// Groups 0..62 run through the task runner, the overflow group serially.
template <typename Size, typename F>
void solve_colour_groups(const TaskRunner& tasks, uint32_t grain, Size&& size, F&& f) {
  for (uint8_t c = 0; c < kOverflowColour; ++c) parallel(tasks, size(c), grain, [&](uint32_t i) { f(c, i); });
  const uint32_t overflow = size(kOverflowColour);
  for (uint32_t i = 0; i < overflow; ++i) f(kOverflowColour, i);
}

}  // namespace dvx
