// Progressive cutting: the divide operator, pieces, and the incrementally updated surface.
// After every step of every test: the surface is closed and consistently oriented, finite, and the
// state's own consistency check passes.
#include "sim/cut.h"
#include "sim/cut_internal.h"
#include "sim/mesh_distance.h"
#include "sim/random.h"
#include "sim/shapes.h"
#include "sim/state_hash.h"
#include "sim/surface_metrics.h"
#include "sim/voxelize.h"

#include <doctest/doctest.h>

#include "fixtures.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <bit>
#include <cmath>

using namespace dvx;

namespace {

using dvx_test::voxelized;

SurfaceStats stats_of(const CutState& state) { return surface_stats(compact_surface(state.surface)); }

// Checks every invariant; returns the stats.
SurfaceStats check_invariants(const VoxelModel& model, const CutState& state) {
  std::string error;
  const bool ok = check_cut_state(model, state, error);
  CHECK_MESSAGE(ok, error);
  const SurfaceStats stats = stats_of(state);
  CHECK(stats.boundary_edges == 0);
  CHECK(stats.misoriented_edges == 0);
  return stats;
}

// Moves the blade from `from` to `to` in `steps` equal steps, checking invariants every
// `check_every` steps (and at the end).
void sweep(const VoxelModel& model, CutState& state, const BladePose& from, const BladePose& to, int steps,
           int check_every = 1) {
  dvx_test::sweep_steps(model, state, from, to, steps, [&](int s) {
    if (s % check_every == 0 || s == steps) check_invariants(model, state);
  });
}

// A blade along z at x = x0, swept along y from y0 to y1.
BladePose z_blade(double x0, double y, double z_half = 3.0) { return {Vec3d(x0, y, -z_half), Vec3d(x0, y, z_half)}; }

const Vec3d kBoxCentre(0.0123, 0.0071, -0.0093);
TriMesh test_box() { return make_box(kBoxCentre, Vec3d(1.0, 0.6, 0.8), Eigen::Matrix3d::Identity(), 2); }

double component_volume_sum(const CutState& state) { return stats_of(state).volume; }

}  // namespace

