#include "sim/state_hash.h"

#include "sim/random.h"

#include <cstdio>
#include <vector>

namespace dvx {

namespace {

uint64_t position_hash(const Vec3f& p) {
  Fnv1a h;
  h.bytes(p.data(), 3 * sizeof(float));
  return mix64(h.value);
}

}  // namespace

uint64_t cut_state_hash(const CutState& state) {
  const CutSurface& s = state.surface;
  // Topology counts: a difference there shows even when positions happen to agree.
  Fnv1a h;
  h.add(uint64_t(state.edge_cuts.size()));
  h.add(uint64_t(state.divided.size()));
  h.add(uint64_t(s.live_vertices()));
  h.add(uint64_t(s.live_triangles()));
  // Vertices and triangles are summed as mixed hashes of their geometry, so the hash depends on
  // the surface itself, not on which slots hold it (slot order is an implementation detail).
  // Each slot's position hash once (a vertex serves ~6 triangles): every slot, live or free, so a
  // triangle's corners need no check; only live slots enter the sum.
  std::vector<uint64_t> corner(s.positions.size());
  for (size_t slot = 0; slot < s.positions.size(); ++slot) corner[slot] = position_hash(s.positions[slot]);
  uint64_t vertices = 0, triangles = 0;
  for (size_t slot = 0; slot < s.positions.size(); ++slot) {
    if (s.vertex_piece[slot] != CutSurface::kFreeKey) vertices += corner[slot];
  }
  for (const Tri& t : s.triangles) {
    if (t[0] == kDeadIndex) continue;
    // Rotate so the smallest corner hash comes first (keeps the orientation).
    const uint64_t c[3] = {corner[t[0]], corner[t[1]], corner[t[2]]};
    const int first = c[0] <= c[1] && c[0] <= c[2] ? 0 : (c[1] <= c[2] ? 1 : 2);
    triangles += mix64(c[first] ^ mix64(c[(first + 1) % 3] ^ mix64(c[(first + 2) % 3])));
  }
  h.add(vertices);
  h.add(triangles);
  return h.value;
}

std::string hash_hex(uint64_t hash) {
  char text[17];
  std::snprintf(text, sizeof text, "%016llx", static_cast<unsigned long long>(hash));
  return text;
}

}  // namespace dvx
