// Deformation on simulation voxels through cuts: mass, sagging and rest, falling pieces, partial
// cuts that open only up to their front, hard cases, and thread-count independence.
#include "sim/cut.h"
#include "sim/pbd.h"
#include "sim/shapes.h"
#include "sim/state_hash.h"
#include "sim/surface_metrics.h"
#include "sim/voxelize.h"
#include "sim/world_to_rest.h"

#include "fixtures.h"

#include <doctest/doctest.h>

#include <cmath>
#include <thread>

using namespace dvx;

namespace {

// A block 1 x 2 x 1 (y up), centred at the origin.
using Scene = dvx_test::PbdScene;
using dvx_test::ThreadRunner;

void make_scene(Scene& scene, int resolution, int sim_resolution, PbdParams params, double half_y = 1.0) {
  const TriMesh box = make_box(Vec3d(0.0013, 0.0021, 0.0007), Vec3d(0.5, half_y, 0.5), Eigen::Matrix3d::Identity(), 1);
  dvx_test::make_pbd_scene(scene, box, resolution, sim_resolution, params);
}

// Anchors the particles at the top of the block (rest y above `y`).
PbdParams hanging(double y) {
  PbdParams p;
  Aabb top;
  top.grow(Vec3d(-5, y, -5));
  top.grow(Vec3d(5, 5, 5));
  p.fixed.push_back(top);
  p.damping = 0.0;
  p.stretch_compliance = 1e-7;
  return p;
}

// The PBD model's and the cut state's consistency checks (after every cut step).
void require_consistent(const Scene& s) {
  std::string error;
  REQUIRE_MESSAGE(check_cut_state(s.model, s.cut, error), error);
  REQUIRE_MESSAGE(check_pbd_state(s.model, s.cut, s.pbd.model, s.pbd.data, error), error);
}

void cut(Scene& s, const BladePose& from, const BladePose& to, int steps) {
  BladePose previous = from;
  for (int i = 1; i <= steps; ++i) {
    const double f = double(i) / steps;
    const BladePose next{from.a + f * (to.a - from.a), from.b + f * (to.b - from.b)};
    cut_step(s.model, s.cut, previous, next);
    pbd_apply_cut(s.model, s.cut, s.pbd.model, s.pbd.data);
    require_consistent(s);
    previous = next;
  }
}

// Horizontal blade along z at height y, swept along x from x0 to x1.
void horizontal_cut(Scene& s, double y, double x0, double x1, int steps) {
  cut(s, {Vec3d(x0, y, -2), Vec3d(x0, y, 2)}, {Vec3d(x1, y, -2), Vec3d(x1, y, 2)}, steps);
}

// Mass-weighted centre of the live particles whose rest position is below y.
Vec3d centre_below(const PbdState& s, double y) {
  Vec3d c = Vec3d::Zero();
  double m = 0.0;
  for (size_t p = 0; p < s.data.position.size(); ++p) {
    if (s.model.refs[p] == 0 || s.model.rest[p].y() >= y) continue;
    c += s.model.mass[p] * s.data.position[p];
    m += s.model.mass[p];
  }
  return c / m;
}

uint64_t particle_hash(const PbdState& s) {
  Fnv1a h;
  for (size_t p = 0; p < s.data.position.size(); ++p) h.bytes(s.data.position[p].data(), 3 * sizeof(double));
  return h.value;
}

}  // namespace

