// Voxelization: node signs by ray parity along grid lines (x, y, z, majority vote) and
// Hermite data on every sign-change lattice edge from the same rays.
#pragma once

#include "sim/voxel_model.h"

#include <cstdint>
#include <string>

namespace dvx {

struct VoxelizeParams {
  int resolution = 128;  // finest voxels along the longest axis of the mesh box
  int padding = 1;       // empty voxels on every side
};

// What voxelization would allocate at its peak (bytes), from the mesh box and counts
// alone, so absurd resolutions are refused before anything is allocated.
// Returns UINT64_MAX when the lattice cannot be indexed with 32 bits.
uint64_t estimate_voxelize_bytes(const Aabb& box, uint64_t triangle_count, const VoxelizeParams& params);

// Voxelizes `mesh` into `out`. Returns false with a one-line reason in `error` when the
// input cannot be voxelized (empty/degenerate box, resolution < 1, lattice too large).
//
// Robustness rules:
// - Ray-triangle hits are decided exactly: vertex coordinates are snapped to a fixed-point
//   grid (2^-20 voxel) and 2D orientations are evaluated in integer arithmetic, with a
//   top-left style tie rule so a ray through a shared mesh edge or vertex is counted once.
// - A crossing exactly at a node counts as lying before the node along the ray.
// - Each axis gives a parity per node; the sign is the majority of the three (robust to
//   holes, inward winding and small self-intersections).
// - Every edge whose final signs differ gets Hermite data: the ray crossing inside the edge
//   closest to its middle, normal flipped to point from the inside node to the outside one;
//   when the majority vote changed a sign so the ray saw no crossing there, the edge midpoint
//   with the axis direction as normal.
bool voxelize(const TriMesh& mesh, const VoxelizeParams& params, VoxelModel& out, std::string& error);

}  // namespace dvx
