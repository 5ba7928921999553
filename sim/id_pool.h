// Stable slots with free lists: the surface's vertices and quads, the pieces, particles and stretch
// handles keep their index for life (other arrays and caches refer to them), and a freed slot is
// reused before the arrays grow. The one way a slot is taken from a free list.
#pragma once

#include <cstdint>
#include <vector>

namespace dvx {

// Takes the most recently freed slot into `slot` and returns true; false when there is none (the
// caller appends a new slot to its arrays).
inline bool take_free_slot(std::vector<uint32_t>& free_slots, uint32_t& slot) {
  if (free_slots.empty()) return false;
  slot = free_slots.back();
  free_slots.pop_back();
  return true;
}

}  // namespace dvx
