// A stroke takes a piece off (issue 29): a blade whose world-swept surface spans the cross-section of
// tissue that moves and deforms while it is cut (sagging under gravity, bent, stretched or twisted by
// the grab, in motion) severs it, over 1 to 40 steps, and the cut faces lie on the swept surface.
// Every path of material from one side of the swept surface to the other crosses it: a body still in
// one piece afterwards has gaps in its cut.
#include "sim/cut.h"
#include "sim/pbd.h"
#include "sim/random.h"
#include "sim/shapes.h"
#include "sim/surface_metrics.h"
#include "sim/world.h"

#include "fixtures.h"

#include <doctest/doctest.h>

#include <algorithm>
#include <fstream>
#include <map>
#include "sim/union_find.h"
#include <sstream>
#include <cmath>
#include <functional>
#include <set>
#include <tuple>

using namespace dvx;

namespace {

using Body = dvx_test::WorldScene;

Aabb box_of(const Vec3d& lo, const Vec3d& hi) {
  Aabb a;
  a.grow(lo);
  a.grow(hi);
  return a;
}

int components(const Body& b) { return int(surface_stats(compact_surface(b.state.cut.surface)).components); }

// A cut triangle's rest corners (how a face is known again after a step: slots are reused).
using FaceKey = std::array<float, 9>;
FaceKey face_key(const CutSurface& s, size_t t) {
  FaceKey k;
  for (int c = 0; c < 3; ++c) {
    for (int a = 0; a < 3; ++a) k[size_t(3 * c + a)] = s.positions[s.triangles[t][size_t(c)]][a];
  }
  return k;
}

// What a sweep did.
struct SweepResult {
  int components = 0;
  uint32_t edges_cut = 0;
  std::vector<double> distance;  // new cut faces' distance from the step's swept plane (fine voxels)
  double p95() {
    if (distance.empty()) return 1e30;
    std::sort(distance.begin(), distance.end());
    return distance[size_t(0.95 * double(distance.size() - 1))];
  }
};

// Sweeps the blade from `from` to `to` in `steps` world steps (the grab's command of each step from
// `grab`, when given), with the state checks after each step. The faces a step cuts are measured
// against the plane the blade moves in (through from.a, spanned by the blade and its motion), at the
// deformation they were cut in.
SweepResult sweep(Body& b, const BladePose& from, const BladePose& to, int steps,
                  const std::function<GrabCommand(int)>& grab = nullptr) {
  SweepResult r;
  const Vec3d normal = (from.b - from.a).cross(to.a - from.a).normalized();
  std::set<FaceKey> seen;
  {
    const CutSurface& s = b.state.cut.surface;
    for (size_t t = 0; t < s.triangles.size(); ++t) {
      if (s.triangles[t][0] != kDeadIndex && s.triangle_cut[t]) seen.insert(face_key(s, t));
    }
  }
  // The blade is placed at `from` (not cutting), then each step sweeps and cuts.
  StepCommands place;
  place.has_blade = true;
  place.blade = from;
  place.cutting = false;
  StepContext context;
  world_step(b.model, b.state, place, context);
  for (int i = 1; i <= steps; ++i) {
    const double f = double(i) / steps;
    StepCommands c;
    c.has_blade = true;
    c.blade = {from.a + f * (to.a - from.a), from.b + f * (to.b - from.b)};
    c.cutting = true;
    if (grab) c.grab = grab(i);
    // The step, with the faces it cuts measured at the deformation they are cut in (after the cut,
    // before the dynamics move them).
    struct Measure {
      std::set<FaceKey>* seen;
      SweepResult* r;
      Vec3d normal, origin;
    } measure{&seen, &r, normal, from.a};
    StepContext cut_context = context;
    cut_context.after_cut_user = &measure;
    cut_context.after_cut = [](const WorldModel& model, WorldState& state, void* user) {
      Measure& m = *static_cast<Measure*>(user);
      world_embed(model, state);
      const CutSurface& s = state.cut.surface;
      for (size_t t = 0; t < s.triangles.size(); ++t) {
        if (s.triangles[t][0] == kDeadIndex || !s.triangle_cut[t]) continue;
        if (!m.seen->insert(face_key(s, t)).second) continue;
        Vec3d centre = Vec3d::Zero();
        for (uint32_t v : s.triangles[t]) centre += state.pbd->data.deformed[v].cast<double>() / 3.0;
        m.r->distance.push_back(std::abs(m.normal.dot(centre - m.origin)) / state.pbd->model.fine_size);
      }
    };
    StepReport report;
    world_step(b.model, b.state, c, cut_context, &report);
    r.edges_cut += report.cut.edges_cut;
    std::string error;
    REQUIRE_MESSAGE(check_cut_state(b.voxels(), b.state.cut, error), error);
    REQUIRE_MESSAGE(check_pbd_state(b.voxels(), b.state.cut, b.pbd().model, b.pbd().data, error), error);
  }
  // The stroke ends (the blade lifted, as on a mouse release): its seams close, its voxels are let go.
  CHECK(!b.state.stroke_voxels.empty());
  StepCommands lift;
  lift.has_blade = true;
  lift.blade = to;
  world_step(b.model, b.state, lift, context);
  CHECK(b.state.stroke_voxels.empty());
  std::string error;
  REQUIRE_MESSAGE(check_cut_state(b.voxels(), b.state.cut, error), error);
  r.components = components(b);
  return r;
}

// A bar 1 x 2 x 1 (times `scale`) standing along y, anchored at its top tenth.
void hanging_bar(Body& b, double scale, double gravity, int resolution = 32, int sim = 8) {
  PbdParams p;
  p.fixed.push_back(box_of(Vec3d(-5, 0.9, -5) * scale, Vec3d(5, 5, 5) * scale));
  p.gravity = Vec3d(0.0, -gravity, 0.0);
  p.damping = 0.01;
  dvx_test::make_world(b, make_box(Vec3d(0.0013, 0.0021, 0.0007) * scale, Vec3d(0.5, 1.0, 0.5) * scale,
                                   Eigen::Matrix3d::Identity(), 1),
                       resolution, sim, p);
}

// Lets the body move for `steps` steps without a blade.
void settle(Body& b, int steps) {
  StepContext context;
  for (int i = 0; i < steps; ++i) world_step(b.model, b.state, StepCommands(), context);
}

// A horizontal blade along z at height y, swept across x from -x_reach to x_reach.
BladePose blade_at(double x, double y, double half) { return {Vec3d(x, y, -half), Vec3d(x, y, half)}; }

}  // namespace

