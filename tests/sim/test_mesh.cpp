#include "sim/mesh.h"
#include "sim/random.h"

#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <vector>

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

  TEST_CASE("weld on many vertices: one vertex per distinct position, every triangle where it was") {
    // 20 000 vertices drawn from 3 000 distinct positions (a few differing in one coordinate's last
    // bit, some with -0.0), triangles over random vertices.
    SplitMix64 rng{20261207};
    std::vector<Vec3d> distinct;
    for (int i = 0; i < 3000; ++i) {
      Vec3d p(double(rng.next() % 50) * 0.25, double(rng.next() % 50) * 0.25, double(rng.next() % 50) * 0.25);
      if (i % 100 == 7) p.x() = std::nextafter(distinct.back().x(), 1e9), p.y() = distinct.back().y(), p.z() = distinct.back().z();
      distinct.push_back(p);
    }
    TriMesh m;
    for (int i = 0; i < 20000; ++i) {
      Vec3d p = distinct[rng.next() % distinct.size()];
      if (p.x() == 0.0 && i % 2) p.x() = -0.0;
      m.positions.push_back(p);
    }
    for (int t = 0; t < 30000; ++t) {
      m.triangles.push_back({uint32_t(rng.next() % 20000), uint32_t(rng.next() % 20000), uint32_t(rng.next() % 20000)});
    }
    const TriMesh before = m;
    const uint32_t dropped = weld_identical_vertices(m);
    // Distinct positions (as values: -0.0 is 0.0) in first-seen order.
    std::vector<Vec3d> expected;
    for (const Vec3d& p : before.positions) {
      if (std::find(expected.begin(), expected.end(), p) == expected.end()) expected.push_back(p);
    }
    REQUIRE(m.positions.size() == expected.size());
    CHECK(m.positions == expected);
    uint32_t kept = 0;
    for (const Tri& t : before.triangles) {
      const Vec3d &a = before.positions[t[0]], &b = before.positions[t[1]], &c = before.positions[t[2]];
      if (a == b || b == c || a == c) continue;  // collapses
      REQUIRE(kept < m.triangles.size());
      const Tri& w = m.triangles[kept++];
      CHECK((m.positions[w[0]] == a && m.positions[w[1]] == b && m.positions[w[2]] == c));
    }
    CHECK(kept == m.triangles.size());
    CHECK(dropped == before.triangles.size() - kept);
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
