// surface_stats and triangle_components on hand-made meshes with known answers.
#include "sim/surface_metrics.h"

#include <doctest/doctest.h>

#include <cmath>
#include <utility>
#include <vector>

using namespace dvx;

namespace {

// Tetrahedron (0,0,0), (1,0,0), (0,1,0), (0,0,1), wound outward: volume 1/6.
TriMesh tetrahedron() {
  TriMesh m;
  m.positions = {Vec3d(0, 0, 0), Vec3d(1, 0, 0), Vec3d(0, 1, 0), Vec3d(0, 0, 1)};
  m.triangles = {Tri{0, 2, 1}, Tri{0, 1, 3}, Tri{0, 3, 2}, Tri{1, 2, 3}};
  return m;
}

}  // namespace

TEST_SUITE("surface_metrics") {
  TEST_CASE("closed tetrahedron") {
    TriMesh m = tetrahedron();
    m.positions.push_back(Vec3d(5, 5, 5));  // unreferenced vertex: not counted
    const SurfaceStats s = surface_stats(m);
    CHECK(s.vertices == 4);
    CHECK(s.triangles == 4);
    CHECK(s.boundary_edges == 0);
    CHECK(s.nonmanifold_edges == 0);
    CHECK(s.misoriented_edges == 0);
    CHECK(s.components == 1);
    CHECK(s.euler == 2);
    CHECK(s.volume == doctest::Approx(1.0 / 6.0));
    CHECK(s.area == doctest::Approx(1.5 + std::sqrt(3.0) / 2.0));

    // Translation does not change the volume of a closed surface; inward winding negates it.
    for (Vec3d& p : m.positions) p += Vec3d(1e3, -2e3, 3e3);
    CHECK(surface_stats(m).volume == doctest::Approx(1.0 / 6.0));
    for (Tri& t : m.triangles) std::swap(t[1], t[2]);
    const SurfaceStats inv = surface_stats(m);
    CHECK(inv.volume == doctest::Approx(-1.0 / 6.0));
    CHECK(inv.misoriented_edges == 0);
  }

  TEST_CASE("open tetrahedron: three boundary edges") {
    TriMesh m = tetrahedron();
    m.triangles.pop_back();
    const SurfaceStats s = surface_stats(m);
    CHECK(s.vertices == 4);
    CHECK(s.triangles == 3);
    CHECK(s.boundary_edges == 3);
    CHECK(s.nonmanifold_edges == 0);
    CHECK(s.misoriented_edges == 0);
    CHECK(s.components == 1);
    CHECK(s.euler == 1);  // a disc
  }

  TEST_CASE("one flipped triangle: its three edges are misoriented") {
    TriMesh m = tetrahedron();
    std::swap(m.triangles[3][1], m.triangles[3][2]);
    const SurfaceStats s = surface_stats(m);
    CHECK(s.boundary_edges == 0);
    CHECK(s.nonmanifold_edges == 0);
    CHECK(s.misoriented_edges == 3);
    CHECK(s.euler == 2);
  }

  TEST_CASE("three triangles on one edge: non-manifold") {
    TriMesh m;
    m.positions = {Vec3d(0, 0, 0), Vec3d(1, 0, 0), Vec3d(0, 1, 0), Vec3d(0, -1, 0), Vec3d(0, 0, 1)};
    m.triangles = {Tri{0, 1, 2}, Tri{1, 0, 3}, Tri{0, 1, 4}};
    const SurfaceStats s = surface_stats(m);
    CHECK(s.nonmanifold_edges == 1);
    CHECK(s.boundary_edges == 6);
    CHECK(s.misoriented_edges == 0);
    CHECK(s.components == 1);
    CHECK(s.vertices == 5);
    CHECK(s.euler == 5 - 7 + 3);
  }

  TEST_CASE("components: triangles sharing only a vertex are one component, ids in first-triangle order") {
    TriMesh a = tetrahedron();
    TriMesh m;
    // Component A: tetrahedron at vertices 4..7; component B: tetrahedron at 0..3;
    // triangles listed A, B, A, B.
    m.positions = a.positions;
    for (const Vec3d& p : a.positions) m.positions.push_back(p + Vec3d(3, 0, 0));
    for (int i = 0; i < 4; ++i) {
      Tri t = a.triangles[i];
      for (uint32_t& v : t) v += 4;
      m.triangles.push_back(t);
      m.triangles.push_back(a.triangles[i]);
    }
    SurfaceStats s = surface_stats(m);
    CHECK(s.components == 2);
    CHECK(s.euler == 4);
    CHECK(s.volume == doctest::Approx(2.0 / 6.0));
    uint32_t n = 0;
    const std::vector<uint32_t> id = triangle_components(m.triangles, uint32_t(m.positions.size()), n);
    CHECK(n == 2);
    CHECK(id == std::vector<uint32_t>{0, 1, 0, 1, 0, 1, 0, 1});

    // A bow tie: two triangles sharing one vertex.
    std::vector<Tri> bow = {Tri{0, 1, 2}, Tri{2, 3, 4}};
    CHECK(triangle_components(bow, 5, n) == std::vector<uint32_t>{0, 0});
    CHECK(n == 1);
    CHECK(triangle_components({}, 10, n).empty());
    CHECK(n == 0);
  }

  TEST_CASE("SurfaceMesh overload and to_trimesh agree") {
    const TriMesh t = tetrahedron();
    SurfaceMesh s;
    for (const Vec3d& p : t.positions) s.positions.push_back(p.cast<float>());
    s.vertex_voxel.assign(4, 0);
    s.triangles = t.triangles;
    const SurfaceStats a = surface_stats(s);
    const SurfaceStats b = surface_stats(to_trimesh(s));
    CHECK(a.volume == doctest::Approx(1.0 / 6.0));
    CHECK(b.volume == a.volume);
    CHECK(a.euler == 2);
    const TriMesh back = to_trimesh(s);
    CHECK(back.triangles == t.triangles);
    CHECK(back.positions == t.positions);

    // Area-weighted normals: at the origin vertex, the three axis-aligned faces (area 1/2
    // each) average to -(1,1,1)/sqrt(3); at (1,0,0), faces -y, -z (area 1/2) and the slanted
    // face (area sqrt(3)/2, normal (1,1,1)/sqrt(3)).
    const std::vector<Vec3f> n = vertex_normals(s);
    REQUIRE(n.size() == 4);
    CHECK((n[0] - Vec3f(-1, -1, -1).normalized()).norm() < 1e-6f);
    const Vec3f expected1 = (Vec3f(0, -0.5f, 0) + Vec3f(0, 0, -0.5f) + Vec3f(0.5f, 0.5f, 0.5f)).normalized();
    CHECK((n[1] - expected1).norm() < 1e-6f);
  }
}