TEST_SUITE("cut") {
  TEST_CASE("the initial state is the closed dual-contoured surface") {
    const VoxelModel model = voxelized(test_box(), 24);
    CutState state;
    init_cut_state(model, state);
    const SurfaceStats stats = check_invariants(model, state);
    CHECK(stats.components == 1);
    CHECK(stats.euler == 2);
    CHECK(stats.volume == doctest::Approx(2.0 * 1.2 * 1.6).epsilon(0.01));
  }

  TEST_CASE("planar through-cut of a box: two closed pieces, volume kept, cut vertices on the plane") {
    const VoxelModel model = voxelized(test_box(), 32);
    const double h = model.lattice.voxel_size;
    CutState state;
    init_cut_state(model, state);
    const double uncut = stats_of(state).volume;
    const double x0 = 0.137;
    sweep(model, state, z_blade(x0, -1.0), z_blade(x0, 1.0), 60);
    const SurfaceStats stats = check_invariants(model, state);
    CHECK(stats.components == 2);
    CHECK(std::abs(stats.volume - uncut) / uncut < 0.005);
    // Vertices of divided voxels away from the box surface lie on the cutting plane.
    const SurfaceMesh mesh = compact_surface(state.surface);
    int on_plane = 0;
    for (size_t v = 0; v < mesh.positions.size(); ++v) {
      const Vec3d p = mesh.positions[v].cast<double>();
      const Vec3d d = (p - kBoxCentre).cwiseAbs();
      if (d.x() > 0.9 || d.y() > 0.6 - 2 * h || d.z() > 0.8 - 2 * h) continue;
      if (state.divided_of.get(mesh.vertex_voxel[v]) == kDeadIndex) continue;
      CHECK(std::abs(p.x() - x0) <= 0.01 * h);
      ++on_plane;
    }
    CHECK(on_plane > 100);
  }

  TEST_CASE("the consistency check finds one broken invariant of each kind") {
    // A through-cut box, then copies of its state with one corruption each: the check must name it.
    const VoxelModel model = voxelized(test_box(), 24);
    CutState state;
    init_cut_state(model, state);
    sweep(model, state, z_blade(0.137, -1.0), z_blade(0.137, 1.0), 20, 20);
    REQUIRE(!state.edge_cuts.empty());
    REQUIRE(!state.divided.empty());
    REQUIRE(!state.shapes.empty());
    const auto fails_with = [&](const CutState& broken, const std::string& what) {
      std::string error;
      const bool ok = check_cut_state(model, broken, error);
      CHECK_FALSE(ok);
      CHECK_MESSAGE(error.find(what) != std::string::npos, error);
    };
    {
      CutState broken = state;
      broken.edge_cuts[0].t_lo = 2.0f;
      fails_with(broken, "bad parameters");
    }
    {
      CutState broken = state;
      broken.divided[0].cut_edges ^= 1u;
      fails_with(broken, "stale cut-edge mask");
    }
    {
      CutState broken = state;
      broken.shapes[0].patch_count += 1;
      fails_with(broken, "memoised shape");
    }
    {
      CutState broken = state;
      uint32_t slot = 0;
      while (broken.surface.vertex_patch[slot] == CutSurface::kFreeKey) ++slot;
      broken.surface.positions[slot].x() += float(model.lattice.voxel_size);
      fails_with(broken, "stale vertex position");
    }
    {
      CutState broken = state;
      uint32_t quad = 0;
      while (broken.surface.quad_half_edge[quad] == CutSurface::kFreeKey) ++quad;
      auto& t = broken.surface.triangles[2 * quad];
      const uint32_t other = t[0] == 0 ? 1 : 0;  // a vertex of no patch of this edge (or a different one)
      for (uint32_t& v : t) v = v == t[0] ? v : other;
      fails_with(broken, "does not join its patches");
    }
  }

  TEST_CASE("a partial cut that stops mid-object and mid-voxel: one closed piece with both slit faces") {
    const VoxelModel model = voxelized(test_box(), 32);
    const double h = model.lattice.voxel_size;
    CutState state;
    init_cut_state(model, state);
    const uint32_t triangles_before = stats_of(state).triangles;
    // Stop inside the box, in the middle of a voxel.
    const double y_stop = model.lattice.origin.y() + (std::floor((0.1 - model.lattice.origin.y()) / h) + 0.5) * h;
    const double x0 = 0.137;
    sweep(model, state, z_blade(x0, -1.0, 0.5), z_blade(x0, y_stop, 0.5), 40);
    const SurfaceStats stats = check_invariants(model, state);
    CHECK(stats.components == 1);
    CHECK(stats.triangles > triangles_before + 100);
    // Both faces of the slit: triangles facing -x and +x on the cutting plane, inside the box.
    const SurfaceMesh mesh = compact_surface(state.surface);
    int facing_minus = 0, facing_plus = 0;
    for (const Tri& t : mesh.triangles) {
      const Vec3d a = mesh.positions[t[0]].cast<double>(), b = mesh.positions[t[1]].cast<double>(),
                  c = mesh.positions[t[2]].cast<double>();
      const Vec3d centroid = (a + b + c) / 3.0;
      if (std::abs(centroid.x() - x0) > 0.01 * h || std::abs(centroid.z() - kBoxCentre.z()) > 0.3) continue;
      if (centroid.y() > y_stop - h) continue;
      const Vec3d n = (b - a).cross(c - a).normalized();
      facing_minus += n.x() < -0.99;
      facing_plus += n.x() > 0.99;
    }
    CHECK(facing_minus > 20);
    CHECK(facing_plus > 20);
    CHECK(std::abs(facing_minus - facing_plus) <= facing_minus / 10 + 2);
  }

  TEST_CASE("the same cut in 1 step and in 200 steps gives the same surface") {
    const VoxelModel model = voxelized(test_box(), 24);
    CutState one, many;
    init_cut_state(model, one);
    init_cut_state(model, many);
    const BladePose from = z_blade(0.071, -1.0, 0.55), to = z_blade(0.071, 0.2, 0.55);  // partial: ends inside
    sweep(model, one, from, to, 1);
    sweep(model, many, from, to, 200, 20);
    const SurfaceStats a = stats_of(one), b = stats_of(many);
    CHECK(a.components == b.components);
    CHECK(a.vertices == b.vertices);
    CHECK(a.triangles == b.triangles);
    CHECK(a.euler == b.euler);
    const ErrorStats e = two_sided_error(to_trimesh(compact_surface(one.surface)),
                                         to_trimesh(compact_surface(many.surface)), 20000, 5);
    CHECK(e.max / model.lattice.voxel_size < 0.05);
  }

  TEST_CASE("a blade crossing 20 voxels in one step equals small steps") {
    const VoxelModel model = voxelized(test_box(), 32);
    const double h = model.lattice.voxel_size;
    CutState big, small;
    init_cut_state(model, big);
    init_cut_state(model, small);
    const BladePose from = z_blade(-0.211, -1.0), mid = z_blade(-0.211, -1.0 + 20 * h), to = z_blade(-0.211, 1.0);
    sweep(model, big, from, mid, 1);
    sweep(model, big, mid, to, 1);
    sweep(model, small, from, to, 100, 25);
    CHECK(stats_of(big).triangles == stats_of(small).triangles);
    CHECK(stats_of(big).components == 2);
    CHECK(stats_of(small).components == 2);
  }

  TEST_CASE("a blade that pauses 50 steps inside a voxel and resumes") {
    const VoxelModel model = voxelized(test_box(), 24);
    const double h = model.lattice.voxel_size;
    CutState paused, straight;
    init_cut_state(model, paused);
    init_cut_state(model, straight);
    const BladePose from = z_blade(0.05, -1.0, 0.5), stop = z_blade(0.05, -0.2 + 0.37 * h, 0.5),
                    to = z_blade(0.05, 0.3, 0.5);
    sweep(model, paused, from, stop, 30);
    for (int i = 0; i < 50; ++i) {
      cut_step(model, paused, stop, stop);  // parked: sweeps nothing
    }
    check_invariants(model, paused);
    // Jitter inside the voxel while parked.
    const BladePose nudge = z_blade(0.05, -0.2 + 0.41 * h, 0.5);
    cut_step(model, paused, stop, nudge);
    cut_step(model, paused, nudge, stop);
    check_invariants(model, paused);
    sweep(model, paused, stop, to, 30);
    sweep(model, straight, from, to, 60);
    CHECK(stats_of(paused).triangles == stats_of(straight).triangles);
    CHECK(stats_of(paused).components == 1);
  }

  TEST_CASE("degenerate: a cut exactly through lattice nodes and a cut lying in a lattice plane") {
    const VoxelModel model = voxelized(test_box(), 20);
    const Lattice& l = model.lattice;
    SUBCASE("plane through a column of nodes") {
      const double x_nodes = l.origin.x() + 11 * l.voxel_size;  // exactly on lattice nodes
      CutState state;
      init_cut_state(model, state);
      sweep(model, state, z_blade(x_nodes, -1.0), z_blade(x_nodes, 1.0), 37);
      CHECK(check_invariants(model, state).components == 2);
    }
    SUBCASE("sweep inside the lattice plane z = k") {
      const double z_nodes = l.origin.z() + 10 * l.voxel_size;
      const BladePose from{Vec3d(-2, -1, z_nodes), Vec3d(2, -1, z_nodes)};
      const BladePose to{Vec3d(-2, 1, z_nodes), Vec3d(2, 1, z_nodes)};
      CutState state;
      init_cut_state(model, state);
      sweep(model, state, from, to, 23);
      CHECK(check_invariants(model, state).components == 2);
    }
    SUBCASE("inclined plane through many nodes (x + y = const on nodes)") {
      const Vec3d node = l.node_position(9, 9, 0);
      const double c = node.x() + node.y();
      // Blade along z on the line x + y = c, moving along (1, -1).
      const BladePose from{Vec3d(c + 2, -2, -3), Vec3d(c + 2, -2, 3)};
      const BladePose to{Vec3d(c - 2, 2, -3), Vec3d(c - 2, 2, 3)};
      CutState state;
      init_cut_state(model, state);
      sweep(model, state, from, to, 41);
      CHECK(check_invariants(model, state).components == 2);
    }
  }

  TEST_CASE("a cut that would isolate a single voxel corner leaves it on the body (no crumbs, docs/cutting.md)") {
    const VoxelModel model = voxelized(test_box(), 20);
    const Lattice& l = model.lattice;
    // The inside node nearest the box's (-,-,-) corner; a plane across its three edges cuts it off.
    int32_t best[3] = {0, 0, 0};
    for (int k = 0; k <= l.nz && best[0] == 0; ++k) {
      for (int j = 0; j <= l.ny && best[0] == 0; ++j) {
        for (int i = 0; i <= l.nx && best[0] == 0; ++i) {
          if (model.is_inside(l.node(i, j, k))) {
            best[0] = i;
            best[1] = j;
            best[2] = k;
          }
        }
      }
    }
    REQUIRE(best[0] > 0);
    const Vec3d corner = l.node_position(best[0], best[1], best[2]);
    const double h = l.voxel_size;
    // Plane x + y + z = corner sum + 0.6 h (only this node lies below it among inside nodes).
    const Vec3d n = Vec3d(1, 1, 1).normalized();
    const Vec3d centre = corner + Vec3d::Constant(0.2 * h);
    const Vec3d u = Vec3d(1, -1, 0).normalized(), w = n.cross(u);
    const BladePose from{centre - 3 * h * u - 3 * h * w, centre + 3 * h * u - 3 * h * w};
    const BladePose to{centre - 3 * h * u + 3 * h * w, centre + 3 * h * u + 3 * h * w};
    CutState state;
    init_cut_state(model, state);
    const double uncut = stats_of(state).volume;
    sweep(model, state, from, to, 5);
    const SurfaceStats stats = check_invariants(model, state);
    // The node would be a component of its own, smaller than a fine voxel: its last link is not cut.
    CHECK(stats.components == 1);
    CHECK(stats.volume == doctest::Approx(uncut).epsilon(1e-3));
  }

  // Issue 29's liver crumbs: two strips of one stroke through moving tissue landed in rest space a
  // fraction of a voxel apart on either side of a layer of nodes near the organ's surface, and the
  // seams closed at the stroke's end sealed the flake between them: closed bits of five nodes and
  // 0.4-0.5 fine voxels, which the node count alone (kCrumbNodes) let go. Here: two slits down from
  // the top face of a box that end inside it, x planes 0.06 to 0.14 voxels on either side of
  // a node layer, and three narrow cuts across that layer (a y plane under the top one or two rows of
  // nodes, z planes on either side), in a random order (fixed seed): the flake between them holds 5
  // or 6 nodes and less than a fine voxel. It stays on the body, and nothing is dropped.
  TEST_CASE("a flake of five or six nodes between two slits, sealed by three cuts, stays on the body (no crumbs)") {
    // The top face half a voxel above the top row of nodes (the lattice centres the box).
    const TriMesh box = make_box(kBoxCentre, Vec3d(1.0, 0.504, 0.8), Eigen::Matrix3d::Identity(), 2);
    const VoxelModel model = voxelized(box, 24);
    const Lattice& l = model.lattice;
    const double h = l.voxel_size, top = kBoxCentre.y() + 0.504;
    SplitMix64 rng{29};
    for (int run = 0; run < 12; ++run) {
      // The flake: nodes x = i, y in [jt - ny, jt] (jt the top row), z in [k, k + nz]: 1 x 5 or 2 x 3.
      const int ny = run % 2, nz = ny ? 2 : 4;
      const int i = l.nx / 2 - 2 + int(rng.uniform() * 4.0);
      const int k = l.nz / 2 - 2 + int(rng.uniform() * 3.0);
      int jt = 0;
      while (model.is_inside(l.node(i, jt + 1, k)) || !model.is_inside(l.node(i, jt, k))) ++jt;
      REQUIRE(top - l.node_position(i, jt, k).y() < 0.6 * h);
      const Vec3d lo = l.node_position(i, jt - ny, k), hi = l.node_position(i, jt, k + nz);
      const double below = rng.uniform(0.06, 0.14) * h, above = rng.uniform(0.06, 0.14) * h;  // the slits
      double rim[3];  // outside the flake: y below, z below, z above
      for (double& r : rim) r = rng.uniform(0.05, 0.25) * h;
      CAPTURE(run);
      CAPTURE(below / h);
      CAPTURE(above / h);
      CutState state;
      init_cut_state(model, state);
      const double uncut = stats_of(state).volume;
      // A slit: a blade along y from above the box to 1.5 voxels under the flake, swept in z from 1.5
      // voxels before it to 1.5 past it (it ends inside the tissue).
      const auto slit = [&](double x) {
        const double y0 = top + h, y1 = lo.y() - 1.5 * h;
        sweep(model, state, {Vec3d(x, y0, lo.z() - 1.5 * h), Vec3d(x, y1, lo.z() - 1.5 * h)},
              {Vec3d(x, y0, hi.z() + 1.5 * h), Vec3d(x, y1, hi.z() + 1.5 * h)}, 4);
      };
      // A cut across the layer: a blade along x over both slits, at y = c (axis 1: swept in z two
      // voxels past the flake) or at z = c (axis 2: swept from above the box to two voxels under it).
      const auto across = [&](int axis, double c) {
        Vec3d p0 = lo, p1 = hi;
        if (axis == 1) {
          p0 = Vec3d(lo.x(), c, lo.z() - 2.0 * h);
          p1 = Vec3d(lo.x(), c, hi.z() + 2.0 * h);
        } else {
          p0 = Vec3d(lo.x(), top + h, c);
          p1 = Vec3d(lo.x(), lo.y() - 2.0 * h, c);
        }
        const Vec3d dx(1.5 * h, 0.0, 0.0);
        sweep(model, state, {p0 - dx, p0 + dx}, {p1 - dx, p1 + dx}, 4);
      };
      std::vector<int> order = {0, 1, 2, 3, 4};  // 0, 1: the slits; 2-4: the cuts across
      for (size_t n = order.size(); n > 1; --n) std::swap(order[n - 1], order[size_t(rng.uniform() * double(n))]);
      for (const int cut : order) {
        if (cut < 2) {
          slit(cut == 0 ? lo.x() - below : lo.x() + above);
        } else if (cut == 2) {
          across(1, lo.y() - rim[0]);
        } else {
          across(2, cut == 3 ? lo.z() - rim[1] : hi.z() + rim[2]);
        }
      }
      const SurfaceStats stats = check_invariants(model, state);
      const std::vector<double> volumes = component_volumes(compact_surface(state.surface));
      // Nothing came off (the flake would be the only piece), and no material was dropped.
      CHECK(stats.components == 1);
      CHECK(*std::min_element(volumes.begin(), volumes.end()) >= h * h * h);
      CHECK(stats.volume == doctest::Approx(uncut).epsilon(1e-3));
    }
  }

  // The crumb test's shortcut (cut_internal::bulk_behind: uncut bulk material behind an end of the
  // edge) must only ever answer where the flood fill would say "no crumb": after random slits and
  // through-cuts of a box (fixed seed), at every end of every uncut edge around the cut edges and at
  // random inside nodes, with a random crossing, the shortcut implies the flood's no.
  TEST_CASE("the crumb test's shortcut agrees with the flood fill on random cuts") {
    const VoxelModel model = voxelized(test_box(), 24);
    const Lattice& l = model.lattice;
    SplitMix64 rng{31};
    int shortcut = 0, crumbs = 0, checked = 0, wrong = 0;
    for (int run = 0; run < 6; ++run) {
      CAPTURE(run);
      CutState state;
      init_cut_state(model, state);
      for (int cut = 0; cut < 4; ++cut) {
        // A blade in a random plane through a point near the centre, of random length, swept a random
        // distance: slits that end inside and cuts across, some a voxel or two apart.
        Vec3d normal(rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-1, 1));
        if (rng.uniform() < 0.5) normal = Vec3d::Unit(int(rng.uniform() * 3.0)) + 0.1 * normal;
        normal.normalize();
        const Vec3d u = normal.unitOrthogonal(), w = normal.cross(u);
        const Vec3d p = kBoxCentre + Vec3d(rng.uniform(-0.4, 0.4), rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3));
        const double half = rng.uniform(0.2, 2.0), from = rng.uniform(-1.5, 0.0), to = rng.uniform(0.0, 1.5);
        dvx_test::sweep_steps(model, state, {p - half * u + from * w, p + half * u + from * w},
                              {p - half * u + to * w, p + half * u + to * w}, 8, [](int) {});
      }
      check_invariants(model, state);
      // Nodes near the cut edges (up to two voxels off) and random inside nodes.
      std::vector<uint32_t> nodes;
      for (const EdgeCut& c : state.edge_cuts) {
        int32_t nc[3];
        l.node_coords(c.edge / 3, nc);
        for (int k = 0; k < 4; ++k) {
          const int32_t i = nc[0] + int(rng.uniform() * 5.0) - 2, j = nc[1] + int(rng.uniform() * 5.0) - 2;
          const int32_t m = nc[2] + int(rng.uniform() * 5.0) - 2;
          if (i >= 0 && i <= l.nx && j >= 0 && j <= l.ny && m >= 0 && m <= l.nz) nodes.push_back(l.node(i, j, m));
        }
      }
      for (int k = 0; k < 400; ++k) nodes.push_back(uint32_t(rng.uniform() * double(l.node_count())));
      for (const uint32_t n : nodes) {
        if (!model.is_inside(n)) continue;
        int32_t nc[3];
        l.node_coords(n, nc);
        const int32_t dims[3] = {l.nx, l.ny, l.nz};
        for (int a = 0; a < 3; ++a) {
          for (int upper = 0; upper < 2; ++upper) {  // the edge toward -a (n its upper end) or +a
            if (upper ? nc[a] == 0 : nc[a] == dims[a]) continue;
            const uint32_t stride = a == 0 ? 1u : a == 1 ? uint32_t(l.nx + 1) : uint32_t(l.nx + 1) * uint32_t(l.ny + 1);
            const uint32_t edge = Lattice::edge(upper ? n - stride : n, a);
            if (state.edge_cut_of.contains(edge)) continue;  // record_cut tests first cuts only
            const float t = float(rng.uniform());
            const bool fast = cut_internal::bulk_behind(model, state, n, edge);
            const bool crumb = cut_internal::material_flood(model, state, n, edge, t);
            wrong += fast && crumb;
            shortcut += fast;
            crumbs += crumb;
            ++checked;
          }
        }
      }
    }
    // The shortcut answered often, and the flood found crumbs too (the cases are not all one kind).
    MESSAGE("checked " << checked << ", shortcut " << shortcut << ", crumbs " << crumbs);
    CHECK(wrong == 0);
    CHECK(shortcut > checked / 10);
    CHECK(crumbs > 0);
  }

  TEST_CASE("two crossing cuts separate four pieces") {
    const VoxelModel model = voxelized(test_box(), 28);
    CutState state;
    init_cut_state(model, state);
    const double uncut = stats_of(state).volume;
    sweep(model, state, z_blade(0.093, -1.0), z_blade(0.093, 1.0), 40, 4);
    CHECK(stats_of(state).components == 2);
    // Second blade along x at z = -0.117, swept along y.
    const BladePose from{Vec3d(-3, -1, -0.117), Vec3d(3, -1, -0.117)}, to{Vec3d(-3, 1, -0.117), Vec3d(3, 1, -0.117)};
    sweep(model, state, from, to, 40, 4);
    const SurfaceStats stats = check_invariants(model, state);
    CHECK(stats.components == 4);
    CHECK(std::abs(component_volume_sum(state) - uncut) / uncut < 0.01);
  }

  TEST_CASE("the surface built and updated over workers is the serial one, to the bit") {
    // refresh_voxels computes a block of voxels' vertices and a block of edges' quads over the
    // workers and writes them in list order: the slots, the changed lists and the stats must be the
    // ones of one serial pass, for lists of many blocks (the whole surface at init, a one-step
    // cut across the box) and with crossing cuts (the voxels across four-point faces).
    const VoxelModel model = voxelized(test_box(), 40);
    dvx_test::ThreadRunner three{3};
    CutState serial, shared;
    init_cut_state(model, serial);
    init_cut_state(model, shared, {}, three.runner());
    CHECK(serial.surface.positions.size() > 2048);  // several blocks of 512 voxels
    CHECK(cut_state_hash(shared) == cut_state_hash(serial));
    const BladePose z_from = z_blade(0.093, -1.0), z_to = z_blade(0.093, 1.0);
    const BladePose x_from{Vec3d(-3, -1, -0.117), Vec3d(3, -1, -0.117)}, x_to{Vec3d(-3, 1, -0.117), Vec3d(3, 1, -0.117)};
    const struct {
      BladePose from, to;
      int steps;
    } strokes[] = {{z_from, z_to, 1}, {x_from, x_to, 3}, {{Vec3d(-3, 0.21, -3), Vec3d(3, 0.21, 3)}, {Vec3d(-3, 0.21, 3), Vec3d(3, 0.21, -3)}, 2}};
    uint32_t largest = 0;
    for (const auto& stroke : strokes) {
      BladePose previous = stroke.from;
      for (int k = 1; k <= stroke.steps; ++k) {
        const double f = double(k) / stroke.steps;
        const BladePose next{stroke.from.a + f * (stroke.to.a - stroke.from.a), stroke.from.b + f * (stroke.to.b - stroke.from.b)};
        CutStepStats a, b;
        cut_divide(model, serial, previous, next, a);
        cut_divide(model, shared, previous, next, b);
        largest = std::max(largest, uint32_t(serial.pending_voxels.size()));
        cut_update_surface(model, serial, a);
        cut_update_surface(model, shared, b, three.runner());
        CHECK(cut_state_hash(shared) == cut_state_hash(serial));
        CHECK(shared.changed_vertices == serial.changed_vertices);
        CHECK(shared.touched_vertices == serial.touched_vertices);
        CHECK(shared.touched_quads == serial.touched_quads);
        CHECK(b.vertices_changed == a.vertices_changed);
        CHECK(b.triangles_changed == a.triangles_changed);
        previous = next;
      }
    }
    CHECK(largest > 512);  // a step's list of several blocks
    CHECK(three.splits > 0);
    CHECK(check_invariants(model, shared).components == 6);
  }

  TEST_CASE("every vertex is its patch's vertex rule to the bit after every step, across four-point faces too") {
    // refresh_voxels recomputes the voxels a step changed and checks the ones across their four-point
    // faces by their patches alone (vertices_current): a voxel the step left alone keeps its vertices
    // when its patches hold the same half-edges. Every live vertex must still be exactly what the
    // vertex rule gives for its patch now (check_cut_state allows 1e-5 voxel), and the crossing cuts
    // must make faces of four points (where those neighbours are checked).
    const VoxelModel model = voxelized(test_box(), 28);
    CutState state;
    init_cut_state(model, state);
    uint32_t four_point_voxels = 0;
    const auto check_exact = [&] {
      const CutSurface& s = state.surface;
      uint32_t differ = 0;
      for (uint32_t slot = 0; slot < s.positions.size(); ++slot) {
        if (s.vertex_patch[slot] == CutSurface::kFreeKey) continue;
        const uint32_t voxel = uint32_t(s.vertex_patch[slot] / 16), p = uint32_t(s.vertex_patch[slot] % 16);
        int32_t vc[3];
        model.lattice.voxel_coords(voxel, vc);
        cut_internal::VoxelPatches patches;
        cut_internal::voxel_patches(model, state, voxel, vc, patches);
        const Vec3f want = cut_internal::patch_vertex_position(model, state, voxel, vc, patches, uint8_t(p));
        differ += want != s.positions[slot] || s.vertex_half_edges[slot] != patches.patch_half_edges[p];
      }
      CHECK(differ == 0);
      for (const uint32_t voxel : state.changed_voxels) {
        int32_t vc[3];
        model.lattice.voxel_coords(voxel, vc);
        cut_internal::VoxelPatches patches;
        cut_internal::voxel_patches(model, state, voxel, vc, patches);
        for (int f = 0; f < 6; ++f) {
          int points = 0;
          for (int i = 0; i < 4; ++i) points += std::popcount((patches.present >> (2 * cut_internal::kFaceEdges.edge[f][i])) & 3u);
          if (points >= 4) {
            ++four_point_voxels;
            break;
          }
        }
      }
    };
    dvx_test::sweep_steps(model, state, z_blade(0.093, -1.0), z_blade(0.093, 1.0), 40, [&](int) { check_exact(); });
    const BladePose from{Vec3d(-3, -1, -0.117), Vec3d(3, -1, -0.117)}, to{Vec3d(-3, 1, -0.117), Vec3d(3, 1, -0.117)};
    dvx_test::sweep_steps(model, state, from, to, 40, [&](int) { check_exact(); });
    CHECK(four_point_voxels > 0);
    CHECK(check_invariants(model, state).components == 4);
  }

  TEST_CASE("a U-shaped object cut once across both arms gives three pieces") {
    // Arms point up (+y); the blade along z sweeps along x across both arms at mid height.
    const TriMesh u = make_u_shape(Vec3d(0.01, 0.02, 0.03), 2.0, 2.0, 1.0, 0.6);
    REQUIRE(!u.triangles.empty());
    const VoxelModel model = voxelized(u, 40);
    CutState state;
    init_cut_state(model, state);
    const BladePose from{Vec3d(-2, 0.61, -2), Vec3d(-2, 0.61, 2)}, to{Vec3d(2, 0.61, -2), Vec3d(2, 0.61, 2)};
    sweep(model, state, from, to, 50, 5);
    const SurfaceStats stats = check_invariants(model, state);
    CHECK(stats.components == 3);
  }

  TEST_CASE("an edge crossed twice by one cut (the blade turns back inside a voxel)") {
    const VoxelModel model = voxelized(test_box(), 24);
    const double h = model.lattice.voxel_size;
    CutState state;
    init_cut_state(model, state);
    const double x0 = model.lattice.origin.x() + 21.3 * h;
    sweep(model, state, z_blade(x0, -1.0), z_blade(x0, 1.0), 30, 3);
    // Step sideways within the voxel and come back: every x-edge there is crossed twice.
    cut_step(model, state, z_blade(x0, 1.0), z_blade(x0 + 0.4 * h, 1.0));
    sweep(model, state, z_blade(x0 + 0.4 * h, 1.0), z_blade(x0 + 0.4 * h, -1.0), 30, 3);
    const SurfaceStats stats = check_invariants(model, state);
    CHECK(stats.components == 2);
    bool twice = false;
    for (const EdgeCut& c : state.edge_cuts) twice = twice || c.t_hi - c.t_lo > 0.3f;
    CHECK(twice);
  }

  TEST_CASE("a helix-shaped cut stays closed and consistent") {
    const TriMesh cylinder_like = make_box(Vec3d(0.003, 0.002, 0.001), Vec3d(0.7, 0.7, 1.0), Eigen::Matrix3d::Identity(), 2);
    const VoxelModel model = voxelized(cylinder_like, 24);
    CutState state;
    init_cut_state(model, state);
    BladePose previous;
    for (int s = 0; s <= 120; ++s) {
      const double angle = 0.08 * s, z = -0.9 + 0.015 * s;
      const Vec3d dir(std::cos(angle), std::sin(angle), 0.0);
      const BladePose pose{Vec3d(0, 0, z) + 0.1 * dir, Vec3d(0, 0, z) + 1.5 * dir};
      if (s > 0) cut_step(model, state, previous, pose);
      previous = pose;
      if (s % 10 == 0) check_invariants(model, state);
    }
    check_invariants(model, state);
  }

  TEST_CASE("a blade far outside the grid, of zero length, or moving a whole object length in one step") {
    const VoxelModel model = voxelized(test_box(), 16);
    CutState state;
    init_cut_state(model, state);
    const uint32_t before = stats_of(state).triangles;
    cut_step(model, state, {Vec3d(1e6, 1e6, 1e6), Vec3d(1e6, 1e6, 1e6 + 1)}, {Vec3d(2e6, 1e6, 1e6), Vec3d(2e6, 1e6, 1e6 + 1)});
    cut_step(model, state, {Vec3d(0.1, 0, 0), Vec3d(0.1, 0, 0)}, {Vec3d(0.1, 0.5, 0), Vec3d(0.1, 0.5, 0)});
    CHECK(stats_of(state).triangles == before);
    cut_step(model, state, z_blade(0.2, -5.0), z_blade(0.2, 5.0));
    CHECK(check_invariants(model, state).components == 2);
  }

  TEST_CASE("dirty ranges cover every slot a step changes") {
    const VoxelModel model = voxelized(test_box(), 20);
    CutState state;
    init_cut_state(model, state);
    const std::vector<Vec3f> positions_before = state.surface.positions;
    const std::vector<Tri> triangles_before = state.surface.triangles;
    state.surface.clear_dirty();
    cut_step(model, state, z_blade(0.1, -1.0), z_blade(0.1, -0.5));
    const CutSurface& s = state.surface;
    for (uint32_t i = 0; i < positions_before.size(); ++i) {
      const bool same = (positions_before[i].array() == s.positions[i].array()).all() ||
                        (!positions_before[i].allFinite() && !s.positions[i].allFinite());
      if (!same) CHECK((i >= s.dirty_vertex_begin && i < s.dirty_vertex_end));
    }
    for (uint32_t i = 0; i < triangles_before.size(); ++i) {
      if (triangles_before[i] != s.triangles[i]) CHECK((i >= s.dirty_triangle_begin && i < s.dirty_triangle_end));
    }
    CHECK((s.positions.size() == positions_before.size() || s.dirty_vertex_end == s.positions.size()));
  }
}

