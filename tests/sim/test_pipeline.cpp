// Voxelize + dual contour on synthetic hard cases: closed surfaces, sharp corners kept,
// winding and holes not changing signs, components and genus right.
#include "sim/contour.h"
#include "sim/mesh_distance.h"
#include "sim/shapes.h"
#include "sim/surface_metrics.h"
#include "sim/voxelize.h"

#include <doctest/doctest.h>

#include "fixtures.h"

#include <Eigen/Geometry>

#include <cmath>

using namespace dvx;

namespace {

using dvx_test::voxelized;

Eigen::Matrix3d rotation(double ax_deg, double ay_deg, double az_deg) {
  const double d = M_PI / 180.0;
  return (Eigen::AngleAxisd(az_deg * d, Vec3d::UnitZ()) * Eigen::AngleAxisd(ay_deg * d, Vec3d::UnitY()) *
          Eigen::AngleAxisd(ax_deg * d, Vec3d::UnitX()))
      .toRotationMatrix();
}

// Nodes whose centre lies farther than `margin` from `centre`.
bool same_signs_away_from(const VoxelModel& a, const VoxelModel& b, const Vec3d& centre, double margin) {
  const Lattice& l = a.lattice;
  for (int k = 0; k <= l.nz; ++k) {
    for (int j = 0; j <= l.ny; ++j) {
      for (int i = 0; i <= l.nx; ++i) {
        if ((l.node_position(i, j, k) - centre).norm() < margin) continue;
        const uint32_t n = l.node(i, j, k);
        if (a.is_inside(n) != b.is_inside(n)) return false;
      }
    }
  }
  return true;
}

}  // namespace

