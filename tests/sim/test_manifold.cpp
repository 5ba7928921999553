// Manifold dual contouring (DESIGN §3 "Surface"): every synthetic mesh at several resolutions, and
// after every step of through, partial, crossing, helix and random cuts, is a closed, consistently
// oriented 2-manifold with the input's topology (Euler characteristic 2 - 2 genus per component);
// a slit tip holds still while another cut runs.
#include "sim/contour.h"
#include "sim/cut.h"
#include "sim/pbd.h"
#include "sim/random.h"
#include "sim/shapes.h"
#include "sim/surface_metrics.h"
#include "sim/voxelize.h"

#include <doctest/doctest.h>

#include "fixtures.h"

#include <Eigen/Geometry>

#include <cmath>
#include <string>
#include <vector>

using namespace dvx;

namespace {

using dvx_test::voxelized;

Eigen::Matrix3d tilt() {
  return (Eigen::AngleAxisd(0.21, Vec3d::UnitZ()) * Eigen::AngleAxisd(-0.13, Vec3d::UnitY()) *
          Eigen::AngleAxisd(0.07, Vec3d::UnitX()))
      .toRotationMatrix();
}

struct Shape {
  const char* name;
  TriMesh mesh;
  uint32_t components;
  int genus;  // total over the components
};

std::vector<Shape> synthetic_shapes() {
  const Vec3d c(0.013, -0.007, 0.011);
  const TriMesh sphere = make_icosphere(c, 1.0, 4);
  std::vector<Shape> shapes;
  shapes.push_back({"sphere", sphere, 1, 0});
  shapes.push_back({"torus", make_torus(c, 1.0, 0.38, 64, 32), 1, 1});
  shapes.push_back({"genus-3 plate", make_holed_plate(3, 0.3, 1, tilt(), c), 1, 3});
  shapes.push_back({"thin plate", make_box(c, Vec3d(1.0, 0.8, 0.09), tilt(), 2), 1, 0});
  shapes.push_back({"two shells", make_two_shells(c, 1.0, 0.62, 4), 2, 0});
  shapes.push_back({"lollipop", make_lollipop(6, 0.2, tilt(), c), 1, 0});
  shapes.push_back({"rotated cube", make_box(c, Vec3d(0.7, 0.7, 0.7), tilt(), 1), 1, 0});
  shapes.push_back({"mesh with a hole", cut_hole(sphere, c + Vec3d(0, 0, 1.0), 0.3), 1, 0});
  shapes.push_back({"inward-wound", flip_winding(sphere), 1, 0});
  shapes.push_back({"two spheres", merge_meshes(make_icosphere(c, 0.5, 3), make_icosphere(c + Vec3d(1.3, 0, 0), 0.5, 3)), 2, 0});
  return shapes;
}

// A closed, consistently oriented 2-manifold with the given topology.
void check_topology(const SurfaceStats& s, uint32_t components, int genus) {
  CHECK(s.boundary_edges == 0);
  CHECK(s.nonmanifold_edges == 0);
  CHECK(s.misoriented_edges == 0);
  CHECK(s.components == components);
  CHECK(s.euler == int64_t(2 * components) - 2 * genus);
}

SurfaceStats checked(const VoxelModel& model, const CutState& state) {
  std::string error;
  const bool ok = check_cut_state(model, state, error);  // manifoldness included
  CHECK_MESSAGE(ok, error);
  return surface_stats(compact_surface(state.surface));
}

// Cuts from `from` to `to` in `steps` steps, checking the state after every step; with `genus0`,
// every piece stays genus 0.
void sweep(const VoxelModel& model, CutState& state, const BladePose& from, const BladePose& to, int steps,
           bool genus0 = true) {
  dvx_test::sweep_steps(model, state, from, to, steps, [&](int) {
    const SurfaceStats stats = checked(model, state);
    if (genus0) CHECK(stats.euler == int64_t(2 * stats.components));
  });
}

BladePose z_blade(double x, double y, double half = 3.0) { return {Vec3d(x, y, -half), Vec3d(x, y, half)}; }

}  // namespace

