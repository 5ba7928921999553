// The implicit voxel lattice: nodes, lattice edges and voxels are addressed by
// linear indices computed from (i, j, k); nothing is stored per element.
//
//   node  (i,j,k), 0 <= i <= nx          -> i + (nx+1) * (j + (ny+1) * k)
//   edge  from node n along axis a      -> 3 * n + a   (a = 0:x, 1:y, 2:z)
//   voxel (i,j,k), 0 <= i <  nx          -> i + nx * (j + ny * k)
//
// 32-bit indices: make_lattice refuses lattices whose edge ids would not fit.
#pragma once

#include "sim/mesh.h"

#include <cstdint>

namespace dvx {

// The 12 edges of a voxel (or of a simulation voxel's hexahedron): its two corners (corner c = dx |
// dy << 1 | dz << 2) and its axis; x edges 0-3, y edges 4-7, z edges 8-11. The one edge table of the
// cutter and the simulation pieces.
struct VoxelEdge {
  uint8_t c0, c1, axis;
};
constexpr VoxelEdge kVoxelEdges[12] = {{0, 1, 0}, {2, 3, 0}, {4, 5, 0}, {6, 7, 0}, {0, 2, 1}, {1, 3, 1},
                                       {4, 6, 1}, {5, 7, 1}, {0, 4, 2}, {1, 5, 2}, {2, 6, 2}, {3, 7, 2}};

struct Lattice {
  Vec3d origin = Vec3d::Zero();  // position of node (0,0,0)
  double voxel_size = 1.0;       // edge length of the cubic voxels
  int32_t nx = 0, ny = 0, nz = 0;  // voxels per axis (nodes per axis are n+1)

  uint64_t node_count() const { return uint64_t(nx + 1) * uint64_t(ny + 1) * uint64_t(nz + 1); }
  uint64_t voxel_count() const { return uint64_t(nx) * uint64_t(ny) * uint64_t(nz); }

  uint32_t node(int32_t i, int32_t j, int32_t k) const {
    return uint32_t(i) + uint32_t(nx + 1) * (uint32_t(j) + uint32_t(ny + 1) * uint32_t(k));
  }
  uint32_t voxel(int32_t i, int32_t j, int32_t k) const {
    return uint32_t(i) + uint32_t(nx) * (uint32_t(j) + uint32_t(ny) * uint32_t(k));
  }
  static uint32_t edge(uint32_t node, int axis) { return 3u * node + uint32_t(axis); }

  // Inverse of node(): (i, j, k) of a node index.
  void node_coords(uint32_t n, int32_t c[3]) const {
    c[0] = int32_t(n % uint32_t(nx + 1));
    n /= uint32_t(nx + 1);
    c[1] = int32_t(n % uint32_t(ny + 1));
    c[2] = int32_t(n / uint32_t(ny + 1));
  }
  void voxel_coords(uint32_t v, int32_t c[3]) const {
    c[0] = int32_t(v % uint32_t(nx));
    v /= uint32_t(nx);
    c[1] = int32_t(v % uint32_t(ny));
    c[2] = int32_t(v / uint32_t(ny));
  }
  Vec3d node_position(int32_t i, int32_t j, int32_t k) const {
    return origin + voxel_size * Vec3d(i, j, k);
  }
};

// Largest node count whose edge ids (3 * node + axis) fit in 32 bits.
constexpr uint64_t kMaxLatticeNodes = (uint64_t(1) << 32) / 3 - 1;

// Finest grid for a mesh box: `resolution` cubic voxels along the longest axis,
// `padding` voxels of empty border on every side (so no inside node touches the border).
// The box is centred in the grid. Returns false (and leaves `out` unchanged) when the
// box is empty or degenerate on its longest axis or resolution < 1.
bool make_lattice(const Aabb& box, int resolution, int padding, Lattice& out);

}  // namespace dvx
