#include "sim/mesh.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cstring>
#include <numeric>

namespace dvx {

Aabb mesh_bounds(const TriMesh& mesh) {
  Aabb box;
  const size_t nv = mesh.positions.size();
  for (const Tri& t : mesh.triangles) {
    for (uint32_t i : t) {
      if (i < nv) box.grow(mesh.positions[i]);
    }
  }
  return box;
}

double signed_volume(const TriMesh& mesh) {
  const size_t nv = mesh.positions.size();
  // Relative to the box centre: keeps the cancellation of the divergence-theorem sum small
  // for meshes far from the origin.
  const Aabb box = mesh_bounds(mesh);
  if (box.empty()) return 0.0;
  const Vec3d o = 0.5 * (box.min + box.max);
  double six_v = 0.0;
  for (const Tri& t : mesh.triangles) {
    if (t[0] >= nv || t[1] >= nv || t[2] >= nv) continue;
    const Vec3d a = mesh.positions[t[0]] - o;
    const Vec3d b = mesh.positions[t[1]] - o;
    const Vec3d c = mesh.positions[t[2]] - o;
    six_v += a.dot(b.cross(c));
  }
  return six_v / 6.0;
}

namespace {

// Bit pattern of a coordinate; -0.0 is folded onto +0.0 (same value, same position).
uint64_t coord_bits(double x) {
  if (x == 0.0) x = 0.0;
  uint64_t b;
  std::memcpy(&b, &x, sizeof b);
  return b;
}

}  // namespace

uint32_t weld_identical_vertices(TriMesh& mesh) {
  const size_t nv = mesh.positions.size();
  struct Key {
    uint64_t b[3];
    uint32_t index;
  };
  std::vector<Key> keys(nv);
  for (size_t i = 0; i < nv; ++i) {
    for (int a = 0; a < 3; ++a) keys[i].b[a] = coord_bits(mesh.positions[i][a]);
    keys[i].index = uint32_t(i);
  }
  // Sort by coordinates (index as tie-break): deterministic, no hashing-order dependence.
  std::sort(keys.begin(), keys.end(), [](const Key& x, const Key& y) {
    if (x.b[0] != y.b[0]) return x.b[0] < y.b[0];
    if (x.b[1] != y.b[1]) return x.b[1] < y.b[1];
    if (x.b[2] != y.b[2]) return x.b[2] < y.b[2];
    return x.index < y.index;
  });
  // Representative of each group: its smallest original index.
  std::vector<uint32_t> rep(nv);
  for (size_t g = 0; g < nv;) {
    size_t e = g + 1;
    while (e < nv && keys[e].b[0] == keys[g].b[0] && keys[e].b[1] == keys[g].b[1] &&
           keys[e].b[2] == keys[g].b[2]) {
      ++e;
    }
    for (size_t i = g; i < e; ++i) rep[keys[i].index] = keys[g].index;
    g = e;
  }
  // Compact: surviving vertices keep their relative order.
  std::vector<uint32_t> remap(nv, UINT32_MAX);
  std::vector<Vec3d> positions;
  positions.reserve(nv);
  for (size_t i = 0; i < nv; ++i) {
    if (rep[i] == i) {
      remap[i] = uint32_t(positions.size());
      positions.push_back(mesh.positions[i]);
    }
  }
  for (size_t i = 0; i < nv; ++i) remap[i] = remap[rep[i]];

  uint32_t dropped = 0;
  std::vector<Tri> triangles;
  triangles.reserve(mesh.triangles.size());
  for (const Tri& t : mesh.triangles) {
    if (t[0] >= nv || t[1] >= nv || t[2] >= nv) {
      ++dropped;  // invalid indices cannot be remapped
      continue;
    }
    const Tri r = {remap[t[0]], remap[t[1]], remap[t[2]]};
    if (r[0] == r[1] || r[1] == r[2] || r[0] == r[2]) {
      ++dropped;
      continue;
    }
    triangles.push_back(r);
  }
  mesh.positions = std::move(positions);
  mesh.triangles = std::move(triangles);
  return dropped;
}

bool is_watertight(const TriMesh& mesh) {
  if (mesh.triangles.empty()) return false;
  std::vector<uint64_t> edges;
  edges.reserve(3 * mesh.triangles.size());
  for (const Tri& t : mesh.triangles) {
    for (int e = 0; e < 3; ++e) {
      const uint32_t a = t[e], b = t[(e + 1) % 3];
      edges.push_back((uint64_t(std::min(a, b)) << 32) | std::max(a, b));
    }
  }
  std::sort(edges.begin(), edges.end());
  for (size_t i = 0; i < edges.size();) {
    size_t e = i + 1;
    while (e < edges.size() && edges[e] == edges[i]) ++e;
    if (e - i != 2) return false;
    i = e;
  }
  return true;
}

}  // namespace dvx
