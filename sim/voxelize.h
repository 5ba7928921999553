// Voxelization: node signs by ray parity along grid lines (x, y, z, majority vote) and
// Hermite data on every sign-change lattice edge from the same rays.
#pragma once

#include "sim/voxel_model.h"

#include <cstdint>
#include <string>
#include <vector>

namespace dvx {

struct VoxelizeParams {
  int resolution = 128;  // finest voxels along the longest axis of the mesh box
  int padding = 1;       // empty voxels on every side
};

// What voxelization would allocate at its peak (bytes), from the mesh box and counts
// alone, so absurd resolutions are refused before anything is allocated.
// Returns UINT64_MAX when the lattice cannot be indexed with 32 bits, and 0 when the box or
// params give no lattice at all (voxelize refuses those itself, with a reason).
uint64_t estimate_voxelize_bytes(const Aabb& box, uint64_t triangle_count, const VoxelizeParams& params);

// Voxelizes `mesh` into `out`. Returns false with a one-line reason in `error` when the
// input cannot be voxelized (empty/degenerate box, resolution < 1, lattice too large).
//
// Robustness rules:
// - Ray-triangle hits are decided exactly: vertex coordinates are snapped to a fixed-point
//   grid (2^-20 voxel) and 2D orientations are evaluated in integer arithmetic, with a
//   top-left style tie rule so a ray through a shared mesh edge or vertex is counted once
//   (symbolic perturbation: the ray through lattice point (u, v) of the other two axes, in
//   cyclic order after the ray axis, is treated as passing through (u + eps, v + eps^2)).
// - A crossing exactly at a node counts as lying before the node along the ray.
// - Each axis gives a parity per node; the sign is the majority of the three (robust to
//   holes, inward winding and small self-intersections).
// - Every edge whose final signs differ gets Hermite data: the ray crossing inside the edge
//   closest to its middle, normal flipped to point from the inside node to the outside one;
//   when the majority vote changed a sign so the ray saw no crossing there: a crossing lying
//   exactly on the edge's first node (a node on the surface) at t = 0, else the edge midpoint
//   with the axis direction as normal.
// - Degenerate triangles (after snapping) contribute nothing; of several triangles with the same
//   snapped vertices in the same cyclic order only the first counts. Opposite-winding copies are
//   kept (two solids sharing a face: the shared wall cancels, giving their union).
bool voxelize(const TriMesh& mesh, const VoxelizeParams& params, VoxelModel& out, std::string& error);

// Testing aid: the three per-axis ray parities behind the majority vote, one byte per node
// (bit a set: an odd number of crossings lie at or before the node along its axis-a ray), on
// the same lattice and with the same rules as voxelize. Fails exactly when voxelize fails.
bool voxelize_parities(const TriMesh& mesh, const VoxelizeParams& params, Lattice& lattice,
                       std::vector<uint8_t>& parities, std::string& error);

}  // namespace dvx