TEST_SUITE("manifold") {
  TEST_CASE("synthetic meshes at several resolutions: closed 2-manifolds with the input's topology") {
    for (const Shape& shape : synthetic_shapes()) {
      for (int resolution : {24, 40, 64}) {
        CAPTURE(shape.name);
        CAPTURE(resolution);
        const VoxelModel model = voxelized(shape.mesh, resolution);
        check_topology(surface_stats(dual_contour(model)), shape.components, shape.genus);
      }
    }
  }

  TEST_CASE("an ambiguous face: two diagonal inside corners are one material unless the blade cuts the face") {
    // corners 0 and 3 inside (face z = 0 ambiguous), everything else outside.
    const uint8_t diagonal = (1u << 0) | (1u << 3);
    CHECK(voxel_material_joins(diagonal, 0) == (1u << 4));
    CHECK(voxel_material_joins(diagonal, 1u << 0) == 0);       // x edge 0 (corners 0-1) cut
    CHECK(voxel_material_joins((1u << 0) | (1u << 7), 0) == 0);  // body diagonal: never
    CHECK(voxel_material_joins(0xFF, 0) == 0);                  // no ambiguous face
  }

  TEST_CASE("after every step of through, partial, crossing and helix cuts") {
    const Vec3d c(0.0123, 0.0071, -0.0093);
    const VoxelModel model = voxelized(make_icosphere(c, 1.0, 4), 28);
    SUBCASE("through, then crossing") {
      CutState state;
      init_cut_state(model, state);
      sweep(model, state, z_blade(0.137, -1.2), z_blade(0.137, 1.2), 40);
      CHECK(checked(model, state).components == 2);
      const BladePose from{Vec3d(-3, -1.2, -0.117), Vec3d(3, -1.2, -0.117)}, to{Vec3d(-3, 1.2, -0.117), Vec3d(3, 1.2, -0.117)};
      sweep(model, state, from, to, 40);
      CHECK(checked(model, state).components == 4);
    }
    SUBCASE("partial, stopping mid-voxel, then turning back") {
      CutState state;
      init_cut_state(model, state);
      sweep(model, state, z_blade(-0.061, -1.2, 0.5), z_blade(-0.061, 0.23, 0.5), 30);
      CHECK(checked(model, state).components == 1);
      // The second pass leaves a wedge between the two sheets, attached to the body above and below
      // the blade (|z| > 0.5) and open at the bottom: a bridge, genus 1 once it is cut through.
      sweep(model, state, z_blade(-0.061, 0.23, 0.5), z_blade(0.05, -1.2, 0.5), 30, false);
      const SurfaceStats stats = checked(model, state);
      CHECK(stats.components == 1);
      CHECK(stats.euler == 0);
    }
    SUBCASE("helix") {
      CutState state;
      init_cut_state(model, state);
      BladePose previous;
      for (int s = 0; s <= 100; ++s) {
        const double angle = 0.09 * s, z = -0.8 + 0.016 * s;
        const Vec3d dir(std::cos(angle), std::sin(angle), 0.0);
        const BladePose pose{c + Vec3d(0, 0, z) + 0.1 * dir, c + Vec3d(0, 0, z) + 1.5 * dir};
        if (s > 0) cut_step(model, state, previous, pose);
        previous = pose;
        checked(model, state);
      }
    }
  }

  TEST_CASE("random cuts on a sphere and a torus stay closed 2-manifolds") {
    const Vec3d c(0.0123, 0.0071, -0.0093);
    const TriMesh meshes[2] = {make_icosphere(c, 1.0, 4), make_torus(c, 1.0, 0.4, 64, 32)};
    for (int m = 0; m < 8; ++m) {
      CAPTURE(m);
      const VoxelModel model = voxelized(meshes[m % 2], 20 + m % 7);
      CutState state;
      init_cut_state(model, state);
      SplitMix64 rng{99 + uint64_t(m)};
      for (int stroke = 0; stroke < 6; ++stroke) {
        const auto random_point = [&]() -> Vec3d { return c + Vec3d(rng.uniform(-1.3, 1.3), rng.uniform(-1.3, 1.3), rng.uniform(-1.3, 1.3)); };
        BladePose pose{random_point(), random_point()};
        for (int s = 0; s < 12; ++s) {
          const Vec3d move(rng.uniform(-0.25, 0.25), rng.uniform(-0.25, 0.25), rng.uniform(-0.25, 0.25));
          const BladePose next{pose.a + move, pose.b + move + Vec3d(rng.uniform(-0.05, 0.05), 0, 0)};
          cut_step(model, state, pose, next);
          pose = next;
          checked(model, state);
        }
      }
    }
  }

  TEST_CASE("a slit tip holds still while another cut runs elsewhere") {
    const Vec3d c(0.0123, 0.0071, -0.0093);
    const TriMesh box = make_box(c, Vec3d(1.0, 0.6, 0.8), Eigen::Matrix3d::Identity(), 2);
    const VoxelModel model = voxelized(box, 32);
    const double h = model.lattice.voxel_size;
    CutState state;
    init_cut_state(model, state);
    // A partial cut that stops mid-object, mid-voxel.
    const double y_stop = model.lattice.origin.y() + (std::floor((0.1 - model.lattice.origin.y()) / h) + 0.43) * h;
    sweep(model, state, z_blade(-0.4, -1.0, 0.5), z_blade(-0.4, y_stop, 0.5), 30);
    // The tip vertices: those of the voxels holding the blade's last edge.
    std::vector<std::pair<uint32_t, Vec3f>> tips;
    const CutSurface& s = state.surface;
    for (uint32_t slot = 0; slot < s.positions.size(); ++slot) {
      if (s.vertex_patch[slot] == CutSurface::kFreeKey) continue;
      const uint32_t voxel = uint32_t(s.vertex_patch[slot] / 16);
      if (std::binary_search(state.blade_voxels.begin(), state.blade_voxels.end(), voxel)) tips.emplace_back(slot, s.positions[slot]);
    }
    REQUIRE(tips.size() > 10);
    // A second stroke elsewhere, in steps.
    BladePose previous = z_blade(0.45, -1.0, 0.5);
    for (int step = 1; step <= 30; ++step) {
      const BladePose next = z_blade(0.45, -1.0 + 1.5 * step / 30.0, 0.5);
      cut_step(model, state, previous, next);
      previous = next;
      double moved = 0.0;
      for (const auto& [slot, position] : tips) moved = std::max(moved, double((s.positions[slot] - position).norm()) / h);
      CHECK(moved <= 0.01);
    }
    checked(model, state);
  }
}

