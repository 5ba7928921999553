#include "sim/mesh.h"

#include <doctest/doctest.h>

using namespace dvx;

namespace {

// Axis-aligned box, 8 shared vertices, 12 triangles wound outward.
TriMesh unit_box(const Vec3d& lo, const Vec3d& hi) {
  TriMesh m;
  for (int i = 0; i < 8; ++i) {
    m.positions.emplace_back((i & 1) ? hi.x() : lo.x(), (i & 2) ? hi.y() : lo.y(), (i & 4) ? hi.z() : lo.z());
  }
  const uint32_t quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& q : quads) {
    m.triangles.push_back({q[0], q[1], q[2]});
    m.triangles.push_back({q[0], q[2], q[3]});
  }
  return m;
}

// The same box as six separate quads (24 vertices, nothing shared).
TriMesh soup_box(const Vec3d& lo, const Vec3d& hi) {
  const TriMesh shared = unit_box(lo, hi);
  TriMesh m;
  for (size_t f = 0; f < 6; ++f) {
    const Tri& t0 = shared.triangles[2 * f];
    const Tri& t1 = shared.triangles[2 * f + 1];
    const uint32_t b = uint32_t(m.positions.size());
    m.positions.push_back(shared.positions[t0[0]]);
    m.positions.push_back(shared.positions[t0[1]]);
    m.positions.push_back(shared.positions[t0[2]]);
    m.positions.push_back(shared.positions[t1[2]]);
    m.triangles.push_back({b, b + 1, b + 2});
    m.triangles.push_back({b, b + 2, b + 3});
  }
  return m;
}

}  // namespace

TEST_SUITE("mesh") {
  TEST_CASE("signed volume of a box, positive outward, negative inward, independent of placement") {
    TriMesh box = unit_box(Vec3d(-1, -1, -1), Vec3d(1, 1, 1));
    CHECK(signed_volume(box) == doctest::Approx(8.0).epsilon(1e-12));
    TriMesh far = unit_box(Vec3d(1e6, 2e6, -3e6), Vec3d(1e6 + 2, 2e6 + 3, -3e6 + 4));
    CHECK(signed_volume(far) == doctest::Approx(24.0).epsilon(1e-9));
    for (Tri& t : box.triangles) std::swap(t[1], t[2]);
    CHECK(signed_volume(box) == doctest::Approx(-8.0).epsilon(1e-12));
    CHECK(signed_volume(TriMesh{}) == 0.0);
  }

  TEST_CASE("bounds cover only the vertices that triangles use") {
    TriMesh box = unit_box(Vec3d(0, 0, 0), Vec3d(1, 2, 3));
    box.positions.emplace_back(100, 100, 100);  // unused
    const Aabb b = mesh_bounds(box);
    CHECK(b.min == Vec3d(0, 0, 0));
    CHECK(b.max == Vec3d(1, 2, 3));
    CHECK(mesh_bounds(TriMesh{}).empty());
  }

  TEST_CASE("weld merges identical vertices and drops triangles that collapse") {
    TriMesh soup = soup_box(Vec3d(0, 0, 0), Vec3d(1, 1, 1));
    REQUIRE(soup.positions.size() == 24);
    CHECK_FALSE(is_watertight(soup));
    const double volume = signed_volume(soup);
    CHECK(weld_identical_vertices(soup) == 0);
    CHECK(soup.positions.size() == 8);
    CHECK(soup.triangles.size() == 12);
    CHECK(is_watertight(soup));
    CHECK(signed_volume(soup) == doctest::Approx(volume));

    // Two distinct vertices at the same place: a triangle over them collapses and is dropped;
    // -0.0 and +0.0 are the same coordinate.
    TriMesh m;
    m.positions = {Vec3d(0, 0, 0), Vec3d(1, 0, 0), Vec3d(-0.0, 0, 0), Vec3d(0, 1, 0), Vec3d(1, 0, 1e-300)};
    m.triangles = {{0, 1, 3}, {0, 2, 3}, {2, 1, 3}, {0, 4, 3}};
    CHECK(weld_identical_vertices(m) == 1);
    CHECK(m.positions.size() == 4);  // (1,0,1e-300) is not (1,0,0)
    CHECK(m.triangles.size() == 3);
    CHECK(m.triangles[0] == m.triangles[1]);  // {0,1,3} and {2->0,1,3}
  }

  TEST_CASE("watertight: closed box yes, holed box no, duplicated face no") {
    TriMesh box = unit_box(Vec3d(0, 0, 0), Vec3d(1, 1, 1));
    CHECK(is_watertight(box));
    TriMesh holed = box;
    holed.triangles.pop_back();
    CHECK_FALSE(is_watertight(holed));
    TriMesh doubled = box;
    doubled.triangles.push_back(box.triangles[0]);
    CHECK_FALSE(is_watertight(doubled));
    CHECK_FALSE(is_watertight(TriMesh{}));
  }
}
