#include "sim/mesh_distance.h"
#include "sim/shapes.h"

#include <doctest/doctest.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <limits>

#include "sim/random.h"

using namespace dvx;

namespace {

// Portable test PRNG (splitmix64) so the points are the same everywhere.
struct Rng : SplitMix64 {
  explicit Rng(uint64_t seed) : SplitMix64{seed} {}
  using SplitMix64::uniform;
  Vec3d point(double lo, double hi) { return Vec3d(uniform(lo, hi), uniform(lo, hi), uniform(lo, hi)); }
};

// Independent reference: closest of the plane projection (when inside) and the three segments.
Vec3d reference_closest(const Vec3d& p, const Vec3d& a, const Vec3d& b, const Vec3d& c) {
  auto seg = [&](const Vec3d& s0, const Vec3d& s1) {
    const Vec3d d = s1 - s0;
    const double l2 = d.squaredNorm();
    const double t = l2 > 0 ? std::clamp((p - s0).dot(d) / l2, 0.0, 1.0) : 0.0;
    return Vec3d(s0 + t * d);
  };
  Vec3d best = seg(a, b);
  for (const Vec3d& q : {seg(b, c), seg(c, a)})
    if ((q - p).squaredNorm() < (best - p).squaredNorm()) best = q;
  const Vec3d n = (b - a).cross(c - a);
  if (n.squaredNorm() > 0) {
    const Vec3d q = p - n * ((p - a).dot(n) / n.squaredNorm());
    // Inside when q is on the inner side of all three edges.
    const bool inside = (b - a).cross(q - a).dot(n) >= 0 && (c - b).cross(q - b).dot(n) >= 0 &&
                        (a - c).cross(q - c).dot(n) >= 0;
    if (inside && (q - p).squaredNorm() < (best - p).squaredNorm()) best = q;
  }
  return best;
}

// Brute force over every triangle.
double brute_distance(const TriMesh& m, const Vec3d& p) {
  double best = std::numeric_limits<double>::infinity();
  for (const Tri& t : m.triangles)
    best = std::min(best, (closest_point_on_triangle(p, m.positions[t[0]], m.positions[t[1]], m.positions[t[2]]) - p).norm());
  return best;
}

// Compares the tree against brute force at `count` random points in the mesh's inflated box.
void check_bvh_against_brute_force(const TriMesh& m, int count, uint64_t seed) {
  const TriangleBvh bvh = build_bvh(m);
  Vec3d lo = Vec3d::Constant(1e300), hi = Vec3d::Constant(-1e300);
  for (const Vec3d& p : m.positions) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  const Vec3d pad = 0.25 * (hi - lo);
  Rng rng{seed};
  int mismatches = 0;
  for (int i = 0; i < count; ++i) {
    const Vec3d u(rng.uniform(0, 1), rng.uniform(0, 1), rng.uniform(0, 1));
    const Vec3d p = (lo - pad) + u.cwiseProduct(hi - lo + 2 * pad);
    Vec3d q;
    const double d = closest_point(bvh, p, &q);
    const double ref = brute_distance(m, p);
    if (std::abs(d - ref) > 1e-12 * (1 + ref) || std::abs((q - p).norm() - d) > 1e-12 * (1 + d)) ++mismatches;
  }
  CHECK(mismatches == 0);
}

}  // namespace

