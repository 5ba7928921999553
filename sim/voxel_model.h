// The voxel model the cutting algorithm works on, as built by voxelization.
//
// Why this layout: an uncut organ needs only a sign per lattice node and Hermite data
// (crossing point + normal) on the lattice edges whose nodes differ in sign. Signs are
// one bit per node in a dense bitset (the implicit lattice); Hermite data is stored
// only for sign-change edges, sorted by edge id so it can be looked up by binary search
// and walked in order. Voxels are not stored at all: a voxel is occupied when any of
// its 8 nodes is inside. Explicit elements (divided voxels, replicas) are added by the
// cutting code only where cuts happen.
#pragma once

#include "sim/lattice.h"

#include <cstdint>
#include <vector>

namespace dvx {

// Hermite data on one sign-change lattice edge. 16 bytes.
struct EdgeCrossing {
  uint32_t edge;      // lattice edge id (3 * node + axis)
  float t;            // crossing point along the edge, in [0, 1] from its first node
  int16_t normal[3];  // unit surface normal pointing from inside to outside, snorm16
  int16_t pad;
};

struct VoxelModel {
  Lattice lattice;
  std::vector<uint64_t> inside;         // (ceil(nodes / 64)) bit n set: node n inside the object
  std::vector<EdgeCrossing> crossings;  // (sign-change edges) sorted by edge id
  // Where each row of nodes' crossings start (a row: the nodes of one (j, k), edge ids
  // 3 (nx + 1) (j + (ny + 1) k) on): row r's are crossings[crossing_rows[r] .. crossing_rows[r + 1]).
  // A lookup then searches a row's few crossings instead of all of them (at 256, ~18 mostly
  // cache-missing halvings of ~300 000 crossings). Built by index_crossings; while it does not
  // match the crossings (empty, or built for another count) lookups search the whole array.
  std::vector<uint32_t> crossing_rows;
  uint32_t occupied_voxels = 0;         // voxels with at least one inside node

  bool is_inside(uint32_t node) const { return (inside[node >> 6] >> (node & 63)) & 1u; }
  // Hermite data of a lattice edge, or nullptr when the edge has no sign change.
  const EdgeCrossing* find_crossing(uint32_t edge) const;
  // Builds crossing_rows from the crossings (after they are set).
  void index_crossings();
  // Bytes held by the model's arrays (capacity), surface mesh excluded.
  uint64_t memory_bytes() const;
};

// Packs/unpacks a unit normal into snorm16.
void encode_normal(const Vec3d& n, int16_t out[3]);
Vec3d decode_normal(const int16_t in[3]);

// Position of a crossing in space.
Vec3d crossing_position(const Lattice& lattice, const EdgeCrossing& c);

}  // namespace dvx
