// Distances between triangle meshes: a bounding-volume hierarchy for closest-point
// queries and the two-sided sampled error used in reports and tests.
#pragma once

#include "sim/mesh.h"

#include <cstdint>
#include <vector>

namespace dvx {

// Static AABB tree over a TriMesh's triangles (flat node array, 32-bit indices).
struct TriangleBvh {
  struct Node {
    Aabb box;
    uint32_t first;  // leaf: first index into `order`; inner: index of left child (right = first + 1)
    uint32_t count;  // leaf: triangle count (> 0); inner: 0
  };
  const TriMesh* mesh = nullptr;
  std::vector<Node> nodes;       // (nnodes) nodes[0] is the root
  std::vector<uint32_t> order;   // (ntris) triangle ids in leaf order
};

TriangleBvh build_bvh(const TriMesh& mesh);

// Closest point on the mesh to `p`; returns the distance and writes the point (may be null).
double closest_point(const TriangleBvh& bvh, const Vec3d& p, Vec3d* closest = nullptr);

// Closest point on one triangle (Ericson, Real-Time Collision Detection 5.1.5).
Vec3d closest_point_on_triangle(const Vec3d& p, const Vec3d& a, const Vec3d& b, const Vec3d& c);

struct ErrorStats {
  double max = 0.0, mean = 0.0, rms = 0.0;
  uint64_t samples = 0;
};

// Area-uniform samples on a mesh (deterministic for a seed): `count` points.
std::vector<Vec3d> sample_surface(const TriMesh& mesh, uint64_t count, uint64_t seed);

// Two-sided sampled distance between meshes a and b: samples of a against b and samples
// of b against a, pooled (max over both, mean/rms over all samples). Also sampled at every
// vertex of both meshes so sharp corners are never missed. `samples_per_side` area samples.
ErrorStats two_sided_error(const TriMesh& a, const TriMesh& b, uint64_t samples_per_side, uint64_t seed);

}  // namespace dvx