TEST_SUITE("sever") {
  TEST_CASE("a world that embeds its surface only now and then shows what one that embeds every step shows") {
    // The window embeds the surface only for the snapshots the renderer takes (embed_surface false,
    // world_embed before publishing); the steps between keep the embedding's rows following the cut.
    // At every third step of a stroke that severs the bar and of the rest after it, every live
    // vertex must be where the world that embeds every step has it, to the bit.
    Body every, sometimes;
    hanging_bar(every, 1.0, 50);
    hanging_bar(sometimes, 1.0, 50);
    StepContext on, off;
    off.embed_surface = false;
    const BladePose from = blade_at(-1.2, -0.2137, 2.0), to = blade_at(1.2, -0.2137, 2.0);
    uint32_t compared = 0;
    for (int i = 0; i <= 24; ++i) {
      StepCommands c;
      c.has_blade = i <= 13;
      c.cutting = i > 0 && i <= 12;
      const double f = std::min(1.0, double(i) / 12);
      c.blade = {from.a + f * (to.a - from.a), from.b + f * (to.b - from.b)};
      world_step(every.model, every.state, c, on);
      world_step(sometimes.model, sometimes.state, c, off);
      if (i % 3 != 2) continue;
      world_embed(sometimes.model, sometimes.state);
      const CutSurface& s = sometimes.state.cut.surface;
      REQUIRE(every.pbd().data.deformed.size() >= s.positions.size());
      REQUIRE(sometimes.pbd().data.deformed.size() >= s.positions.size());
      uint32_t differ = 0;
      for (size_t v = 0; v < s.positions.size(); ++v) {
        if (s.vertex_piece[v] == CutSurface::kFreeKey) continue;
        differ += every.pbd().data.deformed[v] != sometimes.pbd().data.deformed[v];
        ++compared;
      }
      CHECK(differ == 0);
    }
    CHECK(compared > 1000);
    CHECK(components(sometimes) == 2);
  }

  TEST_CASE("a bar hanging under gravity is severed by a sweep across it, in 1 to 40 steps") {
    struct Case {
      double gravity;
      int settle, steps;
    };
    for (const Case c : {Case{9.81, 0, 1}, Case{50, 6, 3}, Case{50, 0, 9}, Case{200, 3, 20}, Case{200, 10, 40},
                         Case{50, 20, 40}, Case{9.81, 5, 20}}) {
      CAPTURE(c.gravity);
      CAPTURE(c.settle);
      CAPTURE(c.steps);
      Body b;
      hanging_bar(b, 1.0, c.gravity);
      settle(b, c.settle);
      SweepResult r = sweep(b, blade_at(-1.2, -0.2137, 2.0), blade_at(1.2, -0.2137, 2.0), c.steps);
      const double p95 = r.p95();
      MESSAGE("g " << c.gravity << " steps " << c.steps << ": components " << r.components << ", edges " << r.edges_cut
                   << ", new faces p95 " << p95 << " fine voxels");
      CHECK(r.components == 2);
      CHECK(p95 <= 1.0);
    }
  }

  TEST_CASE("a 0.2-unit body under 9.81 is severed") {
    for (int steps : {1, 9, 40}) {
      CAPTURE(steps);
      Body b;
      hanging_bar(b, 0.1, 9.81);
      settle(b, 4);
      SweepResult r = sweep(b, blade_at(-0.12, -0.02137, 0.2), blade_at(0.12, -0.02137, 0.2), steps);
      MESSAGE("0.2-unit body, steps " << steps << ": components " << r.components << ", p95 " << r.p95());
      CHECK(r.components == 2);
      CHECK(r.p95() <= 1.0);
    }
  }

  // A bar 3 x 0.5 x 0.5 along x, anchored at x < -1.3, without gravity, deformed by the grab.
  void grab_bar(Body& b, int resolution = 32, int sim = 8) {
    PbdParams p;
    p.fixed.push_back(box_of(Vec3d(-5, -5, -5), Vec3d(-1.3, 5, 5)));
    p.gravity = Vec3d::Zero();
    p.shape_stiffness = 0.2;
    p.stretch_compliance = 1e-4;
    p.damping = 0.05;
    dvx_test::make_world(b, make_box(Vec3d(0.0013, 0.0021, 0.0007), Vec3d(1.5, 0.25, 0.25), Eigen::Matrix3d::Identity(), 1),
                         resolution, sim, p);
  }

  GrabCommand grab_to(const Vec3d& target, double compliance = 1e-7) {
    GrabCommand g;
    g.kind = GrabCommand::kTarget;
    g.target = target;
    g.compliance = compliance;
    return g;
  }

  // Steps the world with the grab's commands of `grab(step)`.
  void drive(Body& b, int steps, const std::function<GrabCommand(int)>& grab) {
    StepContext context;
    for (int i = 0; i < steps; ++i) {
      StepCommands c;
      c.grab = grab(i);
      world_step(b.model, b.state, c, context);
    }
  }

  TEST_CASE("a bar bent by the grab is severed by a sweep across it, in 1 to 20 steps") {
    for (int steps : {1, 9, 20}) {
      CAPTURE(steps);
      Body b;
      grab_bar(b, 48, 12);
      // Drag the free end along a quarter circle about the anchored end: a 90 degree bend, held.
      const double radius = 2.0 * 2.8 / M_PI;
      const Vec3d centre(-1.3, radius, 0.0);
      const auto target = [&](int i) {
        if (i == 0) return grab_to(Vec3d(1.5, 0.0, 0.0));  // takes the free end
        const double angle = 0.5 * M_PI * std::min(i, 150) / 150.0;
        return grab_to(centre + radius * Vec3d(std::sin(angle), -std::cos(angle), 0.0));
      };
      drive(b, 210, target);
      REQUIRE(b.pbd().data.position[b.pbd().data.grab_particles.at(0)].y() > 1.2);  // bent: the end points up
      // A horizontal blade at y = 1 swept across the bar while the grab holds it bent.
      SweepResult r = sweep(b, blade_at(-2.0, 1.0137, 1.0), blade_at(2.0, 1.0137, 1.0), steps,
                            [&](int) { return target(210); });
      MESSAGE("bent bar, steps " << steps << ": components " << r.components << ", p95 " << r.p95());
      CHECK(r.components == 2);
      CHECK(r.p95() <= 1.0);
    }
  }

  TEST_CASE("a bar stretched by the grab is severed, also while it is pulled") {
    for (int steps : {1, 9, 40}) {
      CAPTURE(steps);
      Body b;
      grab_bar(b);
      // Pull the free end out by 1.5 (half the bar's length), then keep pulling during the sweep.
      const auto target = [&](int i) { return grab_to(Vec3d(1.5 + 0.015 * std::min(i, 100) + 0.005 * std::max(0, i - 100), 0.0, 0.0)); };
      drive(b, 100, target);
      const double span = b.pbd().data.position[b.pbd().data.grab_particles.at(0)].x() + 1.5;
      MESSAGE("stretched to " << span / 3.0 << " x");
      // A vertical blade along z at x = 0.4 swept down across the bar, the grab still pulling.
      const BladePose from{Vec3d(0.4137, 1.0, -1.0), Vec3d(0.4137, 1.0, 1.0)};
      const BladePose to{Vec3d(0.4137, -1.0, -1.0), Vec3d(0.4137, -1.0, 1.0)};
      SweepResult r = sweep(b, from, to, steps, [&](int i) { return target(100 + i); });
      MESSAGE("stretched bar, steps " << steps << ": components " << r.components << ", p95 " << r.p95());
      CHECK(r.components == 2);
      CHECK(r.p95() <= 1.0);
    }
  }

  TEST_CASE("a bar twisted by several grabs in turn is severed while they twist it") {
    for (int steps : {3, 20, 40}) {
      CAPTURE(steps);
      Body b;
      grab_bar(b);
      // Each grab takes a corner of the free end and turns it about the bar's axis; every 10 steps
      // the grab lets go and the next corner is taken (four in turn).
      const auto twist = [&](int i) {
        const int phase = i % 10;
        GrabCommand g;
        if (phase == 9) {
          g.kind = GrabCommand::kRelease;
          return g;
        }
        const int corner = (i / 10) % 4;
        const double start = 0.25 * M_PI + 0.5 * M_PI * corner;
        const double angle = start + 0.9 * M_PI * 0.5 * phase / 8.0;
        const double r = 0.25 * std::sqrt(2.0);
        return grab_to(Vec3d(1.5, r * std::cos(angle), r * std::sin(angle)), 1e-6);
      };
      drive(b, 25, twist);
      const BladePose from{Vec3d(0.4137, 1.0, -1.0), Vec3d(0.4137, 1.0, 1.0)};
      const BladePose to{Vec3d(0.4137, -1.0, -1.0), Vec3d(0.4137, -1.0, 1.0)};
      SweepResult r = sweep(b, from, to, steps, [&](int i) { return twist(25 + i); });
      MESSAGE("twisted bar, steps " << steps << ": components " << r.components << ", p95 " << r.p95());
      CHECK(r.components == 2);
      CHECK(r.p95() <= 1.0);
    }
  }

  TEST_CASE("a body in motion through the blade's path is severed, at several speeds") {
    struct Case {
      double speed;
      int steps;
    };
    for (const Case c : {Case{1.0, 1}, Case{1.0, 9}, Case{3.0, 9}, Case{3.0, 20}, Case{6.0, 20}, Case{2.0, 40}}) {
      CAPTURE(c.speed);
      CAPTURE(c.steps);
      Body b;
      PbdParams p;
      p.gravity = Vec3d::Zero();
      p.damping = 0.0;
      dvx_test::make_world(b, make_box(Vec3d(0.0013, 0.0021, 0.0007), Vec3d(0.5, 1.0, 0.5), Eigen::Matrix3d::Identity(), 1), 32, 8, p);
      // The block moves up along y; the blade sweeps across it at a height it passes through while
      // it is swept (the block's middle reaches the blade's height halfway through the sweep).
      for (Vec3d& v : b.pbd().data.velocity) v = Vec3d(0.2, c.speed, 0.0);
      const double t_half = 0.5 * c.steps * b.model.params.dt;
      const double y = 0.0021 + c.speed * t_half + 0.0137;
      SweepResult r = sweep(b, blade_at(-1.2, y, 2.0), blade_at(1.6, y, 2.0), c.steps);
      MESSAGE("moving block, speed " << c.speed << ", steps " << c.steps << ": components " << r.components << ", p95 " << r.p95());
      CHECK(r.components == 2);
      // The material that passed the blade during a step is cut along its path relative to the
      // blade: at cut time those faces lie up to the block's motion in one step off the blade's plane.
      const double motion = c.speed * b.model.params.dt / b.pbd().model.fine_size;
      CHECK(r.p95() <= 1.0 + motion);
    }
  }
}

