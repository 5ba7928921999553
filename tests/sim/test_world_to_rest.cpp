// World -> rest mapping through the deformed pieces, and cuts made through it: a blade through air
// cuts nothing, a bent bar is cut where the blade is, a still blade cuts tissue pushed into it.
#include "sim/cut.h"
#include "sim/pbd.h"
#include "sim/shapes.h"
#include "sim/surface_metrics.h"
#include "sim/voxelize.h"
#include "sim/world_to_rest.h"

#include "fixtures.h"

#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>

using namespace dvx;

namespace {

using Body = dvx_test::WorldScene;

void make_body(Body& b, const TriMesh& mesh, int resolution, int sim_resolution, PbdParams params) {
  dvx_test::make_world(b, mesh, resolution, sim_resolution, params);
}

Aabb box_of(const Vec3d& lo, const Vec3d& hi) {
  Aabb a;
  a.grow(lo);
  a.grow(hi);
  return a;
}

// One world step sweeping the blade (the product's step: map, cut, update, PBD) with the consistency checks.
CutStepStats world_cut(Body& b, const BladePose& from, const BladePose& to) {
  const CutStepStats stats = dvx_test::world_cut_step(b.model, b.state, from, to).cut;
  std::string error;
  REQUIRE_MESSAGE(check_cut_state(b.voxels(), b.state.cut, error), error);
  REQUIRE_MESSAGE(check_pbd_state(b.voxels(), b.state.cut, b.pbd().model, b.pbd().data, error), error);
  return stats;
}

int components(const Body& b) { return int(surface_stats(compact_surface(b.state.cut.surface)).components); }

// A rotated, sheared and bent hexahedron.
void bent_hexahedron(Vec3d corners[8]) {
  const Eigen::Matrix3d r = Eigen::AngleAxisd(0.7, Vec3d(1, 2, 3).normalized()).toRotationMatrix();
  for (int c = 0; c < 8; ++c) {
    const Vec3d u((c & 1), (c >> 1) & 1, (c >> 2) & 1);
    corners[c] = Vec3d(3, 1, 2) + r * (Vec3d(2 * u.x() + 0.4 * u.y(), u.y(), u.z()) + 0.3 * u.x() * u.y() * Vec3d(0, 0, 1));
  }
}

}  // namespace