TEST_SUITE("cut") {
  TEST_CASE("vertex_quads finds each vertex's live triangles, touched_vertices names every vertex a step moved or re-triangulated") {
    // A box cut by a blade that turns as it goes down (partial cuts, a crossing of its own cut),
    // then by a straight one across: after every step, each slot's triangles equal a scan of all
    // live triangles, and the corners of each triangle slot that changed (old and new) are listed.
    const VoxelModel model = voxelized(test_box(), 20);
    CutState state;
    init_cut_state(model, state);
    BladePose previous{Vec3d(0.0, 0.0, -0.9), Vec3d(1.2, 0.0, -0.9)};
    uint64_t changed_triangles = 0;
    for (int step = 1; step <= 50; ++step) {
      const double angle = 0.12 * step, z = -0.9 + 0.03 * step;
      const Vec3d dir(std::cos(angle), std::sin(angle), 0.0);
      const BladePose pose = step <= 40 ? BladePose{Vec3d(0, 0, z) - 0.3 * dir, Vec3d(0, 0, z) + 1.2 * dir}
                                        : BladePose{Vec3d(-2, 0.1 * (step - 45), -2), Vec3d(-2, 0.1 * (step - 45), 2)};
      const BladePose from = step == 41 ? BladePose{Vec3d(2, -0.5, -2), Vec3d(2, -0.5, 2)} : previous;
      const std::vector<Tri> before = state.surface.triangles;
      const std::vector<Vec3f> positions = state.surface.positions;
      const std::vector<uint32_t> touched_before = state.touched_vertices;
      const uint64_t changes = state.surface_changes;
      cut_step(model, state, from, pose);
      previous = pose;
      const CutSurface& s = state.surface;
      std::vector<uint8_t> listed(s.positions.size(), 0);
      for (uint32_t v : state.touched_vertices) {
        REQUIRE(v < listed.size());
        listed[v] = 1;
      }
      // A step that changed the surface counts one change and lists what it touched; one that did
      // not keeps the last list.
      bool changed = !state.changed_vertices.empty();
      for (uint32_t v : state.changed_vertices) CHECK(listed[v] == 1);
      for (uint32_t v = 0; v < positions.size(); ++v) {
        if (positions[v] != s.positions[v]) CHECK(listed[v] == 1);
      }
      for (uint32_t t = 0; t < s.triangles.size(); ++t) {
        const Tri old = t < before.size() ? before[t] : Tri{kDeadIndex, kDeadIndex, kDeadIndex};
        if (old == s.triangles[t]) continue;
        changed = true;
        ++changed_triangles;
        for (const Tri& tri : {old, s.triangles[t]}) {
          for (uint32_t v : tri) {
            if (v != kDeadIndex) CHECK(listed[v] == 1);
          }
        }
      }
      CHECK(state.surface_changes == changes + (changed ? 1 : 0));
      if (!changed) CHECK(state.touched_vertices == touched_before);
      std::vector<std::vector<uint32_t>> scan(s.positions.size());
      for (uint32_t t = 0; t < s.triangles.size(); ++t) {
        if (s.quad_half_edge[t / 2] == CutSurface::kFreeKey) continue;
        for (uint32_t v : s.triangles[t]) scan[v].push_back(t);
      }
      // The triangles of a vertex's quads that name it, ascending.
      for (uint32_t v = 0; v < s.positions.size(); ++v) {
        uint32_t quads[kMaxVertexQuads];
        const uint32_t n = vertex_quads(state, v, quads);
        std::vector<uint32_t> found;
        for (uint32_t q = 0; q < n; ++q) {
          for (uint32_t t = 2 * quads[q]; t < 2 * quads[q] + 2; ++t) {
            const Tri& tri = s.triangles[t];
            if (tri[0] == v || tri[1] == v || tri[2] == v) found.push_back(t);
          }
        }
        std::sort(found.begin(), found.end());
        CHECK(found == scan[v]);
      }
    }
    CHECK(changed_triangles > 1000);
    check_invariants(model, state);
    // A blade through air changes nothing: no change counted, the last list kept.
    const uint64_t changes = state.surface_changes;
    const std::vector<uint32_t> touched = state.touched_vertices;
    cut_step(model, state, {Vec3d(50, 50, -1), Vec3d(50, 50, 1)}, {Vec3d(51, 50, -1), Vec3d(51, 50, 1)});
    CHECK(state.surface_changes == changes);
    CHECK(state.touched_vertices == touched);
    CHECK(!touched.empty());
  }
}