namespace {

// A shipped organ (assets/meshes, OBJ: v and f lines; f a/b/c takes the vertex index).
TriMesh shipped_organ(const std::string& name) {
  TriMesh mesh;
  std::ifstream in(std::string(DIVVOX_SOURCE_DIR) + "/assets/meshes/" + name);
  REQUIRE_MESSAGE(in.good(), name);
  std::string line;
  while (std::getline(in, line)) {
    std::istringstream s(line);
    std::string kind;
    s >> kind;
    if (kind == "v") {
      Vec3d p;
      s >> p.x() >> p.y() >> p.z();
      mesh.positions.push_back(p);
    } else if (kind == "f") {
      Tri t;
      for (uint32_t& v : t) {
        std::string word;
        s >> word;
        v = uint32_t(std::stoul(word.substr(0, word.find('/')))) - 1;
      }
      mesh.triangles.push_back(t);
    }
  }
  return mesh;
}

}  // namespace

TEST_SUITE("sever") {
  TEST_CASE("no crumbs: smooth strokes on the shipped organs leave no component smaller than a fine voxel") {
    for (const char* name : {"bunny_npm.obj", "liver_sofa_smooth.obj"}) {
      CAPTURE(name);
      const TriMesh mesh = shipped_organ(name);
      const VoxelModel model = dvx_test::voxelized(mesh, 48);
      const Aabb box = mesh_bounds(mesh);
      const Vec3d lo = box.min, size = box.extent();
      const double h = model.lattice.voxel_size;
      CutState state;
      init_cut_state(model, state);
      // Strokes: blades along z across the organ, each swept in 12 steps from one side to partway
      // (a slit) or through, at heights and tilts that graze the surface in many places.
      uint32_t strokes = 0;
      for (int s = 0; s < 8; ++s) {
        const double y = lo.y() + size.y() * (0.15 + 0.1 * s) + 0.0137 * h;
        const double tilt = 0.2 * (s % 3 - 1);
        const double reach = s % 2 ? 1.1 : 0.6;  // through, or a slit
        const BladePose from{Vec3d(lo.x() - 0.1 * size.x(), y, lo.z() - 0.1 * size.z()),
                             Vec3d(lo.x() - 0.1 * size.x(), y + tilt * size.z(), lo.z() + 1.1 * size.z())};
        const BladePose to{from.a + Vec3d(reach * size.x(), 0.05 * size.y(), 0.0),
                           from.b + Vec3d(reach * size.x(), 0.05 * size.y(), 0.0)};
        dvx_test::sweep_steps(model, state, from, to, 12, [](int) {});
        ++strokes;
      }
      std::string error;
      REQUIRE_MESSAGE(check_cut_state(model, state, error), error);
      const std::vector<double> volumes = component_volumes(compact_surface(state.surface));
      const double smallest = *std::min_element(volumes.begin(), volumes.end());
      // No one-node components (8-vertex closed bits: a node cut from all its neighbours).
      const SurfaceMesh m = compact_surface(state.surface);
      std::vector<uint32_t> parent(m.positions.size());
      for (uint32_t v = 0; v < parent.size(); ++v) parent[v] = v;
      for (const Tri& t : m.triangles) {
        uf_unite(parent.data(), t[0], t[1]);
        uf_unite(parent.data(), t[0], t[2]);
      }
      std::map<uint32_t, int> vertices;
      for (uint32_t v = 0; v < parent.size(); ++v) ++vertices[uf_find(parent.data(), v)];
      int one_node = 0;
      for (const auto& [root, n] : vertices) one_node += n <= 8;
      CHECK(one_node == 0);
      MESSAGE(std::string(name) << ": " << strokes << " strokes, " << volumes.size() << " components, smallest " << smallest / (h * h * h)
                   << " fine voxels");
      CHECK(smallest >= h * h * h);
    }
  }

  TEST_CASE("five re-cuts of one slit through deformed tissue add no component") {
    Body b;
    hanging_bar(b, 1.0, 50);
    settle(b, 10);
    // A slit halfway across, then the tissue sags open around it.
    sweep(b, blade_at(-1.2, -0.2137, 2.0), blade_at(-0.1, -0.2137, 2.0), 9);
    settle(b, 10);
    const int before = components(b);
    for (int again = 0; again < 5; ++again) {
      sweep(b, blade_at(-1.2, -0.2137, 2.0), blade_at(-0.1, -0.2137, 2.0), 9);
      settle(b, 5);
      CHECK(components(b) == before);
    }
    const std::vector<double> volumes = component_volumes(compact_surface(b.state.cut.surface));
    const double h = b.pbd().model.fine_size;
    CHECK(*std::min_element(volumes.begin(), volumes.end()) >= h * h * h);
  }
}