TEST_SUITE("world_to_rest") {
  TEST_CASE("Newton inverts the trilinear map of a rotated, sheared and bent hexahedron") {
    Vec3d corners[8];
    bent_hexahedron(corners);
    for (const Vec3d& u : {Vec3d(0.1, 0.2, 0.3), Vec3d(0.9, 0.5, 0.01), Vec3d(1.1, -0.05, 0.5)}) {
      Vec3d found = Vec3d::Constant(0.5);
      REQUIRE(invert_trilinear(corners, trilinear(corners, u), found, 1e-12));
      CHECK((found - u).norm() < 1e-9);
    }
    // A flattened hexahedron does not converge (no NaN, no false answer).
    Vec3d flat[8];
    for (int c = 0; c < 8; ++c) flat[c] = Vec3d((c & 1), 0.0, (c >> 2) & 1);
    Vec3d u = Vec3d::Constant(0.5);
    CHECK_FALSE(invert_trilinear(flat, Vec3d(0.5, 0.3, 0.5), u, 1e-9));
  }

  TEST_CASE("the warm inversion reaches Newton's tolerance from another point's inverse Jacobian, and falls back to Newton") {
    // The bent hexahedron, in monomial form.
    Vec3d corners[8];
    bent_hexahedron(corners);
    const TrilinearMap map = trilinear_map(corners);
    for (const Vec3d& u : {Vec3d(0.1, 0.2, 0.3), Vec3d(0.9, 0.5, 0.01), Vec3d(0.5, 0.5, 0.5)}) {
      CHECK((trilinear(corners, u) - (map.c[0] + u.x() * map.c[1] + u.y() * map.c[2] + u.z() * map.c[3] +
                                      u.x() * u.y() * map.c[4] + u.x() * u.z() * map.c[5] + u.y() * u.z() * map.c[6] +
                                      u.x() * u.y() * u.z() * map.c[7]))
                .norm() < 1e-12);
    }
    // The first inversion runs Newton and keeps its inverse Jacobian; the next points, far from it
    // in the bent map, converge with it to the same tolerance.
    Eigen::Matrix3d jinv = Eigen::Matrix3d::Zero();
    bool have = false;
    Vec3d found = Vec3d::Constant(0.5);
    REQUIRE(invert_trilinear_warm(map, trilinear(corners, Vec3d(0.2, 0.3, 0.4)), found, 1e-10, jinv, have));
    CHECK(have);
    CHECK((found - Vec3d(0.2, 0.3, 0.4)).norm() < 1e-8);
    for (const Vec3d& u : {Vec3d(0.1, 0.2, 0.3), Vec3d(0.9, 0.5, 0.01), Vec3d(1.1, -0.05, 0.5), Vec3d(0.95, 0.95, 0.95)}) {
      found = Vec3d::Constant(0.5);
      REQUIRE(invert_trilinear_warm(map, trilinear(corners, u), found, 1e-10, jinv, have));
      CHECK((trilinear(corners, found) - trilinear(corners, u)).norm() <= 1e-10);
      CHECK((found - u).norm() < 1e-8);
    }
    // A useless inverse Jacobian (chord steps that do not contract): Newton takes over and replaces it.
    jinv = -Eigen::Matrix3d::Identity();
    found = Vec3d::Constant(0.5);
    REQUIRE(invert_trilinear_warm(map, trilinear(corners, Vec3d(0.8, 0.1, 0.6)), found, 1e-10, jinv, have));
    CHECK((found - Vec3d(0.8, 0.1, 0.6)).norm() < 1e-8);
    CHECK(jinv != -Eigen::Matrix3d::Identity());
    // A flattened hexahedron fails with or without one.
    Vec3d flat[8];
    for (int c = 0; c < 8; ++c) flat[c] = Vec3d((c & 1), 0.0, (c >> 2) & 1);
    found = Vec3d::Constant(0.5);
    CHECK_FALSE(invert_trilinear_warm(trilinear_map(flat), Vec3d(0.5, 0.3, 0.5), found, 1e-9, jinv, have));
  }

  TEST_CASE("a blade through the space a fallen piece left cuts nothing") {
    Body b;
    PbdParams p;
    p.fixed.push_back(box_of(Vec3d(-5, 0.9, -5), Vec3d(5, 5, 5)));
    p.damping = 0.0;
    make_body(b, make_box(Vec3d(0.0013, 0.0021, 0.0007), Vec3d(0.5, 1.0, 0.5), Eigen::Matrix3d::Identity(), 1), 32, 8, p);
    // Cut through at y = 0.11 in world space: the lower part falls away.
    const double y = 0.1137;
    BladePose blade{Vec3d(-1, y, -2), Vec3d(-1, y, 2)};
    for (int i = 1; i <= 10; ++i) {
      const BladePose next{Vec3d(-1 + 0.2 * i, y, -2), Vec3d(-1 + 0.2 * i, y, 2)};
      world_cut(b, blade, next);
      blade = next;
    }
    REQUIRE(components(b) == 2);
    for (int i = 0; i < 60; ++i) pbd_step(b.state.cut, b.pbd().model, b.pbd().data);
    // Where the lower part was (y = -0.5): air now.
    reset_sweep(b.state.sweep);
    uint32_t edges = 0;
    blade = {Vec3d(-1, -0.5, -2), Vec3d(-1, -0.5, 2)};
    for (int i = 1; i <= 10; ++i) {
      const BladePose next{Vec3d(-1 + 0.2 * i, -0.5, -2), Vec3d(-1 + 0.2 * i, -0.5, 2)};
      edges += world_cut(b, blade, next).edges_cut;
      blade = next;
    }
    CHECK(edges == 0);
    CHECK(components(b) == 2);
    // The same blade through the anchored top still cuts.
    reset_sweep(b.state.sweep);
    blade = {Vec3d(-1, 0.5, -2), Vec3d(-1, 0.5, 2)};
    edges = 0;
    for (int i = 1; i <= 4; ++i) {
      const BladePose next{Vec3d(-1 + 0.2 * i, 0.5, -2), Vec3d(-1 + 0.2 * i, 0.5, 2)};
      edges += world_cut(b, blade, next).edges_cut;
      blade = next;
    }
    CHECK(edges > 0);
  }

  TEST_CASE("a bar bent 90 degrees by the grab tool is cut where the blade is") {
    Body b;
    PbdParams p;
    p.fixed.push_back(box_of(Vec3d(-5, -5, -5), Vec3d(-1.3, 5, 5)));
    p.gravity = Vec3d::Zero();
    p.shape_stiffness = 0.2;
    p.stretch_compliance = 1e-4;
    p.damping = 0.05;
    make_body(b, make_box(Vec3d(0.0013, 0.0021, 0.0007), Vec3d(1.5, 0.25, 0.25), Eigen::Matrix3d::Identity(), 1), 48, 12, p);
    // Drag the free end along a quarter circle about the anchored end: a 90 degree bend.
    const double radius = 2.0 * 2.8 / M_PI;
    const Vec3d centre(-1.3, radius, 0.0);
    grab_begin(b.pbd().model, b.pbd().data, Vec3d(1.5, 0.0, 0.0), 1e-7);
    const int drag = 150;
    for (int i = 0; i <= drag + 60; ++i) {
      const double angle = 0.5 * M_PI * std::min(i, drag) / drag;
      grab_move(b.pbd().data, centre + radius * Vec3d(std::sin(angle), -std::cos(angle), 0.0));
      pbd_step(b.state.cut, b.pbd().model, b.pbd().data);
    }
    const Vec3d end = b.pbd().data.position[b.pbd().data.grab_particles.at(0)];
    REQUIRE(end.y() > 1.2);  // bent: the end points up
    // A horizontal blade at y = 1, swept across the bar in one step.
    const double plane = 1.0137;
    const CutStepStats stats = world_cut(b, {Vec3d(-2, plane, -1), Vec3d(-2, plane, 1)}, {Vec3d(2, plane, -1), Vec3d(2, plane, 1)});
    REQUIRE(stats.edges_cut > 0);
    pbd_embed(b.state.cut, b.pbd().model, b.pbd().data);
    // Cut faces, in world space, lie on the blade's plane.
    std::vector<double> distance;
    const CutSurface& s = b.state.cut.surface;
    for (size_t t = 0; t < s.triangles.size(); ++t) {
      if (s.triangles[t][0] == kDeadIndex || !s.triangle_cut[t]) continue;
      Vec3d c = Vec3d::Zero();
      for (uint32_t v : s.triangles[t]) c += b.pbd().data.deformed[v].cast<double>() / 3.0;
      distance.push_back(std::abs(c.y() - plane) / b.pbd().model.fine_size);
    }
    REQUIRE(distance.size() > 20);
    std::sort(distance.begin(), distance.end());
    const double p95 = distance[size_t(0.95 * double(distance.size() - 1))];
    MESSAGE("cut faces: " << distance.size() << ", distance from the blade plane p95 " << p95 << " fine voxels, max "
                          << distance.back());
    CHECK(p95 <= 1.0);
    CHECK(components(b) == 2);
  }

  TEST_CASE("tissue pulled through a parked blade is cut") {
    Body b;
    PbdParams p;
    p.gravity = Vec3d::Zero();
    p.damping = 0.05;
    make_body(b, make_box(Vec3d(0.0013, 0.0021, 0.0007), Vec3d(0.5, 1.0, 0.5), Eigen::Matrix3d::Identity(), 1), 32, 8, p);
    // The blade stands still above the block; the grab pulls the block up through it.
    const BladePose parked{Vec3d(0.0137, 1.5, -2), Vec3d(0.0137, 1.5, 2)};
    grab_begin(b.pbd().model, b.pbd().data, Vec3d(0.0, 1.0, 0.0), 1e-6);
    uint32_t edges = 0;
    for (int i = 1; i <= 90; ++i) {
      grab_move(b.pbd().data, Vec3d(0.0, 1.0 + 0.045 * i, 0.0));
      edges += world_cut(b, parked, parked).edges_cut;
    }
    CHECK(edges > 0);
    CHECK(components(b) == 2);
  }
}
