// Dual contouring of the (uncut) voxel model: one vertex per boundary voxel, one quad
// per sign-change lattice edge.
#pragma once

#include "sim/surface_mesh.h"
#include "sim/voxel_model.h"

namespace dvx {

struct ContourParams {
  float svd_truncation = 0.1f;  // singular values below this fraction of the largest are dropped
};

// Position minimising the QEF sum_i (n_i . (x - p_i))^2, solved about the mass point
// (mean of p_i) with a truncated pseudo-inverse (3x3 SVD), then clamped to [lo, hi].
// Exposed for tests and for the cutting code, which reuses it for divided voxels.
Vec3d solve_qef(const Vec3d* points, const Vec3d* normals, int count, const Vec3d& lo, const Vec3d& hi,
                float svd_truncation = 0.1f);

// Builds the closed surface: for each crossing edge, a quad joining the vertices of the
// four voxels around it, split into two triangles (along the shorter diagonal), oriented
// so the normal points from the inside node to the outside node.
SurfaceMesh dual_contour(const VoxelModel& model, const ContourParams& params = {});

}  // namespace dvx
