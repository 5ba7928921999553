// Triangle meshes as plain arrays: the input organ surface and the dual-contoured output.
#pragma once

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <vector>

namespace dvx {

using Vec3d = Eigen::Vector3d;
using Vec3f = Eigen::Vector3f;
using Tri = std::array<uint32_t, 3>;

// Axis-aligned box; empty when min > max on any axis.
struct Aabb {
  Vec3d min = Vec3d::Constant(1e300);
  Vec3d max = Vec3d::Constant(-1e300);

  void grow(const Vec3d& p) {
    min = min.cwiseMin(p);
    max = max.cwiseMax(p);
  }
  Vec3d extent() const { return max - min; }
  bool empty() const { return (min.array() > max.array()).any(); }
};

// An indexed triangle mesh in double precision (the input to voxelization).
// Triangles are counter-clockwise seen from outside when the mesh is wound outward;
// nothing in sim/ relies on it (signs come from ray parity, normals are re-oriented).
struct TriMesh {
  std::vector<Vec3d> positions;  // (nverts)
  std::vector<Tri> triangles;    // (ntris) indices into positions
};

// Box of the vertices that triangles use.
Aabb mesh_bounds(const TriMesh& mesh);

// Signed enclosed volume (divergence theorem); positive for outward winding.
double signed_volume(const TriMesh& mesh);

// Merges vertices with bit-identical coordinates and drops triangles that become
// degenerate (two equal indices). Returns the number of triangles dropped.
uint32_t weld_identical_vertices(TriMesh& mesh);

// Every undirected edge is used by exactly two triangles.
bool is_watertight(const TriMesh& mesh);

}  // namespace dvx