TEST_SUITE("pbd") {
  TEST_CASE("total mass is conserved exactly through any sequence of cuts") {
    Scene s;
    make_scene(s, 32, 8, PbdParams{});
    const double before = total_mass(s.pbd.model);
    CHECK(before == doctest::Approx(1000.0 * 1.0 * 2.0 * 1.0).epsilon(0.02));
    horizontal_cut(s, 0.137, -1.0, 1.0, 20);                         // through
    cut(s, {Vec3d(0.11, 1.5, -2), Vec3d(0.11, 1.5, 2)}, {Vec3d(0.11, -0.3, -2), Vec3d(0.11, -0.3, 2)}, 15);  // crossing
    horizontal_cut(s, -0.52, -1.0, 0.1, 12);                         // partial
    CHECK(sim_voxels_divided(s.pbd.model) > 0);
    CHECK(std::abs(total_mass(s.pbd.model) - before) <= 1e-12 * before);
  }

  TEST_CASE("relabelling after cuts gives the material components: spans (ratio 16) and the local search (ratio 64)") {
    // Curved surfaces, a torus's hole and two nested shells (thin gaps, ambiguous faces); cuts that
    // cross, stop halfway and split simulation voxels in one step. check_pbd_state recomputes every
    // block's components node by node (label_block) after each step.
    const TriMesh shapes = merge_meshes(make_torus(Vec3d(0.011, 0.3, 0.007), 0.55, 0.22, 24, 12),
                                        make_two_shells(Vec3d(0.013, -0.45, 0.021), 0.42, 0.33, 3));
    for (const int sim_resolution : {4, 1}) {
      CAPTURE(sim_resolution);
      Scene s;
      dvx_test::make_pbd_scene(s, shapes, 64, sim_resolution, PbdParams{});
      const double before = total_mass(s.pbd.model);
      horizontal_cut(s, 0.3137, -1.0, 1.0, 3);                                                            // through, fast
      cut(s, {Vec3d(0.051, 1.5, -2), Vec3d(0.051, 1.5, 2)}, {Vec3d(0.051, -0.2, -2), Vec3d(0.051, -0.2, 2)}, 9);  // crossing
      horizontal_cut(s, -0.4113, -1.0, 0.05, 5);                                                          // halfway
      cut(s, {Vec3d(-1, -1.2, 0.3), Vec3d(1, 0.8, 0.3)}, {Vec3d(-1, -1.2, -0.2), Vec3d(1, 0.8, -0.2)}, 1);  // oblique, one step
      CHECK(std::abs(total_mass(s.pbd.model) - before) <= 1e-12 * before);
      CHECK(live_pieces(s.pbd.model) > 0);
    }
  }

  TEST_CASE("a block anchored at its top sags under gravity and comes to rest") {
    Scene s;
    PbdParams params = hanging(0.9);
    params.damping = 0.02;
    params.stretch_compliance = 1e-5;
    make_scene(s, 24, 6, params);
    const double bottom_rest = centre_below(s.pbd, -0.5).y();
    double energy = 0.0;
    for (int i = 0; i < 600; ++i) {
      pbd_step(s.cut, s.pbd.model, s.pbd.data);
      if (i == 20) energy = kinetic_energy(s.pbd.model, s.pbd.data);
    }
    const double sag = bottom_rest - centre_below(s.pbd, -0.5).y();
    CHECK(sag > 1e-4);  // it sags
    CHECK(sag < 0.5);   // but holds together
    CHECK(kinetic_energy(s.pbd.model, s.pbd.data) < 1e-3 * std::max(energy, 1e-9));
    CHECK(count_nonfinite(s.pbd.model, s.pbd.data) == 0);
  }

  TEST_CASE("a hanging block cut through falls with g below the cut while the top stays") {
    Scene s;
    make_scene(s, 32, 8, hanging(0.9));
    for (int i = 0; i < 30; ++i) pbd_step(s.cut, s.pbd.model, s.pbd.data);
    const double y_cut = 0.1137;
    horizontal_cut(s, y_cut, -1.0, 1.0, 10);
    CHECK(surface_stats(compact_surface(s.cut.surface)).components == 2);
    // Measure the fall of the lower piece over the next steps: y(t) = y0 + v0 t - g t^2 / 2.
    const double dt = s.pbd.model.params.dt;
    std::vector<double> ys;
    const double top_before = centre_below(s.pbd, 5.0).y();
    for (int i = 0; i <= 30; ++i) {
      ys.push_back(centre_below(s.pbd, y_cut - 0.3).y());
      pbd_step(s.cut, s.pbd.model, s.pbd.data);
    }
    // Second difference (after the first few steps) gives the acceleration.
    const double a = (ys[30] - 2 * ys[20] + ys[10]) / (100 * dt * dt);
    CHECK(std::abs(a + 9.81) < 0.05 * 9.81);
    // The top (anchored) part stays: particles above the cut move little.
    Vec3d top = Vec3d::Zero();
    double m = 0.0;
    for (size_t p = 0; p < s.pbd.data.position.size(); ++p) {
      if (s.pbd.model.refs[p] == 0 || s.pbd.model.rest[p].y() < y_cut + 0.3) continue;
      top += s.pbd.model.mass[p] * (s.pbd.data.position[p] - s.pbd.model.rest[p]);
      m += s.pbd.model.mass[p];
    }
    CHECK((top / m).norm() < 0.05);
    (void)top_before;
  }

  TEST_CASE("a cut stopped halfway: the piece hangs, the slit opens at its mouth and stays closed beyond the front") {
    Scene s;
    PbdParams soft = hanging(0.9);  // soft tissue, so the hinge visibly opens
    soft.stretch_compliance = 1e-4;
    soft.shape_stiffness = 0.2;
    make_scene(s, 32, 8, soft);
    const double y_cut = 0.1137;
    horizontal_cut(s, y_cut, -1.0, 0.02, 12);  // from x = -0.5 (mouth) to just past the middle
    CHECK(surface_stats(compact_surface(s.cut.surface)).components == 1);
    for (int i = 0; i < 240; ++i) pbd_step(s.cut, s.pbd.model, s.pbd.data);
    CHECK(count_nonfinite(s.pbd.model, s.pbd.data) == 0);
    // The lower part still hangs: it did not fall away.
    CHECK(centre_below(s.pbd, y_cut - 0.3).y() > -1.5);
    // Duplicated particles (same rest position): apart near the mouth, none beyond the front.
    double mouth_gap = 0.0;
    int beyond_front_duplicates = 0;
    for (size_t p = 0; p < s.pbd.data.position.size(); ++p) {
      if (s.pbd.model.refs[p] == 0) continue;
      for (size_t q = p + 1; q < s.pbd.data.position.size(); ++q) {
        if (s.pbd.model.refs[q] == 0 || (s.pbd.model.rest[p] - s.pbd.model.rest[q]).norm() > 1e-12) continue;
        if (s.pbd.model.rest[p].x() < -0.3)
          mouth_gap = std::max(mouth_gap, (s.pbd.data.position[p] - s.pbd.data.position[q]).norm());
        if (s.pbd.model.rest[p].x() > 0.3) ++beyond_front_duplicates;
      }
    }
    CHECK(mouth_gap > 0.01);
    CHECK(beyond_front_duplicates == 0);
  }

  TEST_CASE("hard cases stay finite with bounded energy") {
    SUBCASE("zero compliance") {
      Scene s;
      PbdParams p = hanging(0.9);
      p.stretch_compliance = 0.0;
      make_scene(s, 16, 4, p);
      for (int i = 0; i < 200; ++i) pbd_step(s.cut, s.pbd.model, s.pbd.data);
      CHECK(count_nonfinite(s.pbd.model, s.pbd.data) == 0);
      CHECK(kinetic_energy(s.pbd.model, s.pbd.data) < 1e3);
    }
    SUBCASE("dt = 1/30 with one iteration") {
      Scene s;
      PbdParams p = hanging(0.9);
      p.dt = 1.0 / 30.0;
      p.iterations = 1;
      make_scene(s, 16, 4, p);
      for (int i = 0; i < 300; ++i) pbd_step(s.cut, s.pbd.model, s.pbd.data);
      CHECK(count_nonfinite(s.pbd.model, s.pbd.data) == 0);
      CHECK(kinetic_energy(s.pbd.model, s.pbd.data) < 1e3);
    }
    SUBCASE("a one-voxel fragment cut loose falls freely") {
      Scene s;
      make_scene(s, 16, 8, hanging(0.9));
      // Cut the bottom corner of the block off with a small oblique blade.
      const Vec3d corner(-0.5, -1.0, -0.5);
      const double h = s.model.lattice.voxel_size;
      const Vec3d c = corner + Vec3d::Constant(0.9 * h);
      const Vec3d n = Vec3d(1, 1, 1).normalized(), u = Vec3d(1, -1, 0).normalized(), w = n.cross(u);
      cut(s, {c - 3 * h * u - 3 * h * w, c + 3 * h * u - 3 * h * w}, {c - 3 * h * u + 3 * h * w, c + 3 * h * u + 3 * h * w}, 4);
      CHECK(surface_stats(compact_surface(s.cut.surface)).components == 2);
      for (int i = 0; i < 120; ++i) pbd_step(s.cut, s.pbd.model, s.pbd.data);
      CHECK(count_nonfinite(s.pbd.model, s.pbd.data) == 0);
      CHECK(kinetic_energy(s.pbd.model, s.pbd.data) < 1e4);
    }
    SUBCASE("a simulation voxel squashed flat and one inverted by a grab") {
      Scene s;
      make_scene(s, 16, 4, hanging(0.9));
      grab_begin(s.pbd.model, s.pbd.data, Vec3d(0.5, -1.0, 0.5), 1e-6);
      // Drag the bottom corner up through the block and beyond its top (inverts the clusters on the way).
      for (int i = 0; i <= 120; ++i) {
        grab_move(s.pbd.data, Vec3d(0.5, -1.0 + 3.0 * i / 120, 0.5));
        pbd_step(s.cut, s.pbd.model, s.pbd.data);
        CHECK(count_nonfinite(s.pbd.model, s.pbd.data) == 0);
      }
      grab_end(s.pbd.data);
      for (int i = 0; i < 300; ++i) pbd_step(s.cut, s.pbd.model, s.pbd.data);
      CHECK(count_nonfinite(s.pbd.model, s.pbd.data) == 0);
      CHECK(kinetic_energy(s.pbd.model, s.pbd.data) < 1e4);
    }
  }

  TEST_CASE("one and two workers give bit-identical results") {
    Scene a, b;
    make_scene(a, 24, 6, hanging(0.9));
    make_scene(b, 24, 6, hanging(0.9));
    ThreadRunner two;
    b.pbd.data.chunk_work = 1;  // every batch split across the two threads (a scene this small runs on one otherwise)
    horizontal_cut(a, 0.137, -1.0, 0.2, 8);
    horizontal_cut(b, 0.137, -1.0, 0.2, 8);
    for (int i = 0; i < 60; ++i) {
      pbd_step(a.cut, a.pbd.model, a.pbd.data);
      pbd_step(b.cut, b.pbd.model, b.pbd.data, two.runner());
    }
    CHECK(two.splits > 1000);
    CHECK(particle_hash(a.pbd) == particle_hash(b.pbd));
    CHECK(a.pbd.data.deformed == b.pbd.data.deformed);
  }
  // The solver keeps its constraint blocks and the embedding's rows between steps and rebuilds them
  // when a cut changes the model (PbdModel::revision) or the surface (CutState::steps): stepping
  // through cuts with the kept ones must equal rebuilding them before every step.
  TEST_CASE("the solver's kept constraint blocks follow the model through cuts") {
    Scene a, b;
    make_scene(a, 24, 6, hanging(0.9));
    make_scene(b, 24, 6, hanging(0.9));
    const double x[] = {-1.0, -0.4, 0.1, 0.6, 1.1};
    for (int segment = 0; segment + 1 < 5; ++segment) {
      horizontal_cut(a, 0.137, x[segment], x[segment + 1], 2);
      horizontal_cut(b, 0.137, x[segment], x[segment + 1], 2);
      for (int i = 0; i < 10; ++i) {
        pbd_step(a.cut, a.pbd.model, a.pbd.data);
        b.pbd.data.cache.blocks_revision = b.pbd.data.cache.embed_revision = ~uint64_t(0);  // force a rebuild
        pbd_step(b.cut, b.pbd.model, b.pbd.data);
        CHECK(a.pbd.data.deformed == b.pbd.data.deformed);
      }
    }
    CHECK(a.pbd.model.revision > 1);  // the cuts changed the model
    CHECK(particle_hash(a.pbd) == particle_hash(b.pbd));
    CHECK(a.pbd.data.deformed == b.pbd.data.deformed);
  }
  TEST_CASE("a blade in world space cuts a block that has fallen away from its rest place") {
    // The product's step (world_step): the block falls, is stopped where it is, and a blade at its
    // current middle is mapped to rest space through the deformed pieces and cuts it.
    dvx_test::WorldScene w;
    PbdParams free_fall;
    free_fall.damping = 0.0;
    const TriMesh box = make_box(Vec3d(0.0013, 0.0021, 0.0007), Vec3d(0.5, 1.0, 0.5), Eigen::Matrix3d::Identity(), 1);
    dvx_test::make_world(w, box, 24, 6, free_fall);
    for (int i = 0; i < 30; ++i) world_step(w.model, w.state, StepCommands(), StepContext());  // falls about 1.2
    const double drop = centre_below(w.pbd(), 5.0).y();
    REQUIRE(drop < -1.0);
    // Stopped there (no gravity, no velocity), so the blade's plane stays at its middle.
    w.pbd().model.params.gravity = Vec3d::Zero();
    for (Vec3d& v : w.pbd().data.velocity) v.setZero();
    const double y = drop + 0.0137;
    BladePose previous{Vec3d(-1.0, y, -2), Vec3d(-1.0, y, 2)};
    for (int i = 1; i <= 10; ++i) {
      const double x = -1.0 + 2.0 * i / 10;
      const BladePose next{Vec3d(x, y, -2), Vec3d(x, y, 2)};
      dvx_test::world_cut_step(w.model, w.state, previous, next);
      std::string error;
      REQUIRE_MESSAGE(check_cut_state(w.voxels(), w.state.cut, error), error);
      REQUIRE_MESSAGE(check_pbd_state(w.voxels(), w.state.cut, w.pbd().model, w.pbd().data, error), error);
      previous = next;
    }
    CHECK(surface_stats(compact_surface(w.state.cut.surface)).components == 2);
  }
}

