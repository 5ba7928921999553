#include "sim/shapes.h"

#include <doctest/doctest.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <utility>

using namespace dvx;

namespace {

constexpr double kPi = 3.14159265358979323846;

// Signed volume by the divergence theorem (local so these tests do not depend on sim/mesh.cpp).
double volume_of(const TriMesh& m) {
  double v = 0.0;
  for (const Tri& t : m.triangles)
    v += m.positions[t[0]].dot(m.positions[t[1]].cross(m.positions[t[2]]));
  return v / 6.0;
}

// Topology summary: directed edge uses and undirected edge counts.
struct Topology {
  size_t edges = 0;             // undirected
  size_t boundary_edges = 0;    // used once
  size_t nonmanifold_edges = 0; // used more than twice
  size_t inconsistent = 0;      // a directed edge used twice (neighbours disagree on winding)
  size_t unused_vertices = 0;
  size_t degenerate_tris = 0;   // repeated index or zero area
};

Topology topology_of(const TriMesh& m) {
  Topology top;
  std::map<std::pair<uint32_t, uint32_t>, int> directed;
  std::map<std::pair<uint32_t, uint32_t>, int> undirected;
  std::vector<int> used(m.positions.size(), 0);
  for (const Tri& t : m.triangles) {
    const Vec3d& a = m.positions[t[0]];
    if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2] ||
        (m.positions[t[1]] - a).cross(m.positions[t[2]] - a).norm() == 0.0)
      ++top.degenerate_tris;
    for (int k = 0; k < 3; ++k) {
      const uint32_t u = t[k], v = t[(k + 1) % 3];
      used[u] = 1;
      ++directed[{u, v}];
      ++undirected[{std::min(u, v), std::max(u, v)}];
    }
  }
  top.edges = undirected.size();
  for (const auto& [e, n] : undirected) {
    if (n == 1) ++top.boundary_edges;
    if (n > 2) ++top.nonmanifold_edges;
  }
  for (const auto& [e, n] : directed)
    if (n > 1) ++top.inconsistent;
  top.unused_vertices = static_cast<size_t>(std::count(used.begin(), used.end(), 0));
  return top;
}

// Closed, consistently wound, every edge shared by exactly two triangles, no junk.
void check_closed(const TriMesh& m) {
  REQUIRE(!m.triangles.empty());
  const Topology top = topology_of(m);
  CHECK(top.boundary_edges == 0);
  CHECK(top.nonmanifold_edges == 0);
  CHECK(top.inconsistent == 0);
  CHECK(top.unused_vertices == 0);
  CHECK(top.degenerate_tris == 0);
  // No two vertices at the same position.
  std::set<std::array<double, 3>> unique;
  for (const Vec3d& p : m.positions) unique.insert({p.x(), p.y(), p.z()});
  CHECK(unique.size() == m.positions.size());
}

long euler_characteristic(const TriMesh& m) {
  const Topology top = topology_of(m);
  return static_cast<long>(m.positions.size()) - static_cast<long>(top.edges) + static_cast<long>(m.triangles.size());
}

}  // namespace