TEST_SUITE("sever") {
  TEST_CASE("a hanging bar is severed at any height (fixed seeds)") {
    dvx::SplitMix64 rng{29};
    int severed = 0, runs = 0;
    for (int run = 0; run < 24; ++run) {
      const double y = -0.6 + 1.2 * rng.uniform();
      const double g = run % 2 ? 200.0 : 50.0;
      const int steps = run % 3 == 0 ? 40 : run % 3 == 1 ? 20 : 9;
      CAPTURE(y);
      CAPTURE(g);
      CAPTURE(steps);
      Body b;
      hanging_bar(b, 1.0, g);
      settle(b, run % 5);
      SweepResult r = sweep(b, blade_at(-1.2, y, 2.0), blade_at(1.2, y + 0.1 * (rng.uniform() - 0.5), 2.0), steps);
      ++runs;
      severed += r.components == 2;
      CHECK(r.components == 2);
    }
    MESSAGE(severed << " of " << runs << " severed");
  }
}


// Seams (cut_close_seams): two strips of one stroke that leave a gap a fraction of a voxel wide
// between them (as strips cut through tissue that moved between steps do) keep the block in one
// piece until the stroke ends; its end closes the seam, and a blade tip inside the tissue (a cut that
// does not go through) moves by at most one voxel.
TEST_SUITE("sever") {
  TEST_CASE("the end of a stroke closes a seam between its strips, and leaves a partial cut partial") {
    const TriMesh box = make_box(Vec3d(0.0013, 0.0021, 0.0007), Vec3d(0.5, 0.5, 0.5), Eigen::Matrix3d::Identity(), 1);
    const VoxelModel model = dvx_test::voxelized(box, 32);
    const double h = model.lattice.voxel_size;
    std::vector<uint32_t> stroke;  // the stroke's voxels (as world_step keeps them)
    const auto strip = [&](CutState& s, double x, double y0, double y1, double z_low, double z_high) {
      // A blade along z (from z_high down to z_low) at x, swept in y from y0 to y1.
      CutStepStats stats;
      cut_divide(model, s, {Vec3d(x, y0, z_high), Vec3d(x, y0, z_low)}, {Vec3d(x, y1, z_high), Vec3d(x, y1, z_low)}, stats);
      cut_update_surface(model, s, stats);
      stroke.insert(stroke.end(), s.changed_voxels.begin(), s.changed_voxels.end());
    };
    const auto cut = [&](CutState& s, double y0, double y1, double z_tip) { strip(s, 0.0137, y0, y1, z_tip, 1.0); };
    const auto pieces = [&](const CutState& s) { return int(surface_stats(compact_surface(s.surface)).components); };
    std::string error;
    // The stroke's end: its seams closed and the surface updated (a valid cut state); the closing's counts.
    const auto end_stroke = [&](CutState& s) {
      CutStepStats closing;
      cut_close_seams(model, s, stroke, closing);
      cut_update_surface(model, s, closing);
      REQUIRE_MESSAGE(check_cut_state(model, s, error), error);
      MESSAGE("seam edges cut: " << closing.seam_edges << ", hole edges cut: " << closing.hole_edges);
      return closing;
    };
    SUBCASE("through the block: the seam closes and the block is in two") {
      CutState s;
      init_cut_state(model, s);
      cut(s, -1.0, 0.1 - 0.2 * h, -1.0);  // the first strip ends in the middle of a voxel...
      cut(s, 0.1 + 0.3 * h, 1.0, -1.0);   // ...the second starts half a voxel on
      REQUIRE(check_cut_state(model, s, error));
      CHECK(pieces(s) == 1);  // the seam joins the sides
      CHECK(end_stroke(s).seam_edges > 0);
      CHECK(pieces(s) == 2);
    }
    SUBCASE("a hole 3.2 voxels wide inside the stroke's cut: its end closes the hole and the block is in two") {
      // Four strips around a square the blade never crossed (strips of different directions leave
      // such ragged holes where the tissue turned as it was cut). Closing the partly cut voxels
      // around it narrows it by a voxel from each side and leaves its middle; the hole pass cuts it.
      CutState s;
      init_cut_state(model, s);
      const double y1 = 0.05, y2 = y1 + 3.2 * h, z1 = -0.03, z2 = z1 + 3.2 * h;
      strip(s, 0.0137, -1.0, y1, -1.0, 1.0);
      strip(s, 0.0137, y2, 1.0, -1.0, 1.0);
      strip(s, 0.0137, y1, y2, z2, 1.0);
      strip(s, 0.0137, y1, y2, -1.0, z1);
      REQUIRE(check_cut_state(model, s, error));
      CHECK(pieces(s) == 1);
      CHECK(end_stroke(s).hole_edges > 0);
      CHECK(pieces(s) == 2);
    }
    SUBCASE("two strips offset across a plane of nodes, overlapping by two voxels: its end joins them") {
      // The first strip 0.2 voxel before a plane of nodes, the second 0.2 voxel after it, overlapping
      // in y: the nodes between them join the sides around the overlap's ends (the liver tip's last
      // hairline). Each voxel's own plane runs parallel to both; only the nodes' sides along x show
      // the cut passing between two of them.
      CutState s;
      init_cut_state(model, s);
      const double node_x = model.lattice.node_position(model.lattice.nx / 2, 0, 0).x();
      strip(s, node_x - 0.2 * h, -1.0, 0.0517 + 2.0 * h, -1.0, 1.0);
      strip(s, node_x + 0.2 * h, 0.0517, 1.0, -1.0, 1.0);
      REQUIRE(check_cut_state(model, s, error));
      CHECK(pieces(s) == 1);
      CHECK(end_stroke(s).hole_edges > 0);
      CHECK(pieces(s) == 2);
    }
    SUBCASE("a blade that stops inside the block: still one piece, the cut's edge at most a voxel deeper") {
      CutState s;
      init_cut_state(model, s);
      const double tip = 0.05;  // the block spans z -0.5..0.5: the blade reaches its middle only
      cut(s, -1.0, 1.0, tip);
      end_stroke(s);
      CHECK(pieces(s) == 1);
      // Every cut edge lies above the tip less one voxel.
      double lowest = 1e30;
      for (const EdgeCut& e : s.edge_cuts) {
        int32_t c[3];
        model.lattice.node_coords(e.edge / 3, c);
        lowest = std::min(lowest, model.lattice.node_position(c[0], c[1], c[2]).z());
      }
      MESSAGE("lowest cut edge " << (tip - lowest) / h << " voxels below the tip");
      CHECK(lowest >= tip - 2.0 * h);
    }
  }
}