TEST_SUITE("manifold") {
  // Every crossing kept: V-notch, hairpin and attached-tongue cuts whose slivers are thinner than a
  // voxel cross one lattice edge twice with both ends inside; the material between the two
  // crossings stays material (it belongs to the upper node's piece), so the surface keeps the
  // volume (within 0.05 %) and matches the physics mass (density x the nodes' eighths, which no cut
  // changes); nothing is dropped but the rim intervals cut_dropped_length counts.
  TEST_CASE("slivers: V-notch, hairpin and attached tongue keep their volume and match the physics mass") {
    const Vec3d c(0.0123, 0.0071, -0.0093);
    const TriMesh box = make_box(c, Vec3d(1.0, 0.6, 0.8), Eigen::Matrix3d::Identity(), 2);
    const double x_frac[2] = {15.2, 15.35};  // the sliver's first sheet within the voxel
    for (double xf : x_frac) {
      const VoxelModel model = voxelized(box, 32);
      const double h = model.lattice.voxel_size;
      const double x0 = model.lattice.origin.x() + xf * h;
      struct Path {
        const char* name;
        double half_z;  // blade half length (< 0.8: the cut stops inside, the middle stays attached)
        std::vector<Vec3d> points;  // (x, y) of the blade's path
      };
      const double w = 0.6 * h;
      const Path paths[3] = {
          {"V-notch", 3.0, {Vec3d(x0, -1.0, 0), Vec3d(x0 + 0.5 * w, -0.1, 0), Vec3d(x0 + w, -1.0, 0)}},
          {"hairpin", 3.0, {Vec3d(x0, -1.0, 0), Vec3d(x0, -0.1, 0), Vec3d(x0 + w, -0.1, 0), Vec3d(x0 + w, -1.0, 0)}},
          {"attached tongue", 0.4, {Vec3d(x0, -1.0, 0), Vec3d(x0, -0.1, 0), Vec3d(x0 + w, -0.1, 0), Vec3d(x0 + w, -1.0, 0)}},
      };
      for (const Path& path : paths) {
        const std::string name = path.name;
        CAPTURE(name);
        CAPTURE(xf);
        CutState state;
        init_cut_state(model, state);
        PbdState pbd;
        std::string error;
        PbdParams params;
        params.resolution = 32;
        params.sim_resolution = 8;
        REQUIRE_MESSAGE(init_pbd(model, state, params, pbd.model, pbd.data, error), error);
        const double volume_before = surface_stats(compact_surface(state.surface)).volume;
        const double mass_before = total_mass(pbd.model);
        for (size_t i = 1; i < path.points.size(); ++i) {
          const Vec3d& p = path.points[i - 1];
          const Vec3d& q = path.points[i];
          dvx_test::sweep_steps(model, state, z_blade(p.x(), p.y(), path.half_z), z_blade(q.x(), q.y(), path.half_z), 20,
                                [&](int) {
                                  checked(model, state);
                                  pbd_apply_cut(model, state, pbd.model, pbd.data);
                                });
        }
        REQUIRE_MESSAGE(check_pbd_state(model, state, pbd.model, pbd.data, error), error);
        const double volume_after = surface_stats(compact_surface(state.surface)).volume;
        const double volume_change = (volume_after - volume_before) / volume_before;
        const double mass_change = (total_mass(pbd.model) - mass_before) / mass_before;
        MESSAGE(name << " (sheet at " << xf << " voxels): volume change " << 100.0 * volume_change << " %, mass change "
                     << 100.0 * mass_change << " %, dropped " << cut_dropped_length(model, state) << " voxels");
        CHECK(std::abs(volume_change) <= 0.0005);
        CHECK(std::abs(volume_change - mass_change) <= 0.0005);
        CHECK(cut_dropped_length(model, state) == 0.0);  // no rim: the sheets cross interior edges only
      }
    }
  }

  // What a cut does drop: at the rim where a cut meets the organ's surface, the material between
  // the cut and the surface crossing of a surface edge holds no node (cut_dropped_length). Slanted
  // through cuts of a sphere lose about that much and no more.
  TEST_CASE("a through cut loses at most the rim intervals cut_dropped_length measures") {
    const Vec3d c(0.0123, 0.0071, -0.0093);
    const VoxelModel model = voxelized(make_icosphere(c, 1.0, 4), 32);
    const double h = model.lattice.voxel_size;
    for (double slope : {0.0, 0.37, 1.3}) {
      CAPTURE(slope);
      CutState state;
      init_cut_state(model, state);
      const double before = surface_stats(compact_surface(state.surface)).volume;
      const BladePose from{Vec3d(0.11, -1.3, -1.3), Vec3d(0.11 + slope, -1.3, 1.3)};
      const BladePose to{Vec3d(0.11, 1.3, -1.3), Vec3d(0.11 + slope, 1.3, 1.3)};
      dvx_test::sweep_steps(model, state, from, to, 30, [&](int) { checked(model, state); });
      const double lost = (before - surface_stats(compact_surface(state.surface)).volume) / before;
      const double dropped = cut_dropped_length(model, state) * h * h * h / before;
      MESSAGE("through cut, slope " << slope << ": volume lost " << 100.0 * lost << " %, rim intervals " << 100.0 * dropped
                                    << " % of the volume");
      CHECK(lost <= dropped + 0.0005);
      CHECK(lost >= -0.0005);
    }
  }
}