TEST_SUITE("shapes") {
  TEST_CASE("UV sphere: closed, outward, volume within tessellation error, vertices on the sphere") {
    const Vec3d c(0.3, -1, 2);
    const TriMesh m = make_sphere(c, 1.5, 64);
    check_closed(m);
    CHECK(euler_characteristic(m) == 2);
    CHECK(m.positions.size() == 2 + 31 * 64);
    const double exact = 4.0 / 3.0 * kPi * 1.5 * 1.5 * 1.5;
    const double v = volume_of(m);
    // Inscribed polyhedron: slightly smaller than the sphere.
    CHECK(v < exact);
    CHECK(v > 0.99 * exact);
    for (const Vec3d& p : m.positions) CHECK((p - c).norm() == doctest::Approx(1.5).epsilon(1e-12));
  }

  TEST_CASE("icosphere: closed, outward, volume, vertex count") {
    const Vec3d c(1, 2, 3);
    for (int s = 0; s <= 4; ++s) {
      const TriMesh m = make_icosphere(c, 2.0, s);
      check_closed(m);
      CHECK(euler_characteristic(m) == 2);
      CHECK(m.triangles.size() == 20u * (1u << (2 * s)));
      CHECK(volume_of(m) > 0.0);
      for (const Vec3d& p : m.positions) CHECK((p - c).norm() == doctest::Approx(2.0).epsilon(1e-12));
    }
    const double exact = 4.0 / 3.0 * kPi * 8.0;
    const double v = volume_of(make_icosphere(c, 2.0, 4));
    CHECK(v < exact);
    CHECK(v > 0.995 * exact);
  }

  TEST_CASE("box: exact volume, shared border vertices for n x n faces") {
    for (int n : {1, 2, 5}) {
      const TriMesh m = make_box(Vec3d(1, 0, -1), Vec3d(0.5, 1, 2), Eigen::Matrix3d::Identity(), n);
      check_closed(m);
      CHECK(euler_characteristic(m) == 2);
      // Surface points of an (n+1)^3 lattice.
      CHECK(m.positions.size() == static_cast<size_t>(6 * n * n + 2));
      CHECK(m.triangles.size() == static_cast<size_t>(12 * n * n));
      CHECK(volume_of(m) == doctest::Approx(8.0 * 0.5 * 1 * 2).epsilon(1e-12));
      // Corners exactly at centre +- half extent.
      for (const Vec3d& p : m.positions) {
        CHECK(p.x() >= 0.5);
        CHECK(p.x() <= 1.5);
        CHECK(p.z() >= -3.0);
        CHECK(p.z() <= 1.0);
      }
    }
  }

  TEST_CASE("rotated box keeps its volume and stays closed and outward") {
    const Eigen::Matrix3d r =
        (Eigen::AngleAxisd(0.7, Vec3d(1, 2, 3).normalized()) * Eigen::AngleAxisd(-0.3, Vec3d::UnitX())).toRotationMatrix();
    const Vec3d c(2, -1, 0.5), h(0.3, 0.7, 1.1);
    const TriMesh m = make_box(c, h, r, 3);
    check_closed(m);
    CHECK(volume_of(m) == doctest::Approx(8.0 * h.prod()).epsilon(1e-12));
    // Vertices lie in the rotated box (local coordinates within the half extents).
    for (const Vec3d& p : m.positions) {
      const Vec3d local = r.transpose() * (p - c);
      CHECK((local.cwiseAbs().array() <= h.array() + 1e-12).all());
    }
  }

  TEST_CASE("torus: closed genus 1, volume 2 pi^2 R r^2 within tessellation error") {
    const TriMesh m = make_torus(Vec3d(0, 1, 0), 2.0, 0.5, 64, 32);
    check_closed(m);
    CHECK(euler_characteristic(m) == 0);
    const double exact = 2.0 * kPi * kPi * 2.0 * 0.25;
    const double v = volume_of(m);
    CHECK(v > 0.0);
    CHECK(v == doctest::Approx(exact).epsilon(0.01));
    // Every vertex at the minor radius from the core circle.
    for (const Vec3d& p : m.positions) {
      const Vec3d q = p - Vec3d(0, 1, 0);
      const double rho = std::hypot(q.x(), q.y());
      CHECK(std::hypot(rho - 2.0, q.z()) == doctest::Approx(0.5).epsilon(1e-12));
    }
  }

  TEST_CASE("U shape: closed, exact volume, two arms") {
    const Vec3d c(0.5, 0.25, -1);
    const double w = 3, h = 2, d = 1, a = 0.75;
    const TriMesh m = make_u_shape(c, w, h, d, a);
    check_closed(m);
    CHECK(euler_characteristic(m) == 2);
    CHECK(volume_of(m) == doctest::Approx(w * h * d - (w - 2 * a) * (h - a) * d).epsilon(1e-12));
    // Bounding box is width x height x depth about the centre.
    Vec3d lo = Vec3d::Constant(1e300), hi = Vec3d::Constant(-1e300);
    for (const Vec3d& p : m.positions) {
      lo = lo.cwiseMin(p);
      hi = hi.cwiseMax(p);
    }
    CHECK((hi - lo - Vec3d(w, h, d)).norm() < 1e-12);
    CHECK(((hi + lo) / 2 - c).norm() < 1e-12);
    // The notch: no triangle crosses the open middle above the bottom bar (centroids of the
    // top-level caps lie in the arms or the bar).
    for (const Tri& t : m.triangles) {
      const Vec3d g = (m.positions[t[0]] + m.positions[t[1]] + m.positions[t[2]]) / 3.0 - c;
      const bool in_notch = std::abs(g.x()) < w / 2 - a - 1e-9 && g.y() > -h / 2 + a + 1e-9;
      CHECK_FALSE(in_notch);
    }
    // Invalid proportions give an empty mesh.
    CHECK(make_u_shape(c, 1.0, 1.0, 1.0, 0.6).triangles.empty());
  }

  TEST_CASE("flip_winding negates the volume and keeps the topology") {
    const TriMesh m = make_icosphere(Vec3d(0, 0, 0), 1.0, 2);
    const TriMesh f = flip_winding(m);
    CHECK(volume_of(f) == doctest::Approx(-volume_of(m)).epsilon(1e-12));
    const Topology top = topology_of(f);
    CHECK(top.boundary_edges == 0);
    CHECK(top.inconsistent == 0);
    CHECK(f.positions.size() == m.positions.size());
  }

  TEST_CASE("merge_meshes concatenates and volumes add") {
    const TriMesh a = make_box(Vec3d(0, 0, 0), Vec3d(1, 1, 1), Eigen::Matrix3d::Identity(), 2);
    const TriMesh b = make_torus(Vec3d(5, 0, 0), 1.0, 0.3, 24, 12);
    const TriMesh m = merge_meshes(a, b);
    CHECK(m.positions.size() == a.positions.size() + b.positions.size());
    CHECK(m.triangles.size() == a.triangles.size() + b.triangles.size());
    check_closed(m);
    CHECK(euler_characteristic(m) == 2 + 0);
    CHECK(volume_of(m) == doctest::Approx(volume_of(a) + volume_of(b)).epsilon(1e-12));
  }

  TEST_CASE("cut_hole opens the surface around the centre only") {
    const TriMesh m = make_icosphere(Vec3d(0, 0, 0), 1.0, 3);
    const TriMesh h = cut_hole(m, Vec3d(0, 0, 1), 0.3);
    CHECK(h.triangles.size() < m.triangles.size());
    CHECK(h.triangles.size() > m.triangles.size() / 2);
    const Topology top = topology_of(h);
    CHECK(top.boundary_edges > 0);
    CHECK(top.nonmanifold_edges == 0);
    CHECK(top.inconsistent == 0);
    CHECK(top.unused_vertices == 0);
    // No remaining triangle has its centroid in the ball, and the far side is untouched.
    for (const Tri& t : h.triangles) {
      const Vec3d g = (h.positions[t[0]] + h.positions[t[1]] + h.positions[t[2]]) / 3.0;
      CHECK((g - Vec3d(0, 0, 1)).norm() > 0.3);
    }
    // A disc: V - E + F = 1.
    CHECK(euler_characteristic(h) == 1);
    // A ball missing the mesh removes nothing.
    CHECK(cut_hole(m, Vec3d(5, 5, 5), 0.5).triangles.size() == m.triangles.size());
  }
}
