// State hashes for determinism checks (recordings store one every N steps; replay compares).
#pragma once

#include "sim/cut.h"

#include <cstdint>
#include <string>

namespace dvx {

// FNV-1a 64-bit, incremental.
struct Fnv1a {
  uint64_t value = 0xcbf29ce484222325ull;
  void bytes(const void* data, size_t size) {
    const auto* p = static_cast<const unsigned char*>(data);
    for (size_t i = 0; i < size; ++i) {
      value ^= p[i];
      value *= 0x100000001b3ull;
    }
  }
  template <typename T>
  void add(const T& x) {
    bytes(&x, sizeof x);
  }
};

// Hash of the cut state: topology counts, then the live surface's vertex positions and oriented
// triangles, combined independently of the slots that hold them (bit-exact positions count).
uint64_t cut_state_hash(const CutState& state);

// 16 lowercase hex digits.
std::string hash_hex(uint64_t hash);

}  // namespace dvx
