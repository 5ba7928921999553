#include "sim/voxelize.h"

#include <doctest/doctest.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <map>
#include <random>

using namespace dvx;

namespace {

// ---- Small shapes, local to this file ---------------------------------------------------------

// Axis-aligned box, each face split into n x n quads (vertices shared), wound outward.
TriMesh box_mesh(const Vec3d& lo, const Vec3d& hi, int n = 1) {
  TriMesh m;
  std::map<std::array<int, 3>, uint32_t> index;
  auto vertex = [&](int i, int j, int k) {
    const std::array<int, 3> key{i, j, k};
    auto it = index.find(key);
    if (it != index.end()) return it->second;
    const Vec3d p(lo.x() + (hi.x() - lo.x()) * i / n, lo.y() + (hi.y() - lo.y()) * j / n,
                  lo.z() + (hi.z() - lo.z()) * k / n);
    m.positions.push_back(p);
    return index[key] = uint32_t(m.positions.size() - 1);
  };
  // For face axis a at side s (0: low, n: high): two tangent axes b, c with (a, b, c) cyclic.
  for (int a = 0; a < 3; ++a) {
    const int b = (a + 1) % 3, c = (a + 2) % 3;
    for (int side = 0; side <= n; side += n) {
      for (int i = 0; i < n; ++i) {
        for (int j = 0; j < n; ++j) {
          uint32_t q[4];
          const int corner[4][2] = {{i, j}, {i + 1, j}, {i + 1, j + 1}, {i, j + 1}};
          for (int r = 0; r < 4; ++r) {
            int g[3];
            g[a] = side;
            g[b] = corner[r][0];
            g[c] = corner[r][1];
            q[r] = vertex(g[0], g[1], g[2]);
          }
          // (b, c) counter-clockwise has normal +a.
          if (side == n) {
            m.triangles.push_back({q[0], q[1], q[2]});
            m.triangles.push_back({q[0], q[2], q[3]});
          } else {
            m.triangles.push_back({q[0], q[2], q[1]});
            m.triangles.push_back({q[0], q[3], q[2]});
          }
        }
      }
    }
  }
  return m;
}

TriMesh icosphere(const Vec3d& c, double r, int subdivisions) {
  const double t = (1.0 + std::sqrt(5.0)) / 2.0;
  std::vector<Vec3d> p = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
                          {0, -1, -t}, {0, 1, -t}, {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  for (Vec3d& v : p) v.normalize();
  std::vector<Tri> f = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
                        {11, 10, 2}, {10, 7, 6}, {7, 1, 8},  {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
                        {3, 8, 9},  {4, 9, 5},  {2, 4, 11}, {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
  for (int s = 0; s < subdivisions; ++s) {
    std::map<std::pair<uint32_t, uint32_t>, uint32_t> mid;
    auto midpoint = [&](uint32_t a, uint32_t b) {
      const auto key = std::make_pair(std::min(a, b), std::max(a, b));
      auto it = mid.find(key);
      if (it != mid.end()) return it->second;
      p.push_back((p[a] + p[b]).normalized());
      return mid[key] = uint32_t(p.size() - 1);
    };
    std::vector<Tri> g;
    for (const Tri& tr : f) {
      const uint32_t ab = midpoint(tr[0], tr[1]), bc = midpoint(tr[1], tr[2]), ca = midpoint(tr[2], tr[0]);
      g.push_back({tr[0], ab, ca});
      g.push_back({tr[1], bc, ab});
      g.push_back({tr[2], ca, bc});
      g.push_back({ab, bc, ca});
    }
    f.swap(g);
  }
  TriMesh m;
  for (const Vec3d& v : p) m.positions.push_back(c + r * v);
  m.triangles = f;
  return m;
}

// UV sphere with its poles on the z axis through c: `seg` around, `rings` bands.
TriMesh uv_sphere(const Vec3d& c, double r, int seg, int rings) {
  TriMesh m;
  m.positions.push_back(c + Vec3d(0, 0, -r));
  for (int i = 1; i < rings; ++i) {
    const double th = M_PI * i / rings - M_PI / 2;
    for (int j = 0; j < seg; ++j) {
      const double ph = 2 * M_PI * j / seg;
      m.positions.push_back(c + r * Vec3d(std::cos(th) * std::cos(ph), std::cos(th) * std::sin(ph), std::sin(th)));
    }
  }
  m.positions.push_back(c + Vec3d(0, 0, r));
  const uint32_t top = uint32_t(m.positions.size() - 1);
  auto at = [&](int i, int j) { return uint32_t(1 + (i - 1) * seg + (j % seg)); };
  for (int j = 0; j < seg; ++j) m.triangles.push_back({0, at(1, j + 1), at(1, j)});
  for (int i = 1; i + 1 < rings; ++i) {
    for (int j = 0; j < seg; ++j) {
      m.triangles.push_back({at(i, j), at(i, j + 1), at(i + 1, j + 1)});
      m.triangles.push_back({at(i, j), at(i + 1, j + 1), at(i + 1, j)});
    }
  }
  for (int j = 0; j < seg; ++j) m.triangles.push_back({at(rings - 1, j), at(rings - 1, j + 1), top});
  return m;
}

TriMesh torus(const Vec3d& c, double R, double r, int nmaj, int nmin) {
  TriMesh m;
  for (int i = 0; i < nmaj; ++i) {
    const double u = 2 * M_PI * i / nmaj;
    for (int j = 0; j < nmin; ++j) {
      const double v = 2 * M_PI * j / nmin;
      m.positions.push_back(c + Vec3d((R + r * std::cos(v)) * std::cos(u), (R + r * std::cos(v)) * std::sin(u),
                                      r * std::sin(v)));
    }
  }
  auto at = [&](int i, int j) { return uint32_t((i % nmaj) * nmin + (j % nmin)); };
  for (int i = 0; i < nmaj; ++i) {
    for (int j = 0; j < nmin; ++j) {
      m.triangles.push_back({at(i, j), at(i + 1, j), at(i + 1, j + 1)});
      m.triangles.push_back({at(i, j), at(i + 1, j + 1), at(i, j + 1)});
    }
  }
  return m;
}

// Octahedron |x|/rx + |y|/ry + |z|/rz <= 1 around c.
TriMesh octahedron(const Vec3d& c, const Vec3d& radii) {
  TriMesh m;
  for (int a = 0; a < 3; ++a) {
    for (int s = -1; s <= 1; s += 2) {
      Vec3d p = c;
      p[a] += s * radii[a];
      m.positions.push_back(p);  // index 2a + (s > 0)
    }
  }
  for (int sx = 0; sx < 2; ++sx) {
    for (int sy = 0; sy < 2; ++sy) {
      for (int sz = 0; sz < 2; ++sz) {
        Tri t = {uint32_t(sx), uint32_t(2 + sy), uint32_t(4 + sz)};
        // Outward when the sign count of negatives is even.
        if ((sx + sy + sz) % 2 == 0) std::swap(t[1], t[2]);
        m.triangles.push_back(t);
      }
    }
  }
  return m;
}

TriMesh reversed(const TriMesh& m) {
  TriMesh r = m;
  for (Tri& t : r.triangles) t = {t[2], t[1], t[0]};
  return r;
}

TriMesh merged(const TriMesh& a, const TriMesh& b) {
  TriMesh m = a;
  const uint32_t off = uint32_t(a.positions.size());
  m.positions.insert(m.positions.end(), b.positions.begin(), b.positions.end());
  for (const Tri& t : b.triangles) m.triangles.push_back({t[0] + off, t[1] + off, t[2] + off});
  return m;
}

TriMesh transformed(const TriMesh& m, const Eigen::Matrix3d& rot, const Vec3d& shift) {
  TriMesh r = m;
  for (Vec3d& p : r.positions) p = rot * p + shift;
  return r;
}

// ---- Helpers on results ---------------------------------------------------------------------

VoxelModel voxelize_ok(const TriMesh& mesh, int resolution, int padding = 1) {
  VoxelModel model;
  std::string error;
  VoxelizeParams params;
  params.resolution = resolution;
  params.padding = padding;
  REQUIRE_MESSAGE(voxelize(mesh, params, model, error), error);
  return model;
}

std::vector<uint8_t> parities_ok(const TriMesh& mesh, int resolution, int padding = 1) {
  std::vector<uint8_t> par;
  Lattice lattice;
  std::string error;
  VoxelizeParams params;
  params.resolution = resolution;
  params.padding = padding;
  REQUIRE_MESSAGE(voxelize_parities(mesh, params, lattice, par, error), error);
  return par;
}

Vec3d node_pos(const Lattice& l, uint32_t n) {
  int32_t c[3];
  l.node_coords(n, c);
  return l.node_position(c[0], c[1], c[2]);
}

uint32_t axis_stride(const Lattice& l, int a) {
  return a == 0 ? 1u : a == 1 ? uint32_t(l.nx + 1) : uint32_t(l.nx + 1) * uint32_t(l.ny + 1);
}

// Structural invariants of any voxelization: crossings sorted, exactly the sign-change edges
// have data, t in [0, 1], normals point from the inside node to the outside node, the border
// holds no inside node, occupied_voxels matches a brute-force count.
void check_structure(const VoxelModel& m) {
  const Lattice& l = m.lattice;
  const uint64_t nodes = l.node_count();
  REQUIRE(m.inside.size() == (nodes + 63) / 64);
  for (size_t i = 1; i < m.crossings.size(); ++i) REQUIRE(m.crossings[i - 1].edge < m.crossings[i].edge);
  size_t expected = 0;
  size_t bad = 0;
  for (uint32_t n = 0; n < nodes; ++n) {
    int32_t c[3];
    l.node_coords(n, c);
    const int32_t dims[3] = {l.nx, l.ny, l.nz};
    for (int a = 0; a < 3; ++a) {
      if (c[a] == dims[a]) continue;
      const uint32_t e = Lattice::edge(n, a);
      const bool in0 = m.is_inside(n), in1 = m.is_inside(n + axis_stride(l, a));
      const EdgeCrossing* x = m.find_crossing(e);
      if (in0 != in1) {
        ++expected;
        if (!x) {
          ++bad;
          continue;
        }
        if (!(x->t >= 0.0f && x->t <= 1.0f)) ++bad;
        const Vec3d nrm = decode_normal(x->normal);
        if (!((in0 ? nrm[a] : -nrm[a]) >= 0.0)) ++bad;
      } else if (x) {
        ++bad;
      }
    }
  }
  CHECK(bad == 0);
  CHECK(expected == m.crossings.size());
  // Border nodes (padding >= 1 in these tests) are outside.
  uint32_t border_inside = 0, occupied = 0;
  for (int32_t k = 0; k <= l.nz; ++k)
    for (int32_t j = 0; j <= l.ny; ++j)
      for (int32_t i = 0; i <= l.nx; ++i) {
        const bool border = i == 0 || j == 0 || k == 0 || i == l.nx || j == l.ny || k == l.nz;
        if (border && m.is_inside(l.node(i, j, k))) ++border_inside;
      }
  CHECK(border_inside == 0);
  for (int32_t k = 0; k < l.nz; ++k)
    for (int32_t j = 0; j < l.ny; ++j)
      for (int32_t i = 0; i < l.nx; ++i) {
        bool any = false;
        for (int c = 0; c < 8; ++c) any |= m.is_inside(l.node(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1)));
        occupied += any;
      }
  CHECK(occupied == m.occupied_voxels);
}

// Per-axis parities of a closed convex mesh against its face planes: nodes farther than `tol`
// from every face plane they are near must be classified correctly by each axis on its own.
void check_convex_parities(const TriMesh& mesh, const Lattice& l, const std::vector<uint8_t>& par,
                           double tol) {
  std::vector<std::pair<Vec3d, double>> planes;
  for (const Tri& t : mesh.triangles) {
    const Vec3d& a = mesh.positions[t[0]];
    Vec3d n = (mesh.positions[t[1]] - a).cross(mesh.positions[t[2]] - a);
    if (n.norm() == 0) continue;
    n.normalize();
    planes.emplace_back(n, n.dot(a));
  }
  size_t wrong = 0, checked = 0;
  for (uint32_t node = 0; node < par.size(); ++node) {
    const Vec3d p = node_pos(l, node);
    double s = -1e300;
    for (const auto& [n, d] : planes) s = std::max(s, n.dot(p) - d);
    if (std::abs(s) <= tol) continue;
    const uint8_t want = s < 0 ? 7 : 0;
    ++checked;
    if (par[node] != want) ++wrong;
  }
  CHECK(checked > 0);
  CHECK(wrong == 0);
}

bool same_crossings(const VoxelModel& a, const VoxelModel& b) {
  if (a.crossings.size() != b.crossings.size()) return false;
  for (size_t i = 0; i < a.crossings.size(); ++i) {
    const EdgeCrossing& x = a.crossings[i];
    const EdgeCrossing& y = b.crossings[i];
    if (x.edge != y.edge || x.t != y.t || x.normal[0] != y.normal[0] || x.normal[1] != y.normal[1] ||
        x.normal[2] != y.normal[2])
      return false;
  }
  return true;
}

int majority(uint8_t p) { return ((p & 1) + ((p >> 1) & 1) + ((p >> 2) & 1)) >= 2; }

}  // namespace

TEST_SUITE("voxelize") {
  TEST_CASE("icosphere: volume, signs away from the surface, crossings on the sphere, outward normals") {
    const Vec3d c(0.13, -0.07, 0.21);
    const double r = 1.0;
    const TriMesh mesh = icosphere(c, r, 5);
    const VoxelModel m = voxelize_ok(mesh, 64);
    const Lattice& l = m.lattice;
    const double h = l.voxel_size;
    check_structure(m);

    // Inscribed radius of the polyhedron (closest face plane to the centre).
    double r_in = r;
    for (const Tri& t : mesh.triangles) {
      const Vec3d& a = mesh.positions[t[0]];
      const Vec3d n = (mesh.positions[t[1]] - a).cross(mesh.positions[t[2]] - a).normalized();
      r_in = std::min(r_in, std::abs(n.dot(a - c)));
    }
    CHECK(r - r_in < 0.01 * h);

    uint64_t inside = 0, wrong = 0, wrong_axis = 0;
    const std::vector<uint8_t> par = parities_ok(mesh, 64);
    REQUIRE(par.size() == l.node_count());
    for (uint32_t n = 0; n < l.node_count(); ++n) {
      const bool in = m.is_inside(n);
      inside += in;
      CHECK(int(in) == majority(par[n]));
      const double d = (node_pos(l, n) - c).norm();
      if (d < r_in - 1e-9 * h || d > r + 1e-9 * h) {
        const bool want = d < r;
        wrong += in != want;
        wrong_axis += par[n] != (want ? 7 : 0);
      }
    }
    CHECK(wrong == 0);
    CHECK(wrong_axis == 0);  // on a closed mesh every axis alone is right
    const double volume = double(inside) * h * h * h;
    CHECK(volume == doctest::Approx(4.0 / 3.0 * M_PI * r * r * r).epsilon(0.02));

    REQUIRE(m.crossings.size() > 1000);
    double worst = 0, worst_dot = 1;
    for (const EdgeCrossing& x : m.crossings) {
      const Vec3d p = crossing_position(l, x);
      worst = std::max(worst, std::abs((p - c).norm() - r) / h);
      worst_dot = std::min(worst_dot, decode_normal(x.normal).dot((p - c).normalized()));
    }
    CHECK(worst < 0.01);
    CHECK(worst_dot > 0.9);
    // Stronger: every crossing lies on the polyhedron, i.e. between its in- and circumsphere.
    size_t off = 0;
    for (const EdgeCrossing& x : m.crossings) {
      const double d = (crossing_position(l, x) - c).norm();
      off += d < r_in - 1e-5 * h || d > r + 1e-5 * h;
    }
    CHECK(off == 0);
    // The row index finds what a search of all the crossings finds, on every edge of the lattice
    // (crossings and not), and a model without it (or with a stale one) still finds them.
    REQUIRE(m.crossing_rows.size() == uint64_t(l.ny + 1) * uint64_t(l.nz + 1) + 1);
    VoxelModel plain = m;
    plain.crossing_rows.clear();
    VoxelModel stale = m;
    stale.crossings.pop_back();
    uint32_t found = 0, differ = 0, stale_differ = 0;
    for (uint32_t e = 0; e < uint32_t(3 * l.node_count()) + 7; ++e) {
      const EdgeCrossing* a = m.find_crossing(e);
      const EdgeCrossing* b = plain.find_crossing(e);
      found += a != nullptr;
      differ += (a == nullptr) != (b == nullptr) || (a && a->edge != b->edge);
      const EdgeCrossing* z = stale.find_crossing(e);
      stale_differ += (z == nullptr) != (b == nullptr) && e != m.crossings.back().edge;
    }
    CHECK(found == m.crossings.size());
    CHECK(differ == 0);
    CHECK(stale_differ == 0);
    MESSAGE("icosphere res 64: " << m.crossings.size() << " crossings, " << m.occupied_voxels
                                 << " occupied voxels, " << double(m.memory_bytes()) / m.occupied_voxels
                                 << " bytes per occupied voxel; worst crossing error " << worst << " voxel");
  }

  TEST_CASE("inward winding gives identical signs and Hermite data, repeated runs are identical") {
    const TriMesh mesh = icosphere(Vec3d(0.3, 0.1, -0.2), 0.8, 3);
    const VoxelModel a = voxelize_ok(mesh, 40);
    const VoxelModel b = voxelize_ok(reversed(mesh), 40);
    const VoxelModel a2 = voxelize_ok(mesh, 40);
    CHECK(a.inside == b.inside);
    CHECK(same_crossings(a, b));
    CHECK(a.occupied_voxels == b.occupied_voxels);
    CHECK(a.inside == a2.inside);
    CHECK(same_crossings(a, a2));
  }

  TEST_CASE("a hole changes signs only near the hole") {
    const Vec3d c(0.02, 0.05, -0.03);
    const TriMesh closed = icosphere(c, 1.0, 4);
    const Vec3d hole = c + Vec3d(0.3, 0.5, 0.8).normalized();
    TriMesh holed = closed;
    holed.triangles.clear();
    double rho = 0;
    size_t removed = 0;
    for (const Tri& t : closed.triangles) {
      const Vec3d g = (closed.positions[t[0]] + closed.positions[t[1]] + closed.positions[t[2]]) / 3.0;
      if ((g - hole).norm() < 0.12) {
        ++removed;
        for (uint32_t v : t) rho = std::max(rho, (closed.positions[v] - hole).norm());
        continue;
      }
      holed.triangles.push_back(t);
    }
    REQUIRE(removed >= 4);
    REQUIRE_FALSE(is_watertight(holed));
    // Same box, so the same lattice.
    const VoxelModel a = voxelize_ok(closed, 48);
    const VoxelModel b = voxelize_ok(holed, 48);
    REQUIRE(a.lattice.origin == b.lattice.origin);
    check_structure(b);
    const Lattice& l = a.lattice;
    size_t differ = 0, differ_far = 0;
    for (uint32_t n = 0; n < l.node_count(); ++n) {
      if (a.is_inside(n) == b.is_inside(n)) continue;
      ++differ;
      const double d = (node_pos(l, n) - hole).cwiseAbs().maxCoeff();
      if (d > rho + 2 * l.voxel_size) ++differ_far;
    }
    CHECK(differ_far == 0);
    MESSAGE("hole of " << removed << " triangles: " << differ << " node signs differ near it");
  }

  TEST_CASE("a small self-intersection (a vertex dragged over its neighbours) stays local") {
    const Vec3d c(0.02, -0.01, 0.03);
    const TriMesh sphere = icosphere(c, 1.0, 3);
    TriMesh folded = sphere;
    const uint32_t v = 100;
    const Vec3d radial = (sphere.positions[v] - c).normalized();
    const Vec3d tangent = radial.cross(Vec3d(0.3, 0.8, 0.5)).normalized();
    const double shift = 0.25;  // about two edge lengths: its fan folds over the neighbours
    folded.positions[v] += shift * tangent;
    REQUIRE(is_watertight(folded));
    const VoxelModel a = voxelize_ok(sphere, 40);
    const VoxelModel b = voxelize_ok(folded, 40);
    REQUIRE(a.lattice.origin == b.lattice.origin);
    check_structure(b);
    const Lattice& l = a.lattice;
    size_t differ = 0, differ_far = 0;
    for (uint32_t n = 0; n < l.node_count(); ++n) {
      if (a.is_inside(n) == b.is_inside(n)) continue;
      ++differ;
      differ_far += (node_pos(l, n) - sphere.positions[v]).norm() > shift + 0.15 + 2 * l.voxel_size;
    }
    CHECK(differ > 0);
    CHECK(differ_far == 0);
  }

  TEST_CASE("box with faces on lattice planes: half-open rule on every axis, crossings at t = 1") {
    for (int n : {1, 2}) {
      // Extents are whole voxels (voxel size 1): faces on node planes, vertices on nodes.
      const TriMesh mesh = box_mesh(Vec3d(0, 0, 0), Vec3d(8, 6, 4), n);
      const VoxelModel m = voxelize_ok(mesh, 8);
      const Lattice& l = m.lattice;
      REQUIRE(l.voxel_size == 1.0);
      REQUIRE(l.origin == Vec3d(-1, -1, -1));
      REQUIRE(l.nx == 10);
      REQUIRE(l.ny == 8);
      REQUIRE(l.nz == 6);
      const std::vector<uint8_t> par = parities_ok(mesh, 8);
      size_t wrong = 0;
      for (int32_t k = 0; k <= l.nz; ++k)
        for (int32_t j = 0; j <= l.ny; ++j)
          for (int32_t i = 0; i <= l.nx; ++i) {
            const bool want = i >= 1 && i < 9 && j >= 1 && j < 7 && k >= 1 && k < 5;
            const uint32_t node = l.node(i, j, k);
            wrong += m.is_inside(node) != want;
            wrong += par[node] != (want ? 7 : 0);
          }
      CHECK(wrong == 0);
      check_structure(m);
      CHECK(m.crossings.size() == 2 * (8 * 6 + 6 * 4 + 4 * 8) * 1u);
      for (const EdgeCrossing& x : m.crossings) {
        CHECK(x.t == 1.0f);  // the crossing sits on a node and belongs to the edge before it
        const int a = int(x.edge % 3);
        CHECK(std::abs(int(x.normal[a])) == 32767);
        CHECK(x.normal[(a + 1) % 3] == 0);
        CHECK(x.normal[(a + 2) % 3] == 0);
      }
      CHECK(m.occupied_voxels == 9u * 7u * 5u);  // voxels with a corner in [1,9)x[1,7)x[1,5)
    }
  }

  TEST_CASE("octahedra with vertices on nodes: rays through vertices and edges follow the perturbation rule") {
    // Ray along axis a through (u, v) behaves as the generic line through (u + eps, v + eps^2):
    // the node at coordinate x is inside by that ray iff  x/ra + |u|/ru + |v|/rv < 1  and
    // -x/ra + |u|/ru + |v|/rv <= 1 (a crossing at a node lies before it).
    const int cases[][3] = {{5, 5, 5}, {5, 3, 4}, {7, 2, 5}, {6, 6, 1}, {3, 8, 2}};
    size_t surface_nodes = 0;
    for (const auto& rr : cases) {
      const Vec3d radii(rr[0], rr[1], rr[2]);
      const TriMesh mesh = octahedron(Vec3d::Zero(), radii);
      const int res = 2 * std::max({rr[0], rr[1], rr[2]});
      const VoxelModel m = voxelize_ok(mesh, res);
      const std::vector<uint8_t> par = parities_ok(mesh, res);
      const Lattice& l = m.lattice;
      REQUIRE(l.voxel_size == 1.0);
      check_structure(m);
      size_t wrong_axis = 0, wrong_vote = 0;
      const int64_t R = int64_t(rr[0]) * rr[1] * rr[2];
      for (uint32_t node = 0; node < l.node_count(); ++node) {
        const Vec3d p = node_pos(l, node);
        const int64_t x[3] = {std::llround(p.x()), std::llround(p.y()), std::llround(p.z())};
        REQUIRE(std::abs(p.x() - double(x[0])) == 0.0);
        int64_t w[3];  // |x_a| * R / r_a
        for (int a = 0; a < 3; ++a) w[a] = R / rr[a];
        surface_nodes += std::abs(x[0]) * w[0] + std::abs(x[1]) * w[1] + std::abs(x[2]) * w[2] == R;
        uint8_t want = 0;
        for (int a = 0; a < 3; ++a) {
          const int u = (a + 1) % 3, v = (a + 2) % 3;
          const int64_t rest = std::abs(x[u]) * w[u] + std::abs(x[v]) * w[v];
          const bool in = x[a] * w[a] + rest < R && -x[a] * w[a] + rest <= R;
          want |= uint8_t(in << a);
        }
        wrong_axis += par[node] != want;
        wrong_vote += int(m.is_inside(node)) != majority(want);
      }
      CHECK(wrong_axis == 0);
      CHECK(wrong_vote == 0);
    }
    CHECK(surface_nodes > 100);  // plenty of nodes exactly on faces, edges and vertices
  }

  TEST_CASE("UV sphere with poles and equator vertices on lattice nodes") {
    const TriMesh mesh = uv_sphere(Vec3d::Zero(), 10.0, 32, 16);
    const VoxelModel m = voxelize_ok(mesh, 20);
    REQUIRE(m.lattice.voxel_size == 1.0);
    REQUIRE(m.lattice.origin == Vec3d(-11, -11, -11));
    check_structure(m);
    check_convex_parities(mesh, m.lattice, parities_ok(mesh, 20), 1e-9);
    // The z ray through both poles (a fan of 32 triangles at each end): enters at the lower pole
    // (node 1, which counts as after the crossing) and leaves at the upper one (node 21).
    const std::vector<uint8_t> par = parities_ok(mesh, 20);
    for (int32_t k = 0; k <= 22; ++k) {
      const uint32_t node = m.lattice.node(11, 11, k);
      CHECK(((par[node] >> 2) & 1) == (k >= 1 && k < 21));
      if (k >= 2 && k <= 20) CHECK(m.is_inside(node));
    }
    // The lower pole node is outside by the x and y rays (they graze the pole): the vote puts it
    // outside, and its z edge takes the pole crossing at t = 0.
    CHECK_FALSE(m.is_inside(m.lattice.node(11, 11, 1)));
    const EdgeCrossing* pole = m.find_crossing(Lattice::edge(m.lattice.node(11, 11, 1), 2));
    REQUIRE(pole != nullptr);
    CHECK(pole->t == 0.0f);
    CHECK(decode_normal(pole->normal).z() < -0.9);
  }

  TEST_CASE("random rotations of convex shapes: every axis parity right off the surface, crossings on it") {
    std::mt19937 rng(12345);
    std::uniform_real_distribution<double> uni(-1.0, 1.0);
    for (int iter = 0; iter < 24; ++iter) {
      const Eigen::Quaterniond q = Eigen::Quaterniond(uni(rng), uni(rng), uni(rng), uni(rng)).normalized();
      const Vec3d shift(uni(rng), uni(rng), uni(rng));
      const TriMesh base = (iter % 2 == 0) ? box_mesh(Vec3d(-1, -0.6, -0.3), Vec3d(1, 0.6, 0.3), 1 + iter % 3)
                                           : icosphere(Vec3d::Zero(), 1.0, iter % 3);
      const TriMesh mesh = transformed(base, q.toRotationMatrix(), shift);
      const int res = 6 + int(rng() % 40);
      const VoxelModel m = voxelize_ok(mesh, res);
      check_structure(m);
      check_convex_parities(mesh, m.lattice, parities_ok(mesh, res), 1e-6 * m.lattice.voxel_size);
      // Crossings lie on the boundary of the convex polyhedron.
      double worst = 0;
      for (const EdgeCrossing& x : m.crossings) {
        const Vec3d p = crossing_position(m.lattice, x);
        double s = -1e300;
        for (const Tri& t : mesh.triangles) {
          const Vec3d& a = mesh.positions[t[0]];
          const Vec3d n = (mesh.positions[t[1]] - a).cross(mesh.positions[t[2]] - a).normalized();
          s = std::max(s, n.dot(p - a));
        }
        worst = std::max(worst, std::abs(s) / m.lattice.voxel_size);
      }
      CHECK(worst < 1e-5);
    }
  }

  TEST_CASE("torus: hole outside, ring inside, every axis right away from the surface") {
    const Vec3d c(0.05, 0.03, -0.02);
    const double R = 1.0, r = 0.35;
    const TriMesh mesh = torus(c, R, r, 96, 48);
    REQUIRE(is_watertight(mesh));
    const VoxelModel m = voxelize_ok(mesh, 64);
    const Lattice& l = m.lattice;
    const double h = l.voxel_size;
    check_structure(m);
    const std::vector<uint8_t> par = parities_ok(mesh, 64);
    size_t wrong = 0, ring_inside = 0;
    for (uint32_t n = 0; n < l.node_count(); ++n) {
      const Vec3d p = node_pos(l, n) - c;
      const double d = Eigen::Vector2d(std::hypot(p.x(), p.y()) - R, p.z()).norm() - r;
      if (std::abs(d) < h) continue;
      const bool want = d < 0;
      wrong += par[n] != (want ? 7 : 0);
      wrong += m.is_inside(n) != want;
      ring_inside += want;
    }
    CHECK(wrong == 0);
    CHECK(ring_inside > 1000);
    // The node nearest the centre of the hole.
    const Vec3d g = (c - l.origin) / h;
    const uint32_t centre = l.node(int32_t(std::lround(g.x())), int32_t(std::lround(g.y())), int32_t(std::lround(g.z())));
    CHECK_FALSE(m.is_inside(centre));
    const Vec3d g2 = (c + Vec3d(R, 0, 0) - l.origin) / h;
    CHECK(m.is_inside(l.node(int32_t(std::lround(g2.x())), int32_t(std::lround(g2.y())), int32_t(std::lround(g2.z())))));
  }

  TEST_CASE("two components") {
    const TriMesh a = icosphere(Vec3d(-1.5, 0.01, 0.02), 1.0, 3);
    const TriMesh b = icosphere(Vec3d(1.5, -0.02, 0.01), 0.7, 3);
    const TriMesh mesh = merged(a, b);
    const VoxelModel m = voxelize_ok(mesh, 50);
    const Lattice& l = m.lattice;
    check_structure(m);
    const std::vector<uint8_t> par = parities_ok(mesh, 50);
    size_t wrong = 0, in_a = 0, in_b = 0;
    for (uint32_t n = 0; n < l.node_count(); ++n) {
      const Vec3d p = node_pos(l, n);
      const double da = (p - Vec3d(-1.5, 0.01, 0.02)).norm(), db = (p - Vec3d(1.5, -0.02, 0.01)).norm();
      const double margin = 0.05;  // tessellation of subdivision 3 is well below this
      if (std::abs(da - 1.0) < margin || std::abs(db - 0.7) < margin) continue;
      const bool want = da < 1.0 || db < 0.7;
      wrong += par[n] != (want ? 7 : 0);
      in_a += da < 1.0 && m.is_inside(n);
      in_b += db < 0.7 && m.is_inside(n);
    }
    CHECK(wrong == 0);
    CHECK(in_a > 1000);
    CHECK(in_b > 300);
  }

  TEST_CASE("degenerate and same-winding duplicate triangles change nothing") {
    const TriMesh base = icosphere(Vec3d(0.01, 0.02, 0.03), 1.0, 3);
    TriMesh noisy = base;
    const auto& T = base.triangles;
    for (size_t i = 0; i < T.size(); i += 3) noisy.triangles.push_back({T[i][1], T[i][2], T[i][0]});  // rotated
    for (size_t i = 1; i < T.size(); i += 5) noisy.triangles.push_back(T[i]);                         // exact
    // Geometric duplicates over fresh copies of the vertices.
    for (size_t i = 2; i < T.size(); i += 7) {
      const uint32_t v = uint32_t(noisy.positions.size());
      for (int c = 0; c < 3; ++c) noisy.positions.push_back(base.positions[T[i][c]]);
      noisy.triangles.push_back({v + 2, v, v + 1});
    }
    noisy.triangles.push_back({T[9][0], T[9][0], T[9][1]});  // repeated index
    noisy.triangles.push_back({T[9][2], T[9][2], T[9][2]});
    // Collinear triangle crossing the interior (equal y, z: degenerate in every projection).
    const uint32_t v0 = uint32_t(noisy.positions.size());
    noisy.positions.emplace_back(-0.5, 0.0625, 0.125);
    noisy.positions.emplace_back(0.25, 0.0625, 0.125);
    noisy.positions.emplace_back(0.5, 0.0625, 0.125);
    noisy.triangles.push_back({v0, v0 + 1, v0 + 2});
    noisy.triangles.push_back(T[11]);
    noisy.triangles.push_back(T[11]);
    // Put some of the additions first: the original order must not matter.
    std::rotate(noisy.triangles.begin(), noisy.triangles.end() - 5, noisy.triangles.end());
    const VoxelModel a = voxelize_ok(base, 40);
    const VoxelModel b = voxelize_ok(noisy, 40);
    REQUIRE(a.lattice.origin == b.lattice.origin);
    CHECK(a.inside == b.inside);
    CHECK(same_crossings(a, b));
  }

  TEST_CASE("two boxes sharing a face (opposite-winding copies of it) voxelize as their union") {
    const TriMesh a = box_mesh(Vec3d(0, 0, 0), Vec3d(4, 3, 2));
    const TriMesh b = box_mesh(Vec3d(4, 0, 0), Vec3d(8, 3, 2));
    const VoxelModel m = voxelize_ok(merged(a, b), 8);
    const VoxelModel u = voxelize_ok(box_mesh(Vec3d(0, 0, 0), Vec3d(8, 3, 2)), 8);
    REQUIRE(m.lattice.origin == u.lattice.origin);
    CHECK(m.inside == u.inside);
    CHECK(same_crossings(m, u));
  }

  TEST_CASE("several crossings in one edge: the one closest to the edge middle") {
    // Lattice x = world x + 1 (voxel size 1): a thin slab at x in [2.1, 2.2] and a body from 2.6
    // put three crossings in the x edge (2, 3) of the rays through it; a small box far off in
    // y, z fixes the mesh box.
    TriMesh mesh = merged(box_mesh(Vec3d(1.1, 1, 1), Vec3d(1.2, 4, 4)), box_mesh(Vec3d(1.6, 1, 1), Vec3d(6, 4, 4)));
    mesh = merged(mesh, box_mesh(Vec3d(0, 5.5, 5.5), Vec3d(0.05, 6, 6)));
    const VoxelModel m = voxelize_ok(mesh, 6);
    const Lattice& l = m.lattice;
    REQUIRE(l.voxel_size == 1.0);
    REQUIRE(l.origin.x() == -1.0);
    check_structure(m);
    for (int32_t j = 1; j <= 3; ++j) {  // rays at y, z in [1, 4): inside the slab's face by the tie rule
      for (int32_t k = 1; k <= 3; ++k) {
        CHECK_FALSE(m.is_inside(l.node(2, j, k)));
        CHECK(m.is_inside(l.node(3, j, k)));
        const EdgeCrossing* x = m.find_crossing(Lattice::edge(l.node(2, j, k), 0));
        REQUIRE(x != nullptr);
        CHECK(x->t == doctest::Approx(0.6).epsilon(1e-6));
        CHECK(x->normal[0] == -32767);
      }
    }
  }

  TEST_CASE("open box: the vote closes the missing face with midpoint crossings") {
    TriMesh box = box_mesh(Vec3d(0.3, 0.2, 0.4), Vec3d(5.3, 4.6, 4.1));
    TriMesh open = box;
    open.triangles.clear();
    for (const Tri& t : box.triangles) {
      bool on_max_x = true;
      for (uint32_t v : t) on_max_x &= box.positions[v].x() == 5.3;
      if (!on_max_x) open.triangles.push_back(t);
    }
    REQUIRE(open.triangles.size() == 10);
    const VoxelModel closed_m = voxelize_ok(box, 20);
    const VoxelModel m = voxelize_ok(open, 20);
    check_structure(m);
    CHECK(m.inside == closed_m.inside);
    size_t fallback = 0;
    for (const EdgeCrossing& x : m.crossings) {
      const EdgeCrossing* c = closed_m.find_crossing(x.edge);
      REQUIRE(c != nullptr);
      const Vec3d p = crossing_position(m.lattice, *c);
      if (x.edge % 3 == 0 && std::abs(p.x() - 5.3) < 1e-9) {
        ++fallback;
        CHECK(x.t == 0.5f);
        CHECK(x.normal[0] == 32767);
      } else {
        CHECK(x.t == c->t);
      }
    }
    CHECK(fallback > 50);
  }

  TEST_CASE("thin plates: nothing between node planes, exactly one node plane when it holds one") {
    {
      const TriMesh plate = box_mesh(Vec3d(0, 0, 0), Vec3d(8, 8, 0.3));
      const VoxelModel m = voxelize_ok(plate, 8);
      size_t inside = 0;
      for (uint32_t n = 0; n < m.lattice.node_count(); ++n) inside += m.is_inside(n);
      CHECK(inside == 0);
      CHECK(m.crossings.empty());
      CHECK(m.occupied_voxels == 0);
    }
    {
      const TriMesh plate = box_mesh(Vec3d(0, 0, 0), Vec3d(8, 8, 1.2));
      const VoxelModel m = voxelize_ok(plate, 8);
      const Lattice& l = m.lattice;
      REQUIRE(l.nz == 4);
      check_structure(m);
      const std::vector<uint8_t> par = parities_ok(plate, 8);
      size_t wrong = 0;
      for (int32_t k = 0; k <= l.nz; ++k)
        for (int32_t j = 0; j <= l.ny; ++j)
          for (int32_t i = 0; i <= l.nx; ++i) {
            const bool want = k == 2 && i >= 1 && i < 9 && j >= 1 && j < 9;
            wrong += par[l.node(i, j, k)] != (want ? 7 : 0);
          }
      CHECK(wrong == 0);
    }
  }

  TEST_CASE("long lattice (128-bit edge functions) and padding 0") {
    const TriMesh mesh = octahedron(Vec3d::Zero(), Vec3d(1050, 2, 3));
    const VoxelModel m = voxelize_ok(mesh, 2100);
    REQUIRE(m.lattice.nx > 2000);
    check_structure(m);
    const std::vector<uint8_t> par = parities_ok(mesh, 2100);
    const Lattice& l = m.lattice;
    size_t wrong = 0;
    const int64_t rr[3] = {1050, 2, 3};
    const int64_t R = rr[0] * rr[1] * rr[2];
    for (uint32_t node = 0; node < l.node_count(); ++node) {
      const Vec3d p = node_pos(l, node);
      const int64_t x[3] = {std::llround(p.x()), std::llround(p.y()), std::llround(p.z())};
      uint8_t want = 0;
      for (int a = 0; a < 3; ++a) {
        const int u = (a + 1) % 3, v = (a + 2) % 3;
        const int64_t rest = std::abs(x[u]) * (R / rr[u]) + std::abs(x[v]) * (R / rr[v]);
        want |= uint8_t((x[a] * (R / rr[a]) + rest < R && -x[a] * (R / rr[a]) + rest <= R) << a);
      }
      wrong += par[node] != want;
    }
    CHECK(wrong == 0);

    // A rotated long box through the wide path: plane tests.
    // Tilted by a few voxels over its length, so rays cross its long faces at shallow angles.
    const Eigen::Matrix3d rot = Eigen::AngleAxisd(0.004, Vec3d(0.2, 1, 0.7).normalized()).toRotationMatrix();
    const TriMesh rod = transformed(box_mesh(Vec3d(-10, -0.02, -0.015), Vec3d(10, 0.02, 0.015)), rot, Vec3d(0.1, 0, 0));
    const VoxelModel mr = voxelize_ok(rod, 2200);
    check_structure(mr);
    check_convex_parities(rod, mr.lattice, parities_ok(rod, 2200), 1e-6 * mr.lattice.voxel_size);

    // Padding 0: the box touches the border nodes; still a consistent sign field.
    const TriMesh box = box_mesh(Vec3d(0, 0, 0), Vec3d(4, 3, 2));
    const std::vector<uint8_t> p0 = parities_ok(box, 4, 0);
    Lattice l0;
    std::string error;
    std::vector<uint8_t> tmp;
    VoxelizeParams params;
    params.resolution = 4;
    params.padding = 0;
    REQUIRE(voxelize_parities(box, params, l0, tmp, error));
    REQUIRE(l0.origin == Vec3d(0, 0, 0));
    size_t wrong0 = 0;
    for (int32_t k = 0; k <= l0.nz; ++k)
      for (int32_t j = 0; j <= l0.ny; ++j)
        for (int32_t i = 0; i <= l0.nx; ++i) {
          const bool want = i < 4 && j < 3 && k < 2;
          wrong0 += p0[l0.node(i, j, k)] != (want ? 7 : 0);
        }
    CHECK(wrong0 == 0);
  }

  TEST_CASE("estimate and refusals") {
    const TriMesh mesh = icosphere(Vec3d::Zero(), 1.0, 4);
    const Aabb box = mesh_bounds(mesh);
    VoxelizeParams huge;
    huge.resolution = 1000000;
    CHECK(estimate_voxelize_bytes(box, mesh.triangles.size(), huge) == UINT64_MAX);
    VoxelizeParams small;
    small.resolution = 48;
    const uint64_t est = estimate_voxelize_bytes(box, mesh.triangles.size(), small);
    const VoxelModel m = voxelize_ok(mesh, 48);
    CHECK(est >= m.memory_bytes());
    CHECK(est < 64ull << 20);
    // Grows with resolution.
    VoxelizeParams mid;
    mid.resolution = 400;
    CHECK(estimate_voxelize_bytes(box, mesh.triangles.size(), mid) > est);

    VoxelModel out;
    std::string error;
    CHECK_FALSE(voxelize(mesh, huge, out, error));
    CHECK(error.find("too many nodes") != std::string::npos);
    CHECK(error.find('\n') == std::string::npos);
    VoxelizeParams zero;
    zero.resolution = 0;
    error.clear();
    CHECK_FALSE(voxelize(mesh, zero, out, error));
    CHECK_FALSE(error.empty());
    error.clear();
    CHECK_FALSE(voxelize(TriMesh{}, small, out, error));
    CHECK_FALSE(error.empty());
    TriMesh bad = mesh;
    bad.triangles.push_back({0, 1, uint32_t(bad.positions.size())});
    error.clear();
    CHECK_FALSE(voxelize(bad, small, out, error));
    CHECK_FALSE(error.empty());
    TriMesh flat;  // every vertex on one point: degenerate box
    flat.positions = {Vec3d(1, 1, 1), Vec3d(1, 1, 1), Vec3d(1, 1, 1)};
    flat.triangles = {{0, 1, 2}};
    error.clear();
    CHECK_FALSE(voxelize(flat, small, out, error));
    CHECK_FALSE(error.empty());
  }

  TEST_CASE("normal packing and crossing positions") {
    const Vec3d n = Vec3d(0.3, -0.5, 0.8).normalized();
    int16_t packed[3];
    encode_normal(n, packed);
    CHECK((decode_normal(packed) - n).norm() < 1e-4);
    encode_normal(Vec3d(-1, 0, 0), packed);
    CHECK(packed[0] == -32767);
    CHECK(decode_normal(packed) == Vec3d(-1, 0, 0));

    Lattice l;
    l.origin = Vec3d(1, 2, 3);
    l.voxel_size = 0.5;
    l.nx = 4;
    l.ny = 5;
    l.nz = 6;
    EdgeCrossing x{};
    x.edge = Lattice::edge(l.node(1, 2, 3), 1);
    x.t = 0.25f;
    CHECK((crossing_position(l, x) - Vec3d(1.5, 3.125, 4.5)).norm() < 1e-12);

    VoxelModel m;
    m.crossings = {EdgeCrossing{3, 0.5f, {0, 0, 0}, 0}, EdgeCrossing{7, 0.5f, {0, 0, 0}, 0},
                   EdgeCrossing{20, 0.5f, {0, 0, 0}, 0}};
    CHECK(m.find_crossing(7) == &m.crossings[1]);
    CHECK(m.find_crossing(20) == &m.crossings[2]);
    CHECK(m.find_crossing(8) == nullptr);
    CHECK(m.find_crossing(0) == nullptr);
    CHECK(m.find_crossing(21) == nullptr);
  }
}