TEST_SUITE("pbd") {
  TEST_CASE("two shells closer than one simulation voxel are not welded: the free one falls freely") {
    Scene s;
    const TriMesh shells = merge_meshes(make_box(Vec3d(-0.55, 0.0013, 0.0007), Vec3d(0.45, 0.5, 0.5), Eigen::Matrix3d::Identity(), 1),
                                        make_box(Vec3d(0.55, 0.0013, 0.0007), Vec3d(0.45, 0.5, 0.5), Eigen::Matrix3d::Identity(), 1));
    VoxelizeParams vp;
    vp.resolution = 32;
    std::string error;
    REQUIRE(voxelize(shells, vp, s.model, error));
    init_cut_state(s.model, s.cut);
    PbdParams p;
    p.resolution = 32;
    p.sim_resolution = 4;  // simulation voxels of 0.5: the 0.2 gap lies inside one
    p.damping = 0.0;
    Aabb left;
    left.grow(Vec3d(-5, -5, -5));
    left.grow(Vec3d(-0.75, 5, 5));
    p.fixed.push_back(left);
    REQUIRE(init_pbd(s.model, s.cut, p, s.pbd.model, s.pbd.data, error));
    REQUIRE(s.pbd.model.sim_size > 0.2);
    REQUIRE_MESSAGE(check_pbd_state(s.model, s.cut, s.pbd.model, s.pbd.data, error), error);
    const int steps = 60;
    for (int i = 0; i < steps; ++i) pbd_step(s.cut, s.pbd.model, s.pbd.data);
    // Mean drop of each shell's surface vertices.
    double drop[2] = {0, 0};
    int count[2] = {0, 0};
    for (size_t v = 0; v < s.cut.surface.positions.size(); ++v) {
      if (s.cut.surface.vertex_piece[v] == CutSurface::kFreeKey) continue;
      const int side = s.cut.surface.positions[v].x() > 0.0f;
      drop[side] += double(s.cut.surface.positions[v].y() - s.pbd.data.deformed[v].y());
      ++count[side];
    }
    const double t = steps * p.dt, expected = 0.5 * 9.81 * t * t;
    CHECK(drop[0] / count[0] < 0.05);
    CHECK(std::abs(drop[1] / count[1] - expected) < 0.05 * expected);
  }
}

