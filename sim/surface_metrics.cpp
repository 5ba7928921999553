#include "sim/surface_metrics.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cstdint>
#include <vector>

namespace dvx {

namespace {

uint32_t find_root(std::vector<uint32_t>& parent, uint32_t x) {
  while (parent[x] != x) {
    parent[x] = parent[parent[x]];  // path halving
    x = parent[x];
  }
  return x;
}

uint32_t max_index_plus_one(const std::vector<Tri>& triangles) {
  uint32_t m = 0;
  for (const Tri& t : triangles) m = std::max({m, t[0] + 1, t[1] + 1, t[2] + 1});
  return m;
}

}  // namespace

std::vector<uint32_t> triangle_components(const std::vector<Tri>& triangles, uint32_t vertex_count,
                                          uint32_t& components) {
  const uint32_t nv = std::max(vertex_count, max_index_plus_one(triangles));
  std::vector<uint32_t> parent(nv);
  for (uint32_t i = 0; i < nv; ++i) parent[i] = i;
  auto unite = [&](uint32_t a, uint32_t b) {
    a = find_root(parent, a);
    b = find_root(parent, b);
    if (a == b) return;
    if (a < b) std::swap(a, b);
    parent[a] = b;  // smaller index becomes the root: deterministic
  };
  for (const Tri& t : triangles) {
    unite(t[0], t[1]);
    unite(t[1], t[2]);
  }
  constexpr uint32_t kNone = 0xffffffffu;
  std::vector<uint32_t> root_id(nv, kNone);
  std::vector<uint32_t> out(triangles.size());
  components = 0;
  for (size_t i = 0; i < triangles.size(); ++i) {
    const uint32_t r = find_root(parent, triangles[i][0]);
    if (root_id[r] == kNone) root_id[r] = components++;
    out[i] = root_id[r];
  }
  return out;
}

SurfaceStats surface_stats(const std::vector<Vec3d>& positions, const std::vector<Tri>& triangles) {
  SurfaceStats s;
  s.triangles = uint32_t(triangles.size());
  const uint32_t nv = std::max(uint32_t(positions.size()), max_index_plus_one(triangles));

  // Referenced vertices.
  std::vector<uint8_t> used(nv, 0);
  for (const Tri& t : triangles) used[t[0]] = used[t[1]] = used[t[2]] = 1;
  for (uint8_t u : used) s.vertices += u;

  // Undirected edges, bucketed by their smaller vertex (counting sort), then sorted by the
  // larger vertex inside each bucket: no hash map, result independent of any iteration order.
  std::vector<uint32_t> start(size_t(nv) + 1, 0);
  for (const Tri& t : triangles) {
    for (int k = 0; k < 3; ++k) ++start[std::min(t[k], t[(k + 1) % 3]) + 1];
  }
  for (uint32_t i = 0; i < nv; ++i) start[i + 1] += start[i];
  std::vector<uint64_t> entry(start[nv]);  // (larger vertex << 1) | (used as smaller -> larger)
  {
    std::vector<uint32_t> fill(start.begin(), start.end() - 1);
    for (const Tri& t : triangles) {
      for (int k = 0; k < 3; ++k) {
        const uint32_t u = t[k], v = t[(k + 1) % 3];
        const uint32_t lo = std::min(u, v), hi = std::max(u, v);
        entry[fill[lo]++] = (uint64_t(hi) << 1) | uint64_t(u < v);
      }
    }
  }
  uint64_t edges = 0;
  for (uint32_t lo = 0; lo < nv; ++lo) {
    const auto b = entry.begin() + start[lo], e = entry.begin() + start[lo + 1];
    std::sort(b, e);
    for (auto it = b; it != e;) {
      const uint64_t hi = *it >> 1;
      uint32_t count = 0, forward = 0;
      for (; it != e && (*it >> 1) == hi; ++it) {
        ++count;
        forward += uint32_t(*it & 1u);
      }
      ++edges;
      if (count == 1) {
        ++s.boundary_edges;
      } else if (count > 2) {
        ++s.nonmanifold_edges;
      } else if (forward != 1) {
        ++s.misoriented_edges;
      }
    }
  }

  uint32_t components = 0;
  triangle_components(triangles, nv, components);
  s.components = components;
  s.euler = int64_t(s.vertices) - int64_t(edges) + int64_t(s.triangles);

  // Volume about the centre of the referenced vertices' box (exact for closed surfaces,
  // better conditioned than about the origin for meshes far from it); area.
  Aabb box;
  for (const Tri& t : triangles) {
    for (uint32_t k : t) {
      if (k < positions.size()) box.grow(positions[k]);
    }
  }
  const Vec3d ref = box.empty() ? Vec3d::Zero() : Vec3d(0.5 * (box.min + box.max));
  double six_vol = 0.0, twice_area = 0.0;
  for (const Tri& t : triangles) {
    if (t[0] >= positions.size() || t[1] >= positions.size() || t[2] >= positions.size()) continue;
    const Vec3d a = positions[t[0]] - ref, b = positions[t[1]] - ref, c = positions[t[2]] - ref;
    six_vol += a.dot(b.cross(c));
    twice_area += (b - a).cross(c - a).norm();
  }
  s.volume = six_vol / 6.0;
  s.area = 0.5 * twice_area;
  return s;
}

SurfaceStats surface_stats(const TriMesh& mesh) { return surface_stats(mesh.positions, mesh.triangles); }

SurfaceStats surface_stats(const SurfaceMesh& mesh) {
  std::vector<Vec3d> positions;
  positions.reserve(mesh.positions.size());
  for (const Vec3f& p : mesh.positions) positions.push_back(p.cast<double>());
  return surface_stats(positions, mesh.triangles);
}

}  // namespace dvx
