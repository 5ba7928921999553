// Constraint colouring for parallel Gauss-Seidel: constraints of one colour share no particle, so a
// colour group can be solved by any number of workers with bit-identical results. Greedy over a
// 63-bit per-particle mask of colours taken; a constraint that finds all 63 taken goes to the
// overflow colour, solved serially after the others (never a silent cap, never a race). Used by the
// PBD solver (sim/pbd.h) for stretching and shape matching, and reusable for contact constraints.
#pragma once

#include "sim/tasks.h"

#include <cstdint>
#include <type_traits>

namespace dvx {

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

// Solves colour groups in order: group c has size(c) members; f(c, i) solves member i of group c.
// Groups 0..62 run through the task runner, the overflow group serially.
template <typename Size, typename F>
void solve_colour_groups(const TaskRunner& tasks, uint32_t grain, Size&& size, F&& f) {
  for (uint8_t c = 0; c < kOverflowColour; ++c) parallel(tasks, size(c), grain, [&](uint32_t i) { f(c, i); });
  const uint32_t overflow = size(kOverflowColour);
  for (uint32_t i = 0; i < overflow; ++i) f(kOverflowColour, i);
}

}  // namespace dvx
