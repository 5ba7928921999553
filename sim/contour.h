// Dual contouring of the (uncut) voxel model: manifold dual contouring, one vertex per surface
// patch of a voxel, one quad per sign-change lattice edge (built by init_cut_state, cut.h).
#pragma once

#include "sim/surface_mesh.h"
#include "sim/voxel_model.h"

namespace dvx {

struct ContourParams {
  float svd_truncation = 0.1f;  // singular values below this fraction of the largest are dropped
  // A vertex stays in its voxel, except where the voxel's Hermite data describes a clear sharp
  // feature (an edge or corner of more than ~33 degrees: second singular value >= 0.3 x the
  // largest) whose QEF minimiser fits every plane to within feature_residual (rms, voxels) and
  // lies at most feature_margin voxels outside the voxel: the vertex goes there. This keeps the
  // sharp edges and corners of planar data (a rotated cube, a blade's cut) exact where a vertex
  // confined to its voxel is ~0.3 voxel off (the feature passing just outside the voxel).
  // feature_margin = 0 confines every vertex to its voxel.
  float feature_margin = 0.5f;
  float feature_residual = 0.01f;
};

// Position minimising the QEF sum_i (n_i . (x - p_i))^2, solved about the mass point
// (mean of p_i) with a truncated pseudo-inverse (3x3 symmetric eigen-decomposition of A^T A;
// singular values of A below svd_truncation * the largest are dropped), kept in [lo, hi]:
// when that minimiser leaves the box, the QEF is minimised over the box instead (its faces,
// edges and corners with the same truncation), which keeps a sharp feature that crosses the
// box exactly where a coordinate clamp would pull the point off it. count == 0 gives the box
// centre; never NaN. Exposed for tests and for the cutting code, which reuses it for divided voxels.
Vec3d solve_qef(const Vec3d* points, const Vec3d* normals, int count, const Vec3d& lo, const Vec3d& hi,
                float svd_truncation = 0.1f);

// The vertex of a voxel (or of a piece of a divided voxel) from its Hermite data, by the rule
// dual_contour uses (QEF, feature margin, QEF minimum over the voxel). Points are in the voxel's
// local frame: lattice units with the voxel spanning [0,1]^3; normals are unit. Returns the local
// position (inside [-feature_margin, 1 + feature_margin]^3).
Vec3d place_voxel_vertex(const Vec3d* points_local, const Vec3d* normals, int count,
                         const ContourParams& params = {});

// Builds the closed surface of the uncut model: the surface init_cut_state builds (one vertex per
// surface patch of each voxel around a crossing edge, in ascending voxel then patch order, placed by
// the QEF of the patch's Hermite data, see ContourParams; for each crossing edge a quad joining the
// patches holding it in the four voxels around it, split into two triangles along the shorter
// diagonal, oriented so the normal points from the inside node to the outside node). Crossings on
// the lattice border (no four voxels) have no quad.
SurfaceMesh dual_contour(const VoxelModel& model, const ContourParams& params = {});

}  // namespace dvx
