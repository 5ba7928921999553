#include "sim/shapes.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <unordered_map>

namespace dvx {

namespace {

constexpr double kPi = 3.14159265358979323846;

// Two triangles for the quad a-b-c-d (counter-clockwise seen from outside).
inline void add_quad(std::vector<Tri>& tris, uint32_t a, uint32_t b, uint32_t c, uint32_t d) {
  tris.push_back({a, b, c});
  tris.push_back({a, c, d});
}

}  // namespace

TriMesh make_sphere(const Vec3d& centre, double radius, int segments) {
  TriMesh m;
  const int nseg = std::max(segments, 3);
  const int rings = std::max(nseg / 2, 2);
  // Vertices: north pole (+z), rings-1 latitude rings of nseg vertices, south pole.
  m.positions.push_back(centre + Vec3d(0, 0, radius));
  for (int i = 1; i < rings; ++i) {
    const double theta = kPi * i / rings;
    const double z = std::cos(theta), rxy = std::sin(theta);
    for (int j = 0; j < nseg; ++j) {
      const double phi = 2.0 * kPi * j / nseg;
      m.positions.push_back(centre + radius * Vec3d(rxy * std::cos(phi), rxy * std::sin(phi), z));
    }
  }
  m.positions.push_back(centre + Vec3d(0, 0, -radius));
  const uint32_t north = 0;
  const uint32_t south = static_cast<uint32_t>(m.positions.size() - 1);
  auto ring = [&](int i, int j) { return static_cast<uint32_t>(1 + (i - 1) * nseg + (j % nseg)); };
  // Polar fans and quads between consecutive rings (phi increases counter-clockwise about +z).
  for (int j = 0; j < nseg; ++j) m.triangles.push_back({north, ring(1, j), ring(1, j + 1)});
  for (int i = 1; i + 1 < rings; ++i)
    for (int j = 0; j < nseg; ++j) add_quad(m.triangles, ring(i, j), ring(i + 1, j), ring(i + 1, j + 1), ring(i, j + 1));
  for (int j = 0; j < nseg; ++j) m.triangles.push_back({south, ring(rings - 1, j + 1), ring(rings - 1, j)});
  return m;
}

TriMesh make_icosphere(const Vec3d& centre, double radius, int subdivisions) {
  // Unit icosahedron: 12 vertices on three golden rectangles, 20 outward faces.
  const double t = (1.0 + std::sqrt(5.0)) / 2.0;
  std::vector<Vec3d> pos = {{-1, t, 0}, {1, t, 0},  {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
                            {0, -1, -t}, {0, 1, -t}, {t, 0, -1},  {t, 0, 1},  {-t, 0, -1}, {-t, 0, 1}};
  for (Vec3d& p : pos) p.normalize();
  std::vector<Tri> tris = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11}, {1, 5, 9},  {5, 11, 4},
                           {11, 10, 2}, {10, 7, 6}, {7, 1, 8},   {3, 9, 4},  {3, 4, 2},   {3, 2, 6},  {3, 6, 8},
                           {3, 8, 9},   {4, 9, 5},  {2, 4, 11},  {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
  // Each subdivision splits a triangle into four; edge midpoints are shared through a map
  // keyed by the sorted vertex pair (lookups only, so the result is deterministic).
  for (int s = 0; s < subdivisions; ++s) {
    std::unordered_map<uint64_t, uint32_t> midpoint;
    midpoint.reserve(tris.size() * 2);
    auto mid = [&](uint32_t a, uint32_t b) {
      const uint64_t key = (static_cast<uint64_t>(std::min(a, b)) << 32) | std::max(a, b);
      auto it = midpoint.find(key);
      if (it != midpoint.end()) return it->second;
      const uint32_t id = static_cast<uint32_t>(pos.size());
      pos.push_back((pos[a] + pos[b]).normalized());
      midpoint.emplace(key, id);
      return id;
    };
    std::vector<Tri> next;
    next.reserve(tris.size() * 4);
    for (const Tri& tri : tris) {
      const uint32_t ab = mid(tri[0], tri[1]), bc = mid(tri[1], tri[2]), ca = mid(tri[2], tri[0]);
      next.push_back({tri[0], ab, ca});
      next.push_back({tri[1], bc, ab});
      next.push_back({tri[2], ca, bc});
      next.push_back({ab, bc, ca});
    }
    tris.swap(next);
  }
  TriMesh m;
  m.positions.reserve(pos.size());
  for (const Vec3d& p : pos) m.positions.push_back(centre + radius * p);
  m.triangles = std::move(tris);
  return m;
}

TriMesh make_box(const Vec3d& centre, const Vec3d& half_extent, const Eigen::Matrix3d& rotation, int n) {
  TriMesh m;
  const int k = std::max(n, 1);
  const int side = k + 1;
  // Vertices live on the surface of a (k+1)^3 lattice; one index per lattice point (a map over
  // the surface points only, ids in creation order) so faces share their border vertices.
  // Coordinates -1 + 2i/k are exact at both ends.
  std::unordered_map<uint64_t, uint32_t> index;
  index.reserve(static_cast<size_t>(6 * k * k + 2));
  auto vertex = [&](int i, int j, int l) {
    const uint64_t key = (static_cast<uint64_t>(l) * side + j) * side + i;
    const auto [it, inserted] = index.emplace(key, static_cast<uint32_t>(m.positions.size()));
    if (inserted) {
      const Vec3d unit(-1.0 + 2.0 * i / k, -1.0 + 2.0 * j / k, -1.0 + 2.0 * l / k);
      m.positions.push_back(centre + rotation * unit.cwiseProduct(half_extent));
    }
    return it->second;
  };
  // Six faces: axis a at side s; in-face axes (u, v) with u x v = s * e_a (outward).
  for (int a = 0; a < 3; ++a) {
    for (int s = 0; s < 2; ++s) {
      const int u = s == 1 ? (a + 1) % 3 : (a + 2) % 3;
      const int v = s == 1 ? (a + 2) % 3 : (a + 1) % 3;
      auto corner = [&](int i, int j) {
        int g[3];
        g[a] = s == 1 ? k : 0;
        g[u] = i;
        g[v] = j;
        return vertex(g[0], g[1], g[2]);
      };
      for (int j = 0; j < k; ++j)
        for (int i = 0; i < k; ++i) add_quad(m.triangles, corner(i, j), corner(i + 1, j), corner(i + 1, j + 1), corner(i, j + 1));
    }
  }
  // A reflection instead of a rotation would turn the box inside out: keep it outward.
  if (rotation.determinant() < 0.0)
    for (Tri& t : m.triangles) std::swap(t[1], t[2]);
  return m;
}

TriMesh make_torus(const Vec3d& centre, double major_radius, double minor_radius, int major_segments,
                   int minor_segments) {
  TriMesh m;
  const int nu = std::max(major_segments, 3);
  const int nv = std::max(minor_segments, 3);
  // Vertex (i, j): angle phi_i around z, angle theta_j around the tube.
  for (int i = 0; i < nu; ++i) {
    const double phi = 2.0 * kPi * i / nu;
    for (int j = 0; j < nv; ++j) {
      const double theta = 2.0 * kPi * j / nv;
      const double rr = major_radius + minor_radius * std::cos(theta);
      m.positions.push_back(centre + Vec3d(rr * std::cos(phi), rr * std::sin(phi), minor_radius * std::sin(theta)));
    }
  }
  auto id = [&](int i, int j) { return static_cast<uint32_t>((i % nu) * nv + (j % nv)); };
  // d/dphi x d/dtheta points out of the tube, so (i,j) (i+1,j) (i+1,j+1) (i,j+1) is outward.
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) add_quad(m.triangles, id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
  return m;
}

TriMesh flip_winding(const TriMesh& mesh) {
  TriMesh m = mesh;
  for (Tri& t : m.triangles) std::swap(t[1], t[2]);
  return m;
}

TriMesh merge_meshes(const TriMesh& a, const TriMesh& b) {
  TriMesh m = a;
  // b's indices shift past a's vertices.
  const uint32_t offset = static_cast<uint32_t>(a.positions.size());
  m.positions.insert(m.positions.end(), b.positions.begin(), b.positions.end());
  m.triangles.reserve(a.triangles.size() + b.triangles.size());
  for (const Tri& t : b.triangles) m.triangles.push_back({t[0] + offset, t[1] + offset, t[2] + offset});
  return m;
}

TriMesh cut_hole(const TriMesh& mesh, const Vec3d& centre, double radius) {
  // Keep triangles whose centroid is outside the ball.
  std::vector<Tri> kept;
  const double r2 = radius * radius;
  for (const Tri& t : mesh.triangles) {
    const Vec3d c = (mesh.positions[t[0]] + mesh.positions[t[1]] + mesh.positions[t[2]]) / 3.0;
    if ((c - centre).squaredNorm() > r2) kept.push_back(t);
  }
  // Drop the vertices no kept triangle uses (order preserved).
  TriMesh m;
  std::vector<uint32_t> remap(mesh.positions.size(), UINT32_MAX);
  for (Tri& t : kept) {
    for (uint32_t& v : t) {
      if (remap[v] == UINT32_MAX) remap[v] = 0;
    }
  }
  for (uint32_t v = 0; v < remap.size(); ++v) {
    if (remap[v] != UINT32_MAX) {
      remap[v] = static_cast<uint32_t>(m.positions.size());
      m.positions.push_back(mesh.positions[v]);
    }
  }
  for (Tri& t : kept)
    for (uint32_t& v : t) v = remap[v];
  m.triangles = std::move(kept);
  return m;
}

TriMesh make_u_shape(const Vec3d& centre, double width, double height, double depth, double arm_width) {
  TriMesh m;
  // Width along x, height along y (arms point up +y), depth along z; the bottom bar is as thick
  // as the arms. Needs width > 2 * arm_width and height > arm_width; otherwise empty.
  if (!(arm_width > 0.0 && width > 2.0 * arm_width && height > arm_width && depth > 0.0)) return m;
  const double x0 = -0.5 * width, x1 = x0 + arm_width, x3 = 0.5 * width, x2 = x3 - arm_width;
  const double y0 = -0.5 * height, yb = y0 + arm_width, y1 = 0.5 * height;
  const double z0 = -0.5 * depth, z1 = 0.5 * depth;
  // The U outline, counter-clockwise in the xy plane (8 corners).
  const double outline[8][2] = {{x0, y0}, {x3, y0}, {x3, y1}, {x2, y1}, {x2, yb}, {x1, yb}, {x1, y1}, {x0, y1}};
  // Vertices 0..7 at the back (z0), 8..15 at the front (z1).
  for (double z : {z0, z1})
    for (const auto& p : outline) m.positions.push_back(centre + Vec3d(p[0], p[1], z));
  // Cap: three convex quads (left arm, bottom bar, right arm) sharing the diagonals 0-5 and 1-4.
  const uint32_t caps[3][4] = {{0, 5, 6, 7}, {0, 1, 4, 5}, {1, 2, 3, 4}};
  for (const auto& q : caps) {
    add_quad(m.triangles, q[0] + 8, q[1] + 8, q[2] + 8, q[3] + 8);  // front, +z
    add_quad(m.triangles, q[3], q[2], q[1], q[0]);                  // back, -z
  }
  // Sides: one quad per outline edge, outward because the outline is counter-clockwise.
  for (uint32_t k = 0; k < 8; ++k) {
    const uint32_t l = (k + 1) % 8;
    add_quad(m.triangles, k, l, l + 8, k + 8);
  }
  return m;
}

TriMesh make_cell_union(const std::vector<std::array<int, 3>>& cells, double cell, const Eigen::Matrix3d& rotation,
                        const Vec3d& centre) {
  TriMesh m;
  std::vector<std::array<int, 3>> sorted = cells;
  std::sort(sorted.begin(), sorted.end());
  sorted.erase(std::unique(sorted.begin(), sorted.end()), sorted.end());
  const auto filled = [&](int i, int j, int k) {
    return std::binary_search(sorted.begin(), sorted.end(), std::array<int, 3>{i, j, k});
  };
  // Grid vertices, shared between faces (welded by their integer coordinates).
  std::unordered_map<uint64_t, uint32_t> vertex_of;
  const auto vertex = [&](int i, int j, int k) {
    const uint64_t key = (uint64_t(uint32_t(i + 0x8000)) << 32) | (uint64_t(uint32_t(j + 0x8000)) << 16) | uint64_t(uint32_t(k + 0x8000));
    const auto it = vertex_of.find(key);
    if (it != vertex_of.end()) return it->second;
    const uint32_t id = uint32_t(m.positions.size());
    m.positions.push_back(centre + rotation * (cell * Vec3d(i, j, k)));
    vertex_of.emplace(key, id);
    return id;
  };
  // A face toward every empty neighbour, counter-clockwise seen from outside.
  for (const auto& c : sorted) {
    for (int a = 0; a < 3; ++a) {
      for (int s = 0; s < 2; ++s) {
        int n[3] = {c[0], c[1], c[2]};
        n[a] += s ? 1 : -1;
        if (filled(n[0], n[1], n[2])) continue;
        const int b = (a + 1) % 3, d = (a + 2) % 3;
        int p[4][3];
        static constexpr int kUv[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
        for (int q = 0; q < 4; ++q) {
          p[q][a] = c[a] + s;
          p[q][b] = c[b] + kUv[q][0];
          p[q][d] = c[d] + kUv[q][1];
        }
        uint32_t v[4];
        for (int q = 0; q < 4; ++q) v[q] = vertex(p[q][0], p[q][1], p[q][2]);
        // b x d = a: the order above is counter-clockwise seen from +a.
        if (s) {
          add_quad(m.triangles, v[0], v[1], v[2], v[3]);
        } else {
          add_quad(m.triangles, v[0], v[3], v[2], v[1]);
        }
      }
    }
  }
  return m;
}

TriMesh make_holed_plate(int holes, double cell, int thickness, const Eigen::Matrix3d& rotation, const Vec3d& centre) {
  std::vector<std::array<int, 3>> cells;
  const int nx = 2 * std::max(holes, 0) + 1, ny = 3;
  for (int k = 0; k < std::max(thickness, 1); ++k) {
    for (int j = 0; j < ny; ++j) {
      for (int i = 0; i < nx; ++i) {
        if (j == 1 && i % 2 == 1) continue;  // a hole
        cells.push_back({i - nx / 2, j - 1, k});
      }
    }
  }
  return make_cell_union(cells, cell, rotation, centre);
}

TriMesh make_lollipop(int stem, double cell, const Eigen::Matrix3d& rotation, const Vec3d& centre) {
  std::vector<std::array<int, 3>> cells;
  for (int k = 0; k < 4; ++k) {
    for (int j = 0; j < 4; ++j) {
      for (int i = 0; i < 4; ++i) cells.push_back({i - 2, j - 2, k});
    }
  }
  for (int k = 1; k <= std::max(stem, 1); ++k) cells.push_back({0, 0, -k});
  return make_cell_union(cells, cell, rotation, centre);
}

TriMesh make_two_shells(const Vec3d& centre, double r_out, double r_in, int subdivisions) {
  return merge_meshes(make_icosphere(centre, r_out, subdivisions), flip_winding(make_icosphere(centre, r_in, subdivisions)));
}

}  // namespace dvx