TEST_SUITE("pipeline") {
  TEST_CASE("sphere: closed, one component, volume and distance to the analytic surface") {
    const double r = 1.0;
    const TriMesh sphere = make_icosphere(Vec3d(0.1, -0.2, 0.3), r, 5);
    const VoxelModel model = voxelized(sphere, 48);
    const SurfaceMesh surface = dual_contour(model);
    const SurfaceStats stats = surface_stats(surface);
    const double h = model.lattice.voxel_size;
    CHECK(stats.boundary_edges == 0);
    CHECK(stats.misoriented_edges == 0);
    CHECK(stats.components == 1);
    CHECK(stats.euler == 2);
    const double analytic = 4.0 / 3.0 * M_PI * r * r * r;
    CHECK(std::abs(stats.volume - analytic) / analytic < 0.01);
    // Every surface vertex lies near the analytic sphere (tessellation error of a level-5 icosphere is tiny).
    double worst = 0.0;
    for (const Vec3f& p : surface.positions) {
      worst = std::max(worst, std::abs((p.cast<double>() - Vec3d(0.1, -0.2, 0.3)).norm() - r));
    }
    CHECK(worst / h < 0.1);
    const ErrorStats e = two_sided_error(to_trimesh(surface), sphere, 20000, 7);
    CHECK(e.max / h < 0.2);
  }

  TEST_CASE("rotated cube: dual contouring keeps its corners (max error <= 0.1 voxel)") {
    const TriMesh cube = make_box(Vec3d(0.05, 0.02, -0.03), Vec3d(1, 1, 1), rotation(20, 30, 10), 1);
    const VoxelModel model = voxelized(cube, 40);
    const SurfaceMesh surface = dual_contour(model);
    const SurfaceStats stats = surface_stats(surface);
    CHECK(stats.boundary_edges == 0);
    CHECK(stats.components == 1);
    const ErrorStats e = two_sided_error(to_trimesh(surface), cube, 50000, 3);
    CHECK(e.max / model.lattice.voxel_size <= 0.1);
  }

  TEST_CASE("inward winding gives the same signs and crossings") {
    const TriMesh mesh = make_torus(Vec3d(0, 0, 0), 1.0, 0.4, 48, 24);
    const VoxelModel outward = voxelized(mesh, 40);
    const VoxelModel inward = voxelized(flip_winding(mesh), 40);
    CHECK(outward.inside == inward.inside);
    REQUIRE(outward.crossings.size() == inward.crossings.size());
    for (size_t i = 0; i < outward.crossings.size(); ++i) {
      CHECK(outward.crossings[i].edge == inward.crossings[i].edge);
      CHECK(outward.crossings[i].t == inward.crossings[i].t);
      CHECK(decode_normal(outward.crossings[i].normal).dot(decode_normal(inward.crossings[i].normal)) > 0.99);
    }
  }

  TEST_CASE("a hole in the mesh leaves the signs away from it unchanged") {
    const TriMesh closed = make_icosphere(Vec3d(0, 0, 0), 1.0, 4);
    // Away from the box extremes, so both meshes get the same lattice.
    const Vec3d hole_centre = Vec3d(0.5, 0.6, 0.62).normalized();
    const TriMesh open = cut_hole(closed, hole_centre, 0.25);
    REQUIRE(open.triangles.size() < closed.triangles.size());
    REQUIRE(mesh_bounds(open).min == mesh_bounds(closed).min);
    REQUIRE(mesh_bounds(open).max == mesh_bounds(closed).max);
    const VoxelModel a = voxelized(closed, 40);
    const VoxelModel b = voxelized(open, 40);
    CHECK(same_signs_away_from(a, b, hole_centre, 0.25 + 2 * a.lattice.voxel_size));
    const SurfaceStats stats = surface_stats(dual_contour(b));
    CHECK(stats.boundary_edges == 0);
  }

  TEST_CASE("two separate components give two closed surfaces") {
    const TriMesh two = merge_meshes(make_icosphere(Vec3d(-1.5, 0, 0), 1.0, 3), make_icosphere(Vec3d(1.5, 0, 0), 1.0, 3));
    const SurfaceStats stats = surface_stats(dual_contour(voxelized(two, 48)));
    CHECK(stats.components == 2);
    CHECK(stats.boundary_edges == 0);
    CHECK(stats.euler == 4);
  }

  TEST_CASE("a torus has Euler characteristic 0") {
    const TriMesh torus = make_torus(Vec3d(0.01, 0.02, 0.0), 1.0, 0.35, 64, 32);
    const SurfaceStats stats = surface_stats(dual_contour(voxelized(torus, 48)));
    CHECK(stats.components == 1);
    CHECK(stats.boundary_edges == 0);
    CHECK(stats.euler == 0);
  }

  TEST_CASE("degenerate and duplicate triangles change nothing") {
    const TriMesh clean = make_icosphere(Vec3d(0, 0, 0), 1.0, 3);
    TriMesh dirty = clean;
    // A zero-area triangle (repeated vertex), a collinear sliver, and a duplicated pair of triangles
    // (a duplicate pair flips parity twice, so it cancels out).
    dirty.triangles.push_back({0, 0, 1});
    const uint32_t a = uint32_t(dirty.positions.size());
    dirty.positions.push_back(Vec3d(-0.5, 0.1, 0.1));
    dirty.positions.push_back(Vec3d(0, 0.1, 0.1));
    dirty.positions.push_back(Vec3d(0.5, 0.1, 0.1));
    dirty.triangles.push_back({a, a + 1, a + 2});
    dirty.triangles.push_back(clean.triangles[5]);
    dirty.triangles.push_back(clean.triangles[5]);
    const VoxelModel m0 = voxelized(clean, 32);
    const VoxelModel m1 = voxelized(dirty, 32);
    CHECK(m0.inside == m1.inside);
    CHECK(m0.crossings.size() == m1.crossings.size());
  }

  TEST_CASE("a thin plate thicker than two voxels stays one closed piece") {
    const TriMesh plate = make_box(Vec3d(0, 0, 0), Vec3d(1.0, 0.06, 0.7), rotation(3, 5, 7), 4);
    const VoxelModel model = voxelized(plate, 64);  // 2 * 0.06 = ~3.8 voxels
    const SurfaceStats stats = surface_stats(dual_contour(model));
    CHECK(stats.components == 1);
    CHECK(stats.boundary_edges == 0);
    CHECK(stats.volume > 0.0);
  }
}