TEST_SUITE("mesh_distance") {
  TEST_CASE("closest_point_on_triangle: every Voronoi region") {
    const Vec3d a(0, 0, 0), b(2, 0, 0), c(0, 2, 0);
    struct Case {
      Vec3d p, expected;
    };
    const Case cases[] = {
        {{-1, -1, 0.5}, a},               // vertex A
        {{3, -0.5, -0.3}, b},             // vertex B
        {{-0.2, 3, 1}, c},                // vertex C
        {{1, -1, 0.7}, {1, 0, 0}},        // edge AB
        {{1.5, 1.5, 0.2}, {1, 1, 0}},     // edge BC
        {{-1, 1, -0.3}, {0, 1, 0}},       // edge CA
        {{0.5, 0.5, 1}, {0.5, 0.5, 0}},   // face (above)
        {{0.3, 1.2, -2}, {0.3, 1.2, 0}},  // face (below)
        {{0.25, 0.25, 0}, {0.25, 0.25, 0}},  // in the triangle
    };
    for (const Case& k : cases) {
      CHECK((closest_point_on_triangle(k.p, a, b, c) - k.expected).norm() < 1e-12);
      // The same in any vertex order.
      CHECK((closest_point_on_triangle(k.p, b, c, a) - k.expected).norm() < 1e-12);
      CHECK((closest_point_on_triangle(k.p, c, b, a) - k.expected).norm() < 1e-12);
    }
  }

  TEST_CASE("closest_point_on_triangle matches an independent reference on random triangles") {
    Rng rng{42};
    int bad = 0;
    for (int i = 0; i < 20000; ++i) {
      const Vec3d a = rng.point(-1, 1), b = rng.point(-1, 1), c = rng.point(-1, 1), p = rng.point(-2, 2);
      const Vec3d q = closest_point_on_triangle(p, a, b, c);
      const Vec3d r = reference_closest(p, a, b, c);
      if (std::abs((q - p).norm() - (r - p).norm()) > 1e-9) ++bad;
    }
    CHECK(bad == 0);
  }

  TEST_CASE("closest_point_on_triangle: degenerate triangles give finite, correct results") {
    Rng rng{7};
    const Vec3d s0(0, 0, 0), s1(1, 1, 0), s2(2, 2, 0);
    for (int i = 0; i < 2000; ++i) {
      const Vec3d p = rng.point(-3, 3);
      // Collinear (all orders), two equal, all equal.
      const Vec3d tri[][3] = {{s0, s1, s2}, {s1, s0, s2}, {s2, s1, s0}, {s0, s2, s1},
                              {s0, s0, s2}, {s0, s2, s2}, {s2, s0, s0}, {s1, s1, s1}};
      for (const auto& t : tri) {
        const Vec3d q = closest_point_on_triangle(p, t[0], t[1], t[2]);
        REQUIRE(q.allFinite());
        CHECK((q - p).norm() == doctest::Approx((reference_closest(p, t[0], t[1], t[2]) - p).norm()).epsilon(1e-12));
      }
    }
    CHECK((closest_point_on_triangle(Vec3d(5, 5, 5), s1, s1, s1) - s1).norm() == 0.0);
  }

  TEST_CASE("closest_point_on_triangle: rounded-collinear triangles, slivers and needles") {
    // Collinear up to rounding (a + t d for random t) and nearly so: the region tests of the
    // textbook algorithm cancel catastrophically here.
    Rng rng{11};
    int bad = 0;
    for (int i = 0; i < 30000; ++i) {
      const Vec3d o = rng.point(-1, 1), d = rng.point(-1, 1), p = rng.point(-2, 2);
      const double eps = std::pow(10.0, -rng.uniform(3, 16));
      Vec3d a = o + rng.uniform(-1, 1) * d, b = o + rng.uniform(-1, 1) * d, c = o + rng.uniform(-1, 1) * d;
      if (i % 3 == 1) c += eps * rng.point(-1, 1);         // sliver
      if (i % 3 == 2) b = a + eps * rng.point(-1, 1);      // needle
      const Vec3d q = closest_point_on_triangle(p, a, b, c);
      if (!q.allFinite() || std::abs((q - p).norm() - (reference_closest(p, a, b, c) - p).norm()) > 1e-9) ++bad;
    }
    CHECK(bad == 0);
    // Right above a sliver's interior the face itself is nearest, not an edge.
    const Vec3d q = closest_point_on_triangle(Vec3d(0.5, 0.5e-6, 1e-7), Vec3d(0, 0, 0), Vec3d(1, 0, 0), Vec3d(0.5, 1e-6, 0));
    CHECK((q - Vec3d(0.5, 0.5e-6, 0)).norm() < 1e-15);
  }

  TEST_CASE("BVH structure: permutation, small leaves, nested boxes, deterministic") {
    const TriMesh m = make_icosphere(Vec3d(0, 0, 0), 1.0, 3);
    const TriangleBvh bvh = build_bvh(m);
    REQUIRE(!bvh.nodes.empty());
    std::vector<uint32_t> sorted = bvh.order;
    std::sort(sorted.begin(), sorted.end());
    for (uint32_t i = 0; i < sorted.size(); ++i) CHECK(sorted[i] == i);
    std::vector<int> seen(m.triangles.size(), 0);
    for (const auto& node : bvh.nodes) {
      if (node.count > 0) {
        CHECK(node.count <= 4u);
        for (uint32_t i = node.first; i < node.first + node.count; ++i) {
          ++seen[bvh.order[i]];
          for (uint32_t v : m.triangles[bvh.order[i]]) {
            CHECK((m.positions[v].array() >= node.box.min.array()).all());
            CHECK((m.positions[v].array() <= node.box.max.array()).all());
          }
        }
      } else {
        for (uint32_t ch : {node.first, node.first + 1}) {
          REQUIRE(ch < bvh.nodes.size());
          CHECK((bvh.nodes[ch].box.min.array() >= node.box.min.array()).all());
          CHECK((bvh.nodes[ch].box.max.array() <= node.box.max.array()).all());
        }
      }
    }
    for (int s : seen) CHECK(s == 1);
    const TriangleBvh again = build_bvh(m);
    CHECK(again.order == bvh.order);
    REQUIRE(again.nodes.size() == bvh.nodes.size());
    for (size_t i = 0; i < bvh.nodes.size(); ++i) {
      CHECK(again.nodes[i].first == bvh.nodes[i].first);
      CHECK(again.nodes[i].count == bvh.nodes[i].count);
    }
    // Empty mesh: no nodes, infinite distance.
    const TriMesh empty;
    CHECK(std::isinf(closest_point(build_bvh(empty), Vec3d(0, 0, 0))));
  }

  TEST_CASE("BVH closest_point equals brute force: icosphere") {
    check_bvh_against_brute_force(make_icosphere(Vec3d(0.1, -0.2, 0.3), 1.0, 3), 1000, 1);
  }

  TEST_CASE("BVH closest_point equals brute force: merged multi-component mesh") {
    const Eigen::Matrix3d r = Eigen::AngleAxisd(0.4, Vec3d(1, 1, 0).normalized()).toRotationMatrix();
    TriMesh m = merge_meshes(make_box(Vec3d(0, 0, 0), Vec3d(1, 0.5, 0.25), r, 3),
                             make_torus(Vec3d(2.5, 0, 0), 1.0, 0.3, 32, 12));
    m = merge_meshes(m, make_sphere(Vec3d(-3, 1, 0.5), 0.7, 24));
    check_bvh_against_brute_force(m, 1000, 2);
    // A flat (coplanar) mesh: every centroid box is thin along one axis.
    check_bvh_against_brute_force(cut_hole(make_box(Vec3d(0, 0, 0), Vec3d(1, 1, 1), r, 8), Vec3d(0, 0, 5), 1.0), 300, 3);
  }

  TEST_CASE("sample_surface: deterministic, on the surface") {
    const TriMesh m = make_torus(Vec3d(0, 0, 0), 1.0, 0.4, 32, 16);
    const auto s1 = sample_surface(m, 5000, 123);
    const auto s2 = sample_surface(m, 5000, 123);
    const auto s3 = sample_surface(m, 5000, 124);
    REQUIRE(s1.size() == 5000);
    CHECK(s1 == s2);
    CHECK(s1 != s3);
    const TriangleBvh bvh = build_bvh(m);
    double worst = 0;
    for (const Vec3d& p : s1) worst = std::max(worst, closest_point(bvh, p));
    CHECK(worst < 1e-12);
    CHECK(sample_surface(m, 0, 1).empty());
    CHECK(sample_surface(TriMesh{}, 10, 1).empty());
  }

  TEST_CASE("sample_surface: area-uniform across faces and within a triangle") {
    // Box faces of areas 24, 12, 8 (x, y, z normals), each face two triangles.
    const Vec3d h(1, 2, 3);
    const TriMesh box = make_box(Vec3d(0, 0, 0), h, Eigen::Matrix3d::Identity(), 1);
    const int n = 200000;
    const auto samples = sample_surface(box, n, 9);
    int count[3] = {0, 0, 0};
    for (const Vec3d& p : samples) {
      for (int a = 0; a < 3; ++a)
        if (std::abs(std::abs(p[a]) - h[a]) < 1e-12) {
          ++count[a];
          break;
        }
    }
    const double expected[3] = {48.0 / 88.0, 24.0 / 88.0, 16.0 / 88.0};
    for (int a = 0; a < 3; ++a) CHECK(static_cast<double>(count[a]) / n == doctest::Approx(expected[a]).epsilon(0.02));

    // One triangle: the central medial sub-triangle holds a quarter of the area, the mean is the centroid.
    TriMesh tri;
    tri.positions = {Vec3d(0, 0, 0), Vec3d(4, 0, 0), Vec3d(1, 3, 0)};
    tri.triangles = {Tri{0, 1, 2}};
    const auto ts = sample_surface(tri, n, 10);
    Vec3d mean = Vec3d::Zero();
    int corner_a = 0;
    for (const Vec3d& p : ts) {
      mean += p;
      // Barycentric weight of vertex 0 above 1/2 <=> in the corner sub-triangle at vertex 0.
      const Vec3d m0 = 0.5 * (tri.positions[0] + tri.positions[1]), m1 = 0.5 * (tri.positions[0] + tri.positions[2]);
      if ((m1 - m0).cross(p - m0).z() > 0) ++corner_a;
    }
    mean /= n;
    CHECK((mean - Vec3d(5.0 / 3, 1, 0)).norm() < 0.02);
    CHECK(static_cast<double>(corner_a) / n == doctest::Approx(0.25).epsilon(0.03));
  }

  TEST_CASE("two_sided_error: identical meshes give zero") {
    const TriMesh m = make_icosphere(Vec3d(0, 0, 0), 1.0, 3);
    const ErrorStats e = two_sided_error(m, m, 20000, 5);
    CHECK(e.samples == 40000u);
    CHECK(e.max < 1e-12);
    CHECK(e.mean < 1e-12);
    CHECK(e.rms < 1e-12);
  }

  TEST_CASE("two_sided_error: concentric spheres 0.1 apart") {
    const TriMesh a = make_icosphere(Vec3d(0, 0, 0), 1.0, 5);
    const TriMesh b = make_icosphere(Vec3d(0, 0, 0), 1.1, 5);
    const ErrorStats e = two_sided_error(a, b, 20000, 5);
    CHECK(e.max == doctest::Approx(0.1).epsilon(0.01));
    CHECK(e.mean == doctest::Approx(0.1).epsilon(0.01));
    CHECK(e.rms == doctest::Approx(0.1).epsilon(0.01));
    CHECK(e.max >= e.rms);
    CHECK(e.rms >= e.mean);
    // Symmetric by construction (up to the sampling of each side).
    const ErrorStats f = two_sided_error(b, a, 20000, 5);
    CHECK(f.max == doctest::Approx(e.max).epsilon(0.01));
  }

  TEST_CASE("two_sided_error: an extra far part is caught one-sidedly") {
    const TriMesh box = make_box(Vec3d(0, 0, 0), Vec3d(1, 1, 1), Eigen::Matrix3d::Identity(), 2);
    // The UV sphere has a vertex at (5.5, 0, 0): exactly 4.5 from the box.
    const TriMesh extra = merge_meshes(box, make_sphere(Vec3d(5, 0, 0), 0.5, 32));
    for (const auto& [a, b] : {std::pair{&box, &extra}, std::pair{&extra, &box}}) {
      const ErrorStats e = two_sided_error(*a, *b, 10000, 3);
      CHECK(e.max == doctest::Approx(4.5).epsilon(1e-9));
      CHECK(e.mean > 0.0);
      CHECK(e.mean < 4.5);
    }
    // With only the box's own samples (against the extended mesh) nothing is seen: the max must
    // come from the other direction.
    const TriangleBvh bvh = build_bvh(extra);
    double one_side = 0;
    for (const Vec3d& p : sample_surface(box, 10000, 3)) one_side = std::max(one_side, closest_point(bvh, p));
    CHECK(one_side < 1e-12);
  }

  TEST_CASE("two_sided_error: a missing part (hole) is caught") {
    const TriMesh m = make_icosphere(Vec3d(0, 0, 0), 1.0, 4);
    const TriMesh holed = cut_hole(m, Vec3d(0, 0, 1), 0.4);
    const ErrorStats e = two_sided_error(m, holed, 50000, 11);
    // The hole centre is about 0.4 from the rim.
    CHECK(e.max > 0.3);
    CHECK(e.max < 0.45);
    // Most of the surface matches exactly, so the mean is small.
    CHECK(e.mean < 0.02);
  }

  TEST_CASE("two_sided_error: empty meshes") {
    const TriMesh m = make_icosphere(Vec3d(0, 0, 0), 1.0, 1);
    const ErrorStats none = two_sided_error(TriMesh{}, TriMesh{}, 100, 1);
    CHECK(none.max == 0.0);
    CHECK(none.samples == 0u);
    CHECK(std::isinf(two_sided_error(m, TriMesh{}, 100, 1).max));
  }
}
