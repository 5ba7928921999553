#include "sim/state_hash.h"

#include <cstdio>

namespace dvx {

uint64_t cut_state_hash(const CutState& state) {
  Fnv1a h;
  const CutSurface& s = state.surface;
  // Topology counts first: a difference there shows even when positions happen to agree.
  h.add(uint64_t(state.edge_cuts.size()));
  h.add(uint64_t(state.divided.size()));
  h.add(uint64_t(s.live_vertices()));
  h.add(uint64_t(s.live_triangles()));
  for (size_t slot = 0; slot < s.positions.size(); ++slot) {
    if (s.vertex_piece[slot] == CutSurface::kFreeKey) continue;
    h.add(uint32_t(slot));
    h.bytes(s.positions[slot].data(), 3 * sizeof(float));
  }
  for (const Tri& t : s.triangles) {
    if (t[0] != kDeadIndex) h.bytes(t.data(), sizeof t);
  }
  return h.value;
}

std::string hash_hex(uint64_t hash) {
  char text[17];
  std::snprintf(text, sizeof text, "%016llx", static_cast<unsigned long long>(hash));
  return text;
}

}  // namespace dvx