TEST_SUITE("pbd") {
  TEST_CASE("damping removes the same fraction of velocity per time step whatever the substeps") {
    // A free block gliding without gravity: the constraints hold (rigid motion), only damping acts.
    for (int substeps : {1, 2, 5}) {
      CAPTURE(substeps);
      PbdParams params;
      params.gravity = Vec3d::Zero();
      params.damping = 0.1;
      params.substeps = substeps;
      Scene s;
      make_scene(s, 16, 4, params);
      for (size_t p = 0; p < s.pbd.data.position.size(); ++p) s.pbd.data.velocity[p] = Vec3d(1.0, 0.0, 0.0);
      pbd_step(s.cut, s.pbd.model, s.pbd.data);
      pbd_step(s.cut, s.pbd.model, s.pbd.data);
      double worst = 0.0;
      for (size_t p = 0; p < s.pbd.data.position.size(); ++p) {
        if (s.pbd.model.refs[p] == 0) continue;
        worst = std::max(worst, (s.pbd.data.velocity[p] - Vec3d(0.81, 0.0, 0.0)).norm());
      }
      CHECK(worst < 1e-9);
    }
  }

  TEST_CASE("one and two workers give bit-identical results with substeps and contact") {
    // Several substeps and a tray: every kind of batch in the step's job runs through the runner;
    // the paper's constraints, then the material's hexahedra.
    for (const bool material : {false, true}) {
      CAPTURE(material);
      PbdParams params = hanging(0.9);
      params.substeps = 3;
      params.iterations = 3;
      params.planes.push_back(ContactPlane{Vec3d(0.0, -1.3, 0.0), Vec3d::UnitY(), 0.5, 0.5});
      if (material) {
        params.elastic = ElasticModel::kNeoHookean;
        params.youngs_modulus = 2e4;
        params.poisson_ratio = 0.45;
        params.density = 1000.0;
      }
      // a: one thread, colour by colour; b: two threads, every colour's batch split; c: two threads,
      // the two bodies (the hanging part and the one that falls) solved side by side (PbdCache::halves).
      Scene a, b, c;
      for (Scene* s : {&a, &b, &c}) {
        make_scene(*s, 24, 6, params);
        horizontal_cut(*s, 0.137, -1.0, 1.0, 8);  // the lower part falls onto the tray
        grab_begin(s->pbd.model, s->pbd.data, Vec3d(0.4, 0.9, 0.4), 1e-4);
        grab_move(s->pbd.data, Vec3d(0.6, 1.0, 0.4));
      }
      a.pbd.data.body_halves = b.pbd.data.body_halves = false;
      ThreadRunner two, halves;
      b.pbd.data.chunk_work = 1;  // every batch split across the two threads
      for (int i = 0; i < 60; ++i) {
        pbd_step(a.cut, a.pbd.model, a.pbd.data);
        pbd_step(b.cut, b.pbd.model, b.pbd.data, two.runner());
        pbd_step(c.cut, c.pbd.model, c.pbd.data, halves.runner());
      }
      CHECK(a.pbd.data.contacts.points.size() > 0);
      CHECK(two.splits > 1000);
      CHECK(particle_hash(a.pbd) == particle_hash(b.pbd));
      CHECK(a.pbd.data.deformed == b.pbd.data.deformed);
      REQUIRE(c.pbd.data.cache.halves_on);
      CHECK(halves.splits >= 60 * 3 * 3);  // each substep's iterations, at least
      CHECK(particle_hash(a.pbd) == particle_hash(c.pbd));
      CHECK(a.pbd.data.deformed == c.pbd.data.deformed);
    }
  }
}
