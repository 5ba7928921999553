// A tiny portable random generator (splitmix64): the same numbers on every platform and standard
// library, so sampling, tests and benchmarks are reproducible from a seed. Its finaliser (mix64) is
// also the hash of the hash tables and the state hash.
#pragma once

#include <cstdint>

namespace dvx {

// splitmix64's finaliser: spreads a 64-bit value over all bits (dense lattice ids, coordinate bits).
inline uint64_t mix64(uint64_t z) {
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

struct SplitMix64 {
  uint64_t state;
  uint64_t next() { return mix64(state += 0x9E3779B97F4A7C15ull); }
  // Uniform in [0, 1) with 53 random bits.
  double uniform() { return static_cast<double>(next() >> 11) * 0x1.0p-53; }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
};

}  // namespace dvx
