// Contact with static planes: the kernel's Coulomb cone, a box dropped on a tray comes to rest with its
// surface on the plane, friction holds it on a slope (and without friction it slides), a piece cut off
// lands, and the result does not depend on the worker count.
#include "sim/contact.h"
#include "sim/cut.h"
#include "sim/pbd.h"
#include "sim/random.h"
#include "sim/shapes.h"
#include "sim/state_hash.h"
#include "sim/voxelize.h"

#include "fixtures.h"

#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <thread>

using namespace dvx;

namespace {

using Scene = dvx_test::PbdScene;
using dvx_test::ThreadRunner;

// A mesh voxelized at resolution 32 (over its longest axis), sim resolution 8.
void make_scene(Scene& s, const TriMesh& mesh, PbdParams params) { dvx_test::make_pbd_scene(s, mesh, 32, 8, params); }

// A box (half extents `half`, rotated by `rotation` about `centre`).
void make_scene(Scene& s, const Vec3d& centre, const Vec3d& half, const Eigen::Matrix3d& rotation, PbdParams params) {
  make_scene(s, make_box(centre, half, rotation, 1), params);
}

ContactPlane plane(const Vec3d& point, const Vec3d& normal, double friction) {
  ContactPlane p;
  p.point = point;
  p.normal = normal.normalized();
  p.static_friction = p.kinetic_friction = friction;
  return p;
}

// Lowest signed distance of the live deformed surface from a plane.
double lowest_surface(const PbdState& s, const ContactPlane& p) {
  double lowest = 1e300;
  for (size_t v = 0; v < s.model.embedding.size(); ++v) {
    if (s.model.embedding[v].sim_voxel != kDeadIndex)
      lowest = std::min(lowest, plane_distance(p, s.data.deformed[v].cast<double>()));
  }
  return lowest;
}

// Mass centre of the live particles.
Vec3d centre(const PbdState& s) {
  Vec3d c = Vec3d::Zero();
  double m = 0.0;
  for (size_t p = 0; p < s.data.position.size(); ++p) {
    c += s.model.mass[p] * s.data.position[p];
    m += s.model.mass[p];
  }
  return c / m;
}

void run(Scene& s, int steps, const TaskRunner& tasks = {}) {
  for (int i = 0; i < steps; ++i) pbd_step(s.cut, s.pbd.model, s.pbd.data, tasks);
}

double fine_voxel(const Scene& s) { return s.model.lattice.voxel_size; }

// Rotation about z by `angle`: maps the box's y axis onto the tilted plane's normal.
Eigen::Matrix3d tilt(double angle) { return Eigen::AngleAxisd(angle, Vec3d::UnitZ()).toRotationMatrix(); }

}  // namespace

TEST_SUITE("contact") {
  TEST_CASE("a contact point sticks inside the friction cone and slides outside it") {
    // One particle, previously on the plane y = 0, now moved sideways by `slide` and down by `sink`.
    const auto after = [](double slide, double sink, double mu_s, double mu_k) {
      double x[3] = {slide, -sink, 0.0};
      const double previous[3] = {0.0, 0.0, 0.0};
      const double inv_mass[1] = {2.0};
      ContactPlane p = plane(Vec3d::Zero(), Vec3d::UnitY(), mu_s);
      p.kinetic_friction = mu_k;
      const uint32_t particles[8] = {};
      const double weights[8] = {1.0};
      ContactPoint c = plane_contact(p, particles, weights);
      for (int it = 0; it < 5; ++it) solve_contact_point(x, previous, inv_mass, c);  // idempotent
      return Vec3d(x[0], x[1], x[2]);
    };
    // Static: friction needed (0.1) <= 0.5 x 0.3: the point stops where it touched.
    CHECK(after(0.1, 0.3, 0.5, 0.4).norm() < 1e-15);
    // Kinetic: 0.5 > 0.5 x 0.3: it slides on, slowed by 0.4 x 0.3.
    const Vec3d sliding = after(0.5, 0.3, 0.5, 0.4);
    CHECK(sliding.y() == doctest::Approx(0.0));
    CHECK(sliding.x() == doctest::Approx(0.5 - 0.4 * 0.3));
    // Frictionless: only the normal part is undone.
    CHECK(after(0.5, 0.3, 0.0, 0.0).x() == doctest::Approx(0.5));
  }

  TEST_CASE("an embedded point is lifted onto the plane through the particles it interpolates") {
    // Two particles (weights 0.25 / 0.75), the second twice as heavy; the point sinks 0.2 below y = 0.
    double x[6] = {0.0, -0.2, 0.0, 1.0, -0.2, 0.0};
    const double previous[6] = {0.0, -0.2, 0.0, 1.0, -0.2, 0.0};
    const double inv_mass[2] = {1.0, 0.5};
    const uint32_t particles[8] = {0, 1};
    const double weights[8] = {0.25, 0.75};
    ContactPoint c = plane_contact(plane(Vec3d::Zero(), Vec3d::UnitY(), 0.0), particles, weights);
    solve_contact_point(x, previous, inv_mass, c);
    // Momentum-like split: particle i moves by w_i / m_i.
    CHECK((x[1] + 0.2) / (x[4] + 0.2) == doctest::Approx((0.25 * 1.0) / (0.75 * 0.5)));
    // The heavier particle would move 1.09 times the point's correction: the lever cap (kMaxLever = 1)
    // under-relaxes the projection, no particle moves farther than the point, and the point converges.
    CHECK(std::max(x[1], x[4]) + 0.2 <= 0.2 * kMaxLever * (1.0 + 1e-12));
    CHECK(0.25 * x[1] + 0.75 * x[4] < 0.0);
    for (int it = 0; it < 20; ++it) solve_contact_point(x, previous, inv_mass, c);
    CHECK(0.25 * x[1] + 0.75 * x[4] == doctest::Approx(0.0).epsilon(1e-12));
    CHECK((x[1] + 0.2) / (x[4] + 0.2) == doctest::Approx((0.25 * 1.0) / (0.75 * 0.5)));
  }

  TEST_CASE("a nearly anchored contact point does not throw its free particles away") {
    // The contact that blew up the 20 000-cut stress test: a vertex on the anchored face of its piece
    // (weights 2.5e-9 on the piece's four free corners, the rest on anchored ones) against a vertex of
    // an anchored piece: W = 4 (2.5e-9)^2 / m ~ 3e-16. An uncapped rigid projection of its 0.0078
    // overlap would move each free corner by w / m / W x 0.0078 = 7.8e5.
    const double depth = 0.0078, eps = 2.5e-9;
    double x[48] = {}, previous[48] = {}, inv_mass[16] = {};
    ContactPoint c;
    for (uint32_t k = 0; k < 16; ++k) c.particles[k] = k;
    for (uint32_t k = 0; k < 8; ++k) c.weights[k] = 0.125;  // the anchored piece's vertex
    for (uint32_t k = 8; k < 16; ++k) {
      const bool free = k % 2 == 1;
      c.weights[k] = free ? -eps : -(0.25 - eps);
      inv_mass[k] = free ? 13.2 : 0.0;
      x[3 * k + 1] = previous[3 * k + 1] = depth;  // the other vertex is `depth` above: C = -depth
    }
    c.normal = Vec3d::UnitY();
    c.target = 0.0;
    c.static_friction = c.kinetic_friction = 0.5;
    ContactPoint plane_point = c;  // the same point against a plane: its 8 particles, 4 of them free
    // Each projection moves no particle farther than the point's overlap (the point itself barely
    // moves: it is nearly anchored, so each iteration asks again).
    const auto largest = [&]() {
      double moved = 0.0;
      for (int i = 0; i < 48; ++i) moved = std::max(moved, std::abs(x[i] - previous[i]));
      return moved;
    };
    solve_contact_point(x, previous, inv_mass, c);
    CHECK(largest() <= kMaxLever * depth * (1.0 + 1e-9));
    for (int it = 1; it < 5; ++it) solve_contact_point(x, previous, inv_mass, c);
    double moved = largest();
    MESSAGE("largest particle correction after 5 iterations " << moved << " (overlap " << depth << ")");
    CHECK(std::isfinite(moved));
    CHECK(moved <= 5.0 * kMaxLever * depth * (1.0 + 1e-9));
    // Against a plane: a surface point on the anchored face of a piece lying a hair below a tray.
    const uint32_t particles[8] = {8, 9, 10, 11, 12, 13, 14, 15};
    double weights[8];
    for (int k = 0; k < 8; ++k) weights[k] = -plane_point.weights[8 + k];
    ContactPoint p = plane_contact(plane(Vec3d(0.0, 2.0 * depth, 0.0), Vec3d::UnitY(), 0.5), particles, weights);
    std::copy(previous, previous + 48, x);
    solve_contact_point(x, previous, inv_mass, p);
    CHECK(largest() <= kMaxLever * depth * (1.0 + 1e-9));
    for (int it = 1; it < 5; ++it) solve_contact_point(x, previous, inv_mass, p);
    moved = largest();
    CHECK(std::isfinite(moved));
    CHECK(moved <= 5.0 * kMaxLever * depth * (1.0 + 1e-9));
  }

  TEST_CASE("a box dropped on a plane comes to rest with its surface on the plane") {
    PbdParams params;
    const ContactPlane tray = plane(Vec3d(0.0, -0.01, 0.0), Vec3d::UnitY(), 0.5);
    params.planes.push_back(tray);
    Scene s;
    make_scene(s, Vec3d(0.003, 0.6, 0.002), Vec3d(0.5, 0.25, 0.5), Eigen::Matrix3d::Identity(), params);
    const double h = fine_voxel(s);
    const double mass = total_mass(s.pbd.model);
    double deepest = 1e300;
    for (int i = 0; i < 180; ++i) {  // 3 s
      pbd_step(s.cut, s.pbd.model, s.pbd.data);
      deepest = std::min(deepest, lowest_surface(s.pbd, tray));
    }
    // At rest: kinetic energy tiny against the energy of the fall (m g 0.35).
    const double fall = mass * 9.81 * 0.35;
    MESSAGE("kinetic energy after 3 s: " << kinetic_energy(s.pbd.model, s.pbd.data) << " J (fall " << fall
                                         << " J); deepest dip " << -deepest / h << " fine voxels; final lowest vertex "
                                         << lowest_surface(s.pbd, tray) / h << " fine voxels");
    CHECK(kinetic_energy(s.pbd.model, s.pbd.data) < 1e-6 * fall);
    // The surface never dips more than half a fine voxel below the plane, and rests on it (does not
    // float on the particles a simulation voxel below the material).
    CHECK(deepest >= -0.5 * h);
    CHECK(lowest_surface(s.pbd, tray) <= 0.5 * h);
    CHECK(count_nonfinite(s.pbd.model, s.pbd.data) == 0);
  }

  TEST_CASE("on a tilted plane friction holds a box, and without friction it slides") {
    const double angle = 20.0 * M_PI / 180.0;  // tan = 0.36
    const Eigen::Matrix3d r = tilt(angle);
    const Vec3d normal = r * Vec3d::UnitY(), downhill = -(r * Vec3d::UnitX());
    const auto slope = [&](double friction, double& moved_last_second, double& speed) {
      PbdParams params;
      params.planes.push_back(plane(Vec3d::Zero(), normal, friction));
      Scene s;
      make_scene(s, Vec3d(0.003, 0.002, 0.001) + (0.25 + 0.02) * normal, Vec3d(0.5, 0.25, 0.5), r, params);
      run(s, 120);  // 2 s
      const Vec3d before = centre(s.pbd);
      run(s, 60);
      moved_last_second = (centre(s.pbd) - before).dot(downhill);
      speed = std::sqrt(2.0 * kinetic_energy(s.pbd.model, s.pbd.data) / total_mass(s.pbd.model));
      return fine_voxel(s);
    };
    double moved = 0.0, speed = 0.0;
    const double h = slope(0.6, moved, speed);
    MESSAGE("friction 0.6: moved " << moved / h << " fine voxels in the third second, speed " << speed);
    CHECK(std::abs(moved) < 0.1 * h);
    // Without friction it slides down at g sin(angle) less the solver's damping: the same recurrence as
    // the integrator (v <- keep (v + a dt), x <- x + dt (v + a dt)) for a free particle on the slope.
    slope(0.0, moved, speed);
    const double a = 9.81 * std::sin(angle), dt = PbdParams{}.dt, keep = 1.0 - PbdParams{}.damping;
    double v = 0.0, x = 0.0, x2 = 0.0;
    for (int i = 0; i < 180; ++i) {
      if (i == 120) x2 = x;
      x += dt * (v + a * dt);
      v = keep * (v + a * dt);
    }
    const double expected = x - x2;
    MESSAGE("friction 0: moved " << moved << " in the third second (damped free slide " << expected << ")");
    CHECK(moved == doctest::Approx(expected).epsilon(0.05));
  }

  TEST_CASE("a piece cut off a hanging block lands on the tray below and comes to rest") {
    PbdParams params;
    Aabb top;
    top.grow(Vec3d(-5, 0.3, -5));
    top.grow(Vec3d(5, 5, 5));
    params.fixed.push_back(top);
    const ContactPlane tray = plane(Vec3d(0.0, -1.5, 0.0), Vec3d::UnitY(), 0.5);
    params.planes.push_back(tray);
    Scene s;
    make_scene(s, Vec3d(0.003, 0.0, 0.002), Vec3d(0.5, 0.5, 0.5), Eigen::Matrix3d::Identity(), params);
    const double h = fine_voxel(s);
    // Cut through horizontally at y = -0.05.
    BladePose previous{Vec3d(-1, -0.05, -2), Vec3d(-1, -0.05, 2)};
    for (int i = 1; i <= 10; ++i) {
      const double x = -1.0 + 2.0 * i / 10;
      const BladePose next{Vec3d(x, -0.05, -2), Vec3d(x, -0.05, 2)};
      cut_step(s.model, s.cut, previous, next);
      pbd_apply_cut(s.model, s.cut, s.pbd.model, s.pbd.data);
      previous = next;
    }
    double deepest = 1e300;
    for (int i = 0; i < 180; ++i) {
      pbd_step(s.cut, s.pbd.model, s.pbd.data);
      deepest = std::min(deepest, lowest_surface(s.pbd, tray));
    }
    MESSAGE("cut piece: kinetic energy " << kinetic_energy(s.pbd.model, s.pbd.data) << " J, deepest dip "
                                         << -deepest / h << " fine voxels");
    CHECK(kinetic_energy(s.pbd.model, s.pbd.data) < 1e-6 * total_mass(s.pbd.model) * 9.81 * 1.0);
    CHECK(deepest >= -0.5 * h);
    CHECK(lowest_surface(s.pbd, tray) <= 0.5 * h);  // it landed (did not hang or stop early)
  }

  TEST_CASE("contact gives bit-identical results with one and two workers") {
    const auto final_hash = [](int workers) {
      PbdParams params;
      const Eigen::Matrix3d r = tilt(0.3);
      params.planes.push_back(plane(Vec3d::Zero(), r * Vec3d::UnitY(), 0.2));
      params.planes.push_back(plane(Vec3d(-0.4, 0, 0), Vec3d(1, 0.2, 0), 0.0));
      Scene s;
      make_scene(s, Vec3d(0.003, 0.4, 0.001), Vec3d(0.5, 0.25, 0.5), Eigen::Matrix3d::Identity(), params);
      ThreadRunner runner{workers};
      s.pbd.data.chunk_work = 1;  // every batch split across the threads
      run(s, 90, workers > 1 ? runner.runner() : TaskRunner{});
      CHECK(s.pbd.data.contacts.points.size() >= 256);  // enough contact points for the parallel path
      CHECK((workers == 1 || runner.splits > 1000));
      Fnv1a f;
      for (const Vec3d& p : s.pbd.data.position) f.bytes(p.data(), 3 * sizeof(double));
      return f.value;
    };
    CHECK(final_hash(1) == final_hash(2));
  }
}

namespace {

// Several boxes voxelized together.
void make_boxes(Scene& s, const std::vector<std::pair<Vec3d, Vec3d>>& boxes, PbdParams params, int resolution = 32) {
  TriMesh mesh;
  for (const auto& [centre, half] : boxes) mesh = merge_meshes(mesh, make_box(centre, half, Eigen::Matrix3d::Identity(), 1));
  dvx_test::make_pbd_scene(s, mesh, resolution, 8, params);
}

// Body of each particle (the connected components of pieces under particle sharing), ~0u: unused.
std::vector<uint32_t> particle_bodies(const PbdState& s) {
  std::vector<uint32_t> corners, body;
  std::vector<uint8_t> live(s.model.pieces.size(), 0);
  for (size_t i = 0; i < s.model.pieces.size(); ++i) {
    live[i] = s.model.pieces[i].sim_voxel != kDeadIndex;
    corners.insert(corners.end(), s.model.pieces[i].particles, s.model.pieces[i].particles + 8);
  }
  PieceContactScratch scratch;
  find_bodies(corners.data(), live.data(), uint32_t(s.model.pieces.size()), uint32_t(s.data.position.size()), body,
              scratch);
  std::vector<uint32_t> of(s.data.position.size(), ~0u);
  for (size_t i = 0; i < s.model.pieces.size(); ++i) {
    if (!live[i]) continue;
    for (uint32_t p : s.model.pieces[i].particles) of[p] = body[i];
  }
  return of;
}

// Mass-weighted velocity and centre of the particles of one body.
void body_motion(const PbdState& s, const std::vector<uint32_t>& of, uint32_t body, Vec3d& centre, Vec3d& velocity) {
  centre.setZero();
  velocity.setZero();
  double m = 0.0;
  for (size_t p = 0; p < s.data.position.size(); ++p) {
    if (of[p] != body) continue;
    centre += s.model.mass[p] * s.data.position[p];
    velocity += s.model.mass[p] * s.data.velocity[p];
    m += s.model.mass[p];
  }
  centre /= m;
  velocity /= m;
}

// The distinct bodies, lowest centre first.
std::vector<uint32_t> bodies_bottom_up(const PbdState& s, const std::vector<uint32_t>& of) {
  std::vector<uint32_t> bodies;
  for (uint32_t b : of) {
    if (b != ~0u && std::find(bodies.begin(), bodies.end(), b) == bodies.end()) bodies.push_back(b);
  }
  std::sort(bodies.begin(), bodies.end(), [&](uint32_t a, uint32_t b) {
    Vec3d ca, cb, v;
    body_motion(s, of, a, ca, v);
    body_motion(s, of, b, cb, v);
    return ca.y() < cb.y();
  });
  return bodies;
}

// The body of a surface vertex slot (that of its piece), ~0u: none.
uint32_t vertex_body(const PbdState& s, const std::vector<uint32_t>& of, uint32_t slot) {
  // The embedding names a simulation voxel and a fine node of the vertex's piece (sim/pbd.h).
  const VertexEmbedding& e = s.model.embedding[slot];
  if (e.sim_voxel == kDeadIndex || s.model.pieces_in_voxel[e.sim_voxel] == 0) return ~0u;
  uint32_t piece = s.model.voxel_piece[e.sim_voxel];
  if (s.model.voxel_divided[e.sim_voxel] != kDeadIndex) {
    const SimDivided& d = s.model.divided[s.model.voxel_divided[e.sim_voxel]];
    const uint8_t label = s.model.labels[d.first_label + e.node];
    piece = label == kNoPiece ? kDeadIndex : s.model.label_slots[d.first_slot + label];
  }
  return piece == kDeadIndex ? ~0u : of[s.model.pieces[piece].particles[0]];
}

// Surface vertices of body `a` inside the closed deformed surface of body `b` (ray parity) by more than
// `depth` (their distance to b's nearest vertex).
uint32_t vertices_inside(const Scene& s, const std::vector<uint32_t>& of, uint32_t a, uint32_t b, double depth) {
  const CutSurface& surface = s.cut.surface;
  std::vector<std::array<Vec3d, 3>> tris;
  std::vector<Vec3d> b_vertices;
  for (uint32_t t = 0; t < surface.triangles.size(); ++t) {
    if (surface.quad_half_edge[t / 2] == CutSurface::kFreeKey) continue;
    const Tri& tri = surface.triangles[t];
    if (vertex_body(s.pbd, of, tri[0]) != b) continue;
    tris.push_back({s.pbd.data.deformed[tri[0]].cast<double>(), s.pbd.data.deformed[tri[1]].cast<double>(),
                    s.pbd.data.deformed[tri[2]].cast<double>()});
  }
  for (uint32_t v = 0; v < s.pbd.model.embedding.size(); ++v) {
    if (vertex_body(s.pbd, of, v) == b) b_vertices.push_back(s.pbd.data.deformed[v].cast<double>());
  }
  const Vec3d dir = Vec3d(1.0, 0.0123, 0.0071).normalized();
  uint32_t inside = 0;
  for (uint32_t v = 0; v < s.pbd.model.embedding.size(); ++v) {
    if (vertex_body(s.pbd, of, v) != a) continue;
    const Vec3d p = s.pbd.data.deformed[v].cast<double>();
    int crossings = 0;
    for (const auto& t : tris) {  // Möller-Trumbore
      const Vec3d e1 = t[1] - t[0], e2 = t[2] - t[0], h = dir.cross(e2);
      const double det = e1.dot(h);
      if (std::abs(det) < 1e-14) continue;
      const Vec3d o = p - t[0];
      const double u = o.dot(h) / det;
      const Vec3d q = o.cross(e1);
      const double w = dir.dot(q) / det;
      if (u < 0.0 || w < 0.0 || u + w > 1.0) continue;
      crossings += e2.dot(q) / det > 0.0;
    }
    if (crossings % 2 == 0) continue;
    double nearest = 1e300;
    for (const Vec3d& q : b_vertices) nearest = std::min(nearest, (q - p).norm());
    inside += nearest > depth;
  }
  return inside;
}

}  // namespace

namespace {

// A block 1 wide at `resolution` / sim 8 settles on a tray, then is cut through horizontally: the
// largest speed (> 0: apart, < 0: sinking in) at which the mean heights of the two sides' cut faces
// part in the 10 steps after the cut, in `worst`.
void cut_separation(bool piece_contact, int substeps, int iterations, int resolution, double& worst) {
  PbdParams params;
  params.piece_contact = piece_contact;
  params.substeps = substeps;
  params.iterations = iterations;
  params.planes.push_back(plane(Vec3d(0.0, -0.52, 0.0), Vec3d::UnitY(), 0.5));
  Scene s;
  make_boxes(s, {{Vec3d(0.003, 0.0, 0.002), Vec3d(0.5, 0.5, 0.5)}}, params, resolution);
  run(s, 180);  // settle on the tray
  // Cut through horizontally (between simulation voxel corners), then watch the two halves.
  BladePose previous{Vec3d(-1, 0.013, -2), Vec3d(-1, 0.013, 2)};
  for (int i = 1; i <= 8; ++i) {
    const double x = -1.0 + 2.0 * i / 8;
    const BladePose next{Vec3d(x, 0.013, -2), Vec3d(x, 0.013, 2)};
    cut_step(s.model, s.cut, previous, next);
    pbd_apply_cut(s.model, s.cut, s.pbd.model, s.pbd.data);
    previous = next;
  }
  const std::vector<uint32_t> of = particle_bodies(s.pbd);
  const std::vector<uint32_t> bodies = bodies_bottom_up(s.pbd, of);
  REQUIRE(bodies.size() == 2);
  // The two sides' cut faces: the vertices of the cut triangles, per body; their mean height.
  const CutSurface& surface = s.cut.surface;
  std::vector<int> side(surface.positions.size(), -1);
  for (uint32_t t = 0; t < surface.triangles.size(); ++t) {
    if (surface.quad_half_edge[t / 2] == CutSurface::kFreeKey || !surface.triangle_cut[t]) continue;
    for (uint32_t v : surface.triangles[t]) side[v] = vertex_body(s.pbd, of, v) == bodies[1];
  }
  const auto face_height = [&](int which) {
    double y = 0.0;
    int n = 0;
    for (size_t v = 0; v < side.size(); ++v) {
      if (side[v] != which) continue;
      y += s.pbd.data.deformed[v].y();
      ++n;
    }
    REQUIRE(n > 100);
    return y / n;
  };
  pbd_embed(s.cut, s.pbd.model, s.pbd.data);  // deformed positions of the cut's new vertices
  double gap = face_height(1) - face_height(0);
  CHECK(std::abs(gap) < 1e-6);  // the faces start together (the new particles copy the old)
  worst = 0.0;
  for (int i = 0; i < 10; ++i) {
    pbd_step(s.cut, s.pbd.model, s.pbd.data);
    const double now = face_height(1) - face_height(0);
    const double speed = (now - gap) / PbdParams{}.dt;  // > 0: apart, < 0: sinking in
    gap = now;
    if (std::abs(speed) > std::abs(worst)) worst = speed;
  }
}


// cut_separation with piece contact, against the bound: the sides part or sink at under 1 %
// of g dt.
void check_fresh_cut(int substeps, int iterations, int resolution) {
  const double g_dt = 9.81 * PbdParams{}.dt;
  double worst = 0.0;
  cut_separation(true, substeps, iterations, resolution, worst);
  MESSAGE(resolution << " / sim 8, " << substeps << " x " << iterations << ": largest separation speed in the first 10 steps "
                     << worst / g_dt << " g dt");
  CHECK(std::abs(worst) < 0.01 * g_dt);
}

// A box dropped onto another (at `resolution` / sim 8, with `workers`): it lands and stays on top,
// no vertex deeper than a fine voxel inside the other box; the particles' hash in `hash`.
void box_drop(int workers, int resolution, uint64_t& hash) {
  PbdParams params;
  params.planes.push_back(plane(Vec3d(0.0, -0.51, 0.0), Vec3d::UnitY(), 0.5));
  Scene s;
  make_boxes(s, {{Vec3d(0.003, -0.25, 0.002), Vec3d(0.5, 0.25, 0.5)}, {Vec3d(0.053, 0.55, 0.012), Vec3d(0.3, 0.15, 0.3)}},
             params, resolution);
  ThreadRunner runner{workers};
  s.pbd.data.chunk_work = 1;  // every batch split across the threads
  const TaskRunner tasks = workers > 1 ? runner.runner() : TaskRunner{};
  const std::vector<uint32_t> of = particle_bodies(s.pbd);
  const std::vector<uint32_t> bodies = bodies_bottom_up(s.pbd, of);
  REQUIRE(bodies.size() == 2);
  uint32_t deep = 0;
  double tray_dip = 1e300;  // the lowest surface vertex's height above the tray
  for (int i = 0; i < 12; ++i) {  // 2 s, checked every 10 steps
    run(s, 10, tasks);
    tray_dip = std::min(tray_dip, lowest_surface(s.pbd, params.planes[0]));
    deep += vertices_inside(s, of, bodies[1], bodies[0], fine_voxel(s));
    deep += vertices_inside(s, of, bodies[0], bodies[1], fine_voxel(s));
  }
  Vec3d c0, v0, c1, v1;
  body_motion(s.pbd, of, bodies[0], c0, v0);
  body_motion(s.pbd, of, bodies[1], c1, v1);
  Fnv1a f;
  for (const Vec3d& p : s.pbd.data.position) f.bytes(p.data(), 3 * sizeof(double));
  hash = f.value;
  // The gap between the top box's lowest surface vertex and the bottom box's highest.
  double low = 1e300, high = -1e300;
  for (uint32_t v = 0; v < s.pbd.model.embedding.size(); ++v) {
    const uint32_t b = vertex_body(s.pbd, of, v);
    if (b == bodies[1]) low = std::min(low, double(s.pbd.data.deformed[v].y()));
    if (b == bodies[0]) high = std::max(high, double(s.pbd.data.deformed[v].y()));
  }
  const double gap = (low - high) / fine_voxel(s);
  MESSAGE("top box: gap to the bottom box " << gap << " fine voxels, speed " << v1.norm()
                                            << ", vertices deeper than a fine voxel inside the other box: " << deep);
  CHECK((workers == 1 || runner.splits > 1000));
  CHECK(deep == 0);
  CHECK(gap > -0.5);  // on top, not sunk in
  CHECK(gap < 0.5);   // landed
  CHECK(v1.norm() < 0.01 * 9.81 * PbdParams{}.dt);
  // The bottom box rests on the tray: its surface never more than half a fine voxel below it.
  CHECK(tray_dip >= -0.5 * fine_voxel(s));
  CHECK(lowest_surface(s.pbd, params.planes[0]) <= 0.5 * fine_voxel(s));
}
}  // namespace

TEST_SUITE("contact") {
  TEST_CASE("a fresh through-cut neither pushes its sides apart nor lets them sink into each other") {
    // The block settles under its own weight first, then is cut through horizontally. What parted the faces
    // (measured per batch kind, on the mean height gap of the cut faces): not the release of a residual
    // compression of the unconverged solve -- in the first substep the stretch and shape corrections close
    // the faces (-0.24 g dt^2 at 5 x 2) and the contacts open them by more (+0.28), and the gap then stays
    // where the first step put it -- but the piece contacts' resting offset (sim/contact.h, "Resting
    // offset"): one Gauss-Seidel sweep over the faces' redundant vertex contacts (~17 per piece pair, all on
    // the same 16 particles) over-separates them, and the faces rest that far apart (0.055 g dt^2 at the
    // scenes' 5 substeps x 2 iterations, 0.25 at 1 x 10, 0.004 at 8 x 10); a fresh cut starts at zero gap and
    // reached it in its first step (faces parting at 0.058, 0.22 and 0.004 g dt). Each substep now ends with
    // two sweeps of the piece contacts alone, and a vertex-on-vertex pair is one contact, not two: |speed| <
    // 0.001 g dt at all three.
    // The scenes' solver (assets/scenes/*.json: 5 substeps x 2 iterations), then 1 x 10 and 8 x 10.
    check_fresh_cut(5, 2, 32);
    check_fresh_cut(1, 10, 32);
    check_fresh_cut(8, 10, 32);
    // Without piece contact the top half sinks through the bottom half (the checks above can fail).
    const double g_dt = 9.81 * PbdParams{}.dt;
    double worst = 0.0;
    cut_separation(false, 8, 10, 32, worst);
    MESSAGE("without: " << worst / g_dt << " g dt");
    CHECK(worst < -1.0 * g_dt);
  }

  TEST_CASE("a box dropped onto another box stays on top, and the result does not depend on the workers") {
    uint64_t one = 0, two = 0;
    box_drop(1, 32, one);
    box_drop(2, 32, two);
    CHECK(one == two);
  }

  TEST_CASE("at 8 fine voxels per simulation voxel a fresh cut neither parts nor sinks, and a box stays on another") {
    // The default recording's ratio (128 / sim 16): contact cells of 4 fine voxels, 2 x 2 contact
    // points on a piece's flat face (sim/contact.h, "Contact points"); the tests above run at 4 fine
    // voxels per simulation voxel, where the cells are 2 fine voxels.
    check_fresh_cut(5, 2, 64);
    uint64_t hash = 0;
    box_drop(1, 64, hash);
  }

  TEST_CASE("pieces three fine voxels apart slide past each other untouched") {
    // A box held at its top and a second one falling past its side, 3 fine voxels away.
    const double h = 1.0 / 32.0;  // the fine voxel: the longest axis is 1
    PbdParams params;
    params.damping = 0.0;
    Aabb held;
    held.grow(Vec3d(-1.0, 0.3, -1.0));
    held.grow(Vec3d(-0.3, 1.0, 1.0));  // well away from the other box's corner particles
    params.fixed.push_back(held);
    Scene s;
    const double x0 = 3.0 * h;  // the falling box's left face; the held box ends at x = 0
    make_boxes(s, {{Vec3d(-0.25, 0.0, 0.002), Vec3d(0.25, 0.5, 0.5)}, {Vec3d((x0 + 0.5) / 2, 0.2, 0.002), Vec3d((0.5 - x0) / 2, 0.2, 0.2)}},
               params);
    REQUIRE(fine_voxel(s) == doctest::Approx(h).epsilon(0.05));
    const std::vector<uint32_t> of = particle_bodies(s.pbd);
    const std::vector<uint32_t> bodies = bodies_bottom_up(s.pbd, of);
    REQUIRE(bodies.size() == 2);
    run(s, 20);
    // The falling box (the one that moves) falls freely: g t after 20 steps, untouched by the other.
    Vec3d c0, v0, c1, v1;
    body_motion(s.pbd, of, bodies[0], c0, v0);
    body_motion(s.pbd, of, bodies[1], c1, v1);
    const Vec3d v = v0.norm() > v1.norm() ? v0 : v1;
    CHECK(v.y() == doctest::Approx(-9.81 * 20 * PbdParams{}.dt).epsilon(0.01));
    CHECK(std::abs(v.x()) < 1e-3 * std::abs(v.y()));
  }
}

TEST_SUITE("contact") {
  TEST_CASE("only the surface near another body enters the narrow phase") {
    // A small box resting on a large one: the pieces along their touching faces are exposed, but of
    // their surface vertices only those within reach of the other box's pieces are gathered.
    PbdParams params;
    params.planes.push_back(plane(Vec3d(0.0, -0.51, 0.0), Vec3d::UnitY(), 0.5));
    Scene s;
    make_boxes(s, {{Vec3d(0.003, -0.25, 0.002), Vec3d(0.5, 0.25, 0.5)}, {Vec3d(0.053, 0.55, 0.012), Vec3d(0.3, 0.15, 0.3)}},
               params);
    run(s, 40);  // it lands within 0.3 s
    const PieceContacts& pc = s.pbd.data.piece_contacts;
    REQUIRE(pc.counters.gathers > 0);
    uint32_t live = 0;
    for (uint32_t v = 0; v < s.pbd.model.embedding.size(); ++v) live += vertex_sim_piece(s.pbd.model, v) != kDeadIndex;
    const double points = double(pc.counters.points) / double(pc.counters.gathers);
    MESSAGE("points per gather " << points << " of " << live << " surface vertices; point pairs per gather "
                                 << double(pc.counters.point_pairs) / double(pc.counters.gathers) << ", contacts "
                                 << double(pc.counters.contacts) / double(pc.counters.gathers));
    CHECK(pc.counters.contacts > 0);
    CHECK(points < 0.5 * live);
    // Each gathered point is tested against the other body's points in the cells around it, never
    // against its own body's: far fewer pairs than all pairs of gathered points.
    CHECK(double(pc.counters.point_pairs) / double(pc.counters.gathers) < 0.25 * points * points);
  }
}

namespace {

// Two unit cubes of particles (A: 0-7 on [0,1]^3, B: 8-15 with its bottom face at y = bottom), and the
// centres of A's top face and B's bottom face as surface points of two bodies.
struct TwoCubes {
  double x[48] = {}, previous[48] = {}, inv_mass[16] = {};
  SurfacePoint points[2];
  explicit TwoCubes(double bottom, float allowance) {
    for (uint32_t k = 0; k < 16; ++k) {
      const uint32_t c = k % 8;
      x[3 * k] = double(c & 1);
      x[3 * k + 1] = double((c >> 1) & 1) + (k >= 8 ? bottom : 0.0);
      x[3 * k + 2] = double((c >> 2) & 1);
      inv_mass[k] = 1.0;
    }
    std::copy(x, x + 48, previous);
    for (int side = 0; side < 2; ++side) {
      SurfacePoint& p = points[side];
      p.body = side == 0 ? 0 : 8;
      p.normal = Vec3d(0.0, side == 0 ? 1.0 : -1.0, 0.0);
      p.position = Vec3d(0.5, side == 0 ? 1.0 : bottom, 0.5);
      for (uint32_t c = 0; c < 8; ++c) {
        p.particles[c] = 8 * uint32_t(side) + c;
        p.weights[c] = (((c >> 1) & 1) == (side == 0 ? 1u : 0u)) ? 0.25 : 0.0;
      }
      p.allowance = allowance;
      p.slot = uint32_t(side);
      p.reach = 0.5f;
    }
  }
  // Gathers the pair's contacts (reach 0.5) and solves them `iterations` times in one substep.
  void step(double max_push, int iterations) {
    ContactSet set;
    PieceContactScratch scratch;
    contacts_clear(set);
    for (SurfacePoint& p : points) {  // positions at the gather
      p.position.setZero();
      for (int c = 0; c < 8; ++c) p.position += p.weights[c] * Vec3d(x[3 * p.particles[c]], x[3 * p.particles[c] + 1], x[3 * p.particles[c] + 2]);
    }
    REQUIRE(gather_piece_contacts(points, 2, x, 16, max_push, 0.5, set, scratch) == 1);  // a mutual pair: one contact
    contacts_finish(set);
    contacts_begin_substep(set);
    std::copy(x, x + 48, previous);
    for (int it = 0; it < iterations; ++it) {
      for (uint32_t g = 0; g + 1 < set.group_begin.size(); ++g) solve_contact_group(x, previous, inv_mass, set, g);
    }
  }
  double gap() const { return x[3 * 8 + 1] - x[3 * 2 + 1]; }  // B's bottom corner above A's top corner
};

}  // namespace

TEST_SUITE("contact") {
  TEST_CASE("a fresh pair that starts with a gap may close it and is not pushed apart") {
    // A cut whose two faces start 0.1 apart (fresh: allowance infinity). The pair holds no gap open:
    // when B then comes down onto A (gap 0, no overlap), the contact does not push it back up. (It
    // used to keep the initial gap as a negative allowance, a separating push every step.)
    TwoCubes cubes(1.1, std::numeric_limits<float>::infinity());
    cubes.step(1e30, 5);
    CHECK(cubes.gap() == doctest::Approx(0.1));
    CHECK(cubes.points[0].allowance == 0.0f);  // no overlap to keep
    CHECK(cubes.points[1].allowance == 0.0f);
    for (uint32_t k = 8; k < 16; ++k) cubes.x[3 * k + 1] -= 0.1;  // B comes down onto A
    cubes.step(1e30, 5);
    CHECK(std::abs(cubes.gap()) < 1e-12);
  }

  TEST_CASE("a deep overlap is pushed out by at most max_push per step, a fresh one is kept") {
    // B sunk 0.3 into A. Not fresh (allowance 0): pushed out 0.05 per step, not 0.3 at once.
    TwoCubes deep(0.7, 0.0f);
    deep.step(0.05, 5);
    CHECK(deep.gap() == doctest::Approx(-0.25));
    deep.step(0.05, 5);
    CHECK(deep.gap() == doctest::Approx(-0.2));
    // Fresh (a cut made it so): it starts in contact at that depth, and no deeper.
    TwoCubes fresh(0.7, std::numeric_limits<float>::infinity());
    fresh.step(0.05, 5);
    CHECK(fresh.gap() == doctest::Approx(-0.3));
    CHECK(fresh.points[0].allowance == doctest::Approx(0.3));
    for (uint32_t k = 8; k < 16; ++k) fresh.x[3 * k + 1] -= 0.01;  // pressed 0.01 deeper
    fresh.step(0.05, 5);
    CHECK(fresh.gap() == doctest::Approx(-0.3));
  }
}

namespace {

// Random surface points in a slab (x, z in [0, extent), y in [0, 0.3)) of three bodies, four points a
// piece, each point on 8 particles of its own (all its weight on the first, which sits at the point):
// bodies 0 and 2 face up, body 1 faces down (normals jittered by up to ~8 degrees).
std::vector<SurfacePoint> random_points(uint32_t count, double extent, uint64_t seed, std::vector<double>& x) {
  SplitMix64 rng{seed};
  std::vector<SurfacePoint> points(count);
  x.assign(24 * size_t(count), 0.0);
  for (uint32_t v = 0; v < count; ++v) {
    SurfacePoint& p = points[v];
    p.piece = v / 4;
    p.body = p.piece % 3;
    p.position = Vec3d(rng.uniform(0.0, extent), rng.uniform(0.0, 0.3), rng.uniform(0.0, extent));
    const double side = p.body == 1 ? -1.0 : 1.0;
    p.normal = Vec3d(rng.uniform(-0.1, 0.1), side, rng.uniform(-0.1, 0.1)).normalized();
    for (uint32_t c = 0; c < 8; ++c) {
      p.particles[c] = 8 * v + c;
      p.weights[c] = c == 0 ? 1.0 : 0.0;
    }
    for (int a = 0; a < 3; ++a) x[24 * size_t(v) + a] = p.position[a];
    p.allowance = 0.0f;
    p.slot = v;
    p.reach = float(rng.uniform(0.05, 0.1));
  }
  return points;
}

// The point pairs (v << 32 | q) of the contacts gather_piece_contacts makes, from the particles.
std::vector<uint64_t> contact_pairs(std::vector<SurfacePoint> points, const std::vector<double>& x) {
  ContactSet set;
  PieceContactScratch scratch;
  contacts_clear(set);
  gather_piece_contacts(points.data(), uint32_t(points.size()), x.data(), uint32_t(x.size() / 3), 1.0, 0.5, set, scratch);
  contacts_finish(set);
  std::vector<uint64_t> pairs;
  for (const ContactPoint& c : set.points) pairs.push_back(uint64_t(c.particles[0] / 8) << 32 | (c.particles[8] / 8));
  std::sort(pairs.begin(), pairs.end());
  return pairs;
}

// The same pairs by brute force (sim/contact.h, "Broad phase" and "Contacts"): each point's nearest
// facing point of another body within the pair's reach (ties: the lower index); one contact per
// mutual pair, the lower point's.
std::vector<uint64_t> brute_force_pairs(const std::vector<SurfacePoint>& points) {
  const uint32_t n = uint32_t(points.size());
  std::vector<uint32_t> best(n, ~0u);
  for (uint32_t v = 0; v < n; ++v) {
    double best_d = 0.0;
    for (uint32_t q = 0; q < n; ++q) {
      if (points[q].body == points[v].body || points[v].normal.dot(points[q].normal) > -0.9) continue;
      const double d = (points[q].position - points[v].position).squaredNorm();
      const double reach = std::max(double(points[v].reach), double(points[q].reach));
      if (d > reach * reach) continue;
      if (best[v] == ~0u || d < best_d) {
        best[v] = q;
        best_d = d;
      }
    }
  }
  std::vector<uint64_t> pairs;
  for (uint32_t v = 0; v < n; ++v) {
    if (best[v] == ~0u || (best[best[v]] == v && best[v] < v)) continue;
    pairs.push_back(uint64_t(v) << 32 | best[v]);
  }
  std::sort(pairs.begin(), pairs.end());
  return pairs;
}

}  // namespace

TEST_SUITE("contact") {
  TEST_CASE("the narrow phase pairs each point with its nearest facing point of another body, on a dense grid or hashed cells") {
    // A slab 2 wide (20 cells of the largest reach along x and z: a dense grid over the points' cells),
    // and the same with one pair of points moved 1e4 away (too many cells: hashed cells).
    for (const uint64_t seed : {1u, 2u, 3u}) {
      CAPTURE(seed);
      std::vector<double> x;
      std::vector<SurfacePoint> points = random_points(2000, 2.0, seed, x);
      const std::vector<uint64_t> dense = contact_pairs(points, x);
      CHECK(dense.size() > 100);
      CHECK(dense == brute_force_pairs(points));
      for (uint32_t v : {8u, 12u}) {  // a piece of body 2 and one of body 1
        points[v].position += Vec3d(1e4, 0.0, 0.0);
        x[24 * size_t(v)] += 1e4;
      }
      const std::vector<uint64_t> hashed = contact_pairs(points, x);
      CHECK(hashed == brute_force_pairs(points));
    }
  }
}

namespace {

// Checks the contact index (sim/contact.h ContactIndex) of `s` against the model as it is now: each
// slot's piece, the slots of each piece, mobility, bodies, and the rest positions the allowances
// were refreshed from.
void check_index(const Scene& s) {
  const PbdState& pbd = s.pbd;
  const PieceContacts& pc = pbd.data.piece_contacts;
  const ContactIndex& x = pc.index;
  const uint32_t slots = uint32_t(std::min(pbd.model.embedding.size(), s.cut.surface.positions.size()));
  REQUIRE(x.slots == slots);
  REQUIRE(x.pieces == pbd.model.pieces.size());
  uint32_t embedded = 0;
  for (uint32_t slot = 0; slot < slots; ++slot) {
    CHECK(x.slot_piece[slot] == vertex_sim_piece(pbd.model, slot));
    embedded += vertex_sim_piece(pbd.model, slot) != kDeadIndex;
  }
  CHECK(x.piece_slots.size() == embedded);
  for (uint32_t i = 0; i < x.pieces; ++i) {
    for (uint32_t n = x.piece_begin[i]; n < x.piece_begin[i + 1]; ++n) {
      CHECK(x.slot_piece[x.piece_slots[n]] == i);
      if (n > x.piece_begin[i]) CHECK(x.piece_slots[n - 1] < x.piece_slots[n]);
    }
    bool mobile = false;
    if (pbd.model.pieces[i].sim_voxel != kDeadIndex) {
      for (uint32_t p : pbd.model.pieces[i].particles) mobile = mobile || pbd.model.inv_mass[p] > 0.0;
    }
    CHECK(bool(x.mobile[i]) == mobile);
  }
  // Bodies: the same partition as find_bodies' from scratch.
  const std::vector<uint32_t> of = particle_bodies(pbd);
  std::vector<uint32_t> first_of(pbd.data.position.size(), ~0u);  // body root -> the index of its first piece
  std::vector<uint32_t> roots;
  for (uint32_t i = 0; i < x.pieces; ++i) {
    if (pbd.model.pieces[i].sim_voxel == kDeadIndex) continue;
    const uint32_t root = of[pbd.model.pieces[i].particles[0]];
    if (first_of[root] == ~0u) {
      first_of[root] = x.body_index[i];
      roots.push_back(root);
    }
    CHECK(x.body_index[i] == first_of[root]);
  }
  CHECK(x.bodies == roots.size());
  // Allowances were refreshed against the surface as it is (NaN: free slots).
  REQUIRE(pc.seen.size() == s.cut.surface.positions.size());
  uint32_t stale = 0;
  for (size_t v = 0; v < pc.seen.size(); ++v) {
    const Vec3f& a = pc.seen[v];
    const Vec3f& b = s.cut.surface.positions[v];
    stale += !(a == b || (std::isnan(a.x()) && std::isnan(b.x())));
  }
  CHECK(stale == 0);
}

// The contact points of every piece both sets have built are the same, bit for bit (slots and
// normals, in order); returns the pieces compared.
uint64_t check_same_reps(const PieceContacts& x, const PieceContacts& y) {
  uint64_t compared = 0;
  for (uint32_t i = 0; i < x.rep_begin.size(); ++i) {
    if (x.rep_begin[i] == ~0u || y.rep_begin[i] == ~0u) continue;
    REQUIRE(x.rep_count[i] == y.rep_count[i]);
    ++compared;
    for (uint32_t r = 0; r < x.rep_count[i]; ++r) {
      const ContactRep &a = x.reps[x.rep_begin[i] + r], &b = y.reps[y.rep_begin[i] + r];
      CHECK(a.slot == b.slot);
      CHECK(std::equal(a.normal, a.normal + 3, b.normal));
    }
  }
  return compared;
}

uint64_t position_hash(const PbdState& s) {
  Fnv1a f;
  for (const Vec3d& p : s.data.position) f.bytes(p.data(), 3 * sizeof(double));
  return f.value;
}

}  // namespace

TEST_SUITE("contact") {
  TEST_CASE("the contact index follows every cut and gives the contacts a fresh index gives") {
    // A block on a tray cut through horizontally (one cut step per solver step), then vertically
    // (two cut steps per solver step). A twin steps through the same cuts with its index and
    // allowances rebuilt from scratch every step: the two stay bit-identical.
    PbdParams params;
    params.planes.push_back(plane(Vec3d(0.0, -0.52, 0.0), Vec3d::UnitY(), 0.5));
    Scene s;
    make_boxes(s, {{Vec3d(0.003, 0.0, 0.002), Vec3d(0.5, 0.5, 0.5)}}, params);
    run(s, 30);
    PbdState twin = s.pbd;
    BladePose previous{Vec3d(-1, 0.013, -2), Vec3d(-1, 0.013, 2)};
    const auto cut = [&](const BladePose& next) {
      cut_step(s.model, s.cut, previous, next);
      pbd_apply_cut(s.model, s.cut, s.pbd.model, s.pbd.data);
      pbd_apply_cut(s.model, s.cut, twin.model, twin.data);
      previous = next;
    };
    uint64_t compared = 0;  // pieces whose kept points were compared
    const auto step = [&]() {
      pbd_step(s.cut, s.pbd.model, s.pbd.data);
      twin.data.piece_contacts.index.revision = ~uint64_t(0);  // rebuild
      twin.data.piece_contacts.seen_steps = ~uint64_t(0);      // compare every slot
      pbd_step(s.cut, twin.model, twin.data);
      check_index(s);
      CHECK(position_hash(s.pbd) == position_hash(twin));
      // The contact points kept from before the cut equal those the twin built afresh.
      compared += check_same_reps(s.pbd.data.piece_contacts, twin.data.piece_contacts);
    };
    for (int i = 1; i <= 8; ++i) {
      const double x = -1.0 + 2.0 * i / 8;
      cut(BladePose{Vec3d(x, 0.013, -2), Vec3d(x, 0.013, 2)});
      step();
    }
    for (int i = 0; i < 10; ++i) step();  // no cut: the index stays
    previous = BladePose{Vec3d(0.21, 1.0, -2), Vec3d(0.21, 1.0, 2)};
    for (int i = 1; i <= 12; i += 2) {
      for (int k = i; k <= i + 1; ++k) {
        const double y = 1.0 - 2.0 * k / 12;
        cut(BladePose{Vec3d(0.21, y, -2), Vec3d(0.21, y, 2)});
      }
      step();
    }
    for (int i = 0; i < 20; ++i) step();
    const std::vector<uint32_t> of = particle_bodies(s.pbd);
    CHECK(bodies_bottom_up(s.pbd, of).size() >= 3);  // the cuts made pieces
    CHECK(s.pbd.data.piece_contacts.counters.contacts > 0);  // that touched
    // Each cut rebuilt only the contact points of the pieces it touched; the twin rebuilt every
    // piece's it needed after each step.
    CHECK(s.pbd.data.piece_contacts.counters.reps_built > 0);
    CHECK(compared > s.pbd.data.piece_contacts.counters.reps_built);  // mostly points kept across cuts
    CHECK(2 * s.pbd.data.piece_contacts.counters.reps_built < twin.data.piece_contacts.counters.reps_built);
  }

  TEST_CASE("contact points built by several workers, in one batch or piece by piece, are the serial ones bit for bit") {
    // The block on a tray cut through horizontally, then vertically (a cut step per solver step).
    // `one` steps serially; `many` with three workers (every batch split); `fresh` with three
    // workers and its index rebuilt every step, so every piece it needs is built again in one batch
    // (one scan of the surface, in two parts at once) where the others build only what the last cut
    // touched (`many` through the quads around the slots, `one` by scans); `many` also gathers each
    // piece's surface points as a chunk of its own. The contact points and the positions stay
    // bit-identical.
    PbdParams params;
    params.planes.push_back(plane(Vec3d(0.0, -0.52, 0.0), Vec3d::UnitY(), 0.5));
    Scene s;
    make_boxes(s, {{Vec3d(0.003, 0.0, 0.002), Vec3d(0.5, 0.5, 0.5)}}, params);
    run(s, 30);
    PbdState many = s.pbd, fresh = s.pbd;
    many.data.chunk_work = fresh.data.chunk_work = 1;
    many.data.piece_contacts.rep_slots_per_scan = 1;  // small batches through the quads around the slots
    many.data.piece_contacts.point_pieces_per_chunk = 1;  // each piece's surface points a chunk of its own
    fresh.data.piece_contacts.rep_slots_per_part = 1;  // every scan in two parts
    ThreadRunner runner{3};
    BladePose previous{Vec3d(-1, 0.013, -2), Vec3d(-1, 0.013, 2)};
    const auto cut = [&](const BladePose& next) {
      cut_step(s.model, s.cut, previous, next);
      for (PbdState* p : {&s.pbd, &many, &fresh}) pbd_apply_cut(s.model, s.cut, p->model, p->data);
      previous = next;
    };
    uint64_t compared = 0, points_compared = 0;
    const auto step = [&]() {
      pbd_step(s.cut, s.pbd.model, s.pbd.data);
      pbd_step(s.cut, many.model, many.data, runner.runner());
      fresh.data.piece_contacts.index.revision = ~uint64_t(0);  // rebuild
      pbd_step(s.cut, fresh.model, fresh.data, runner.runner());
      const PieceContacts& serial = s.pbd.data.piece_contacts;
      CHECK(position_hash(many) == position_hash(s.pbd));
      CHECK(position_hash(fresh) == position_hash(s.pbd));
      for (const PbdState* other : {&many, &fresh}) {
        compared += check_same_reps(serial, other->data.piece_contacts);
        // The step's surface points in the same order (by piece, then contact point).
        const std::vector<SurfacePoint>& a = serial.points;
        const std::vector<SurfacePoint>& b = other->data.piece_contacts.points;
        REQUIRE(a.size() == b.size());
        for (size_t k = 0; k < a.size(); ++k) REQUIRE(a[k].slot == b[k].slot);
        points_compared += a.size();
      }
    };
    for (int i = 1; i <= 8; ++i) {
      const double x = -1.0 + 2.0 * i / 8;
      cut(BladePose{Vec3d(x, 0.013, -2), Vec3d(x, 0.013, 2)});
      step();
    }
    previous = BladePose{Vec3d(0.21, 1.0, -2), Vec3d(0.21, 1.0, 2)};
    for (int k = 1; k <= 12; ++k) {
      cut(BladePose{Vec3d(0.21, 1.0 - 2.0 * k / 12, -2), Vec3d(0.21, 1.0 - 2.0 * k / 12, 2)});
      step();
    }
    for (int i = 0; i < 5; ++i) step();
    // `fresh` built some batches in one pass over the surface, `many` some through the quads
    // around the slots.
    CHECK(fresh.data.piece_contacts.counters.reps_scanned > 0);
    CHECK(fresh.data.piece_contacts.counters.scans_split > 0);
    CHECK(many.data.piece_contacts.counters.reps_built > many.data.piece_contacts.counters.reps_scanned);
    CHECK(s.pbd.data.piece_contacts.counters.contacts > 0);
    CHECK(compared > 1000);
    CHECK(points_compared > 1000);
    CHECK(runner.splits > 100);
  }
}

TEST_SUITE("contact") {
  TEST_CASE("a stroke's pieces get their contact points as the blade leaves them, the same as built on need") {
    // A block on a tray at 64 (16 simulation voxels across) cut through vertically in 16 steps, one
    // solver step each, then left to rest. `lazy` builds contact points only on need (nothing ahead),
    // the other also ahead (build_settled_reps). Their positions stay bit-identical and every piece
    // both have built has the same points; in the step that severs, over two thirds of what the new pair of
    // bodies needs was built ahead.
    PbdParams params;
    params.planes.push_back(plane(Vec3d(0.0, -0.52, 0.0), Vec3d::UnitY(), 0.5));
    Scene s;
    dvx_test::make_pbd_scene(s, make_box(Vec3d(0.003, 0.0, 0.002), Vec3d(0.5, 0.5, 0.5), Eigen::Matrix3d::Identity(), 1), 64, 16,
                             params);
    run(s, 10);
    PbdState lazy = s.pbd;
    lazy.data.piece_contacts.rep_ahead_slots = 0;
    BladePose previous{Vec3d(-0.21, 1.0, -2), Vec3d(-0.21, 1.0, 2)};
    uint64_t compared = 0, built_at_sever = ~uint64_t(0), lazy_built_at_sever = ~uint64_t(0);
    const auto step = [&]() {
      const uint32_t bodies = s.pbd.data.piece_contacts.index.bodies;
      const uint64_t built = s.pbd.data.piece_contacts.counters.reps_built;
      const uint64_t lazy_built = lazy.data.piece_contacts.counters.reps_built;
      pbd_step(s.cut, s.pbd.model, s.pbd.data);
      pbd_step(s.cut, lazy.model, lazy.data);
      CHECK(position_hash(s.pbd) == position_hash(lazy));
      compared += check_same_reps(s.pbd.data.piece_contacts, lazy.data.piece_contacts);
      if (bodies == 1 && s.pbd.data.piece_contacts.index.bodies == 2) {  // the step that severs
        built_at_sever = s.pbd.data.piece_contacts.counters.reps_built - built;
        lazy_built_at_sever = lazy.data.piece_contacts.counters.reps_built - lazy_built;
      }
    };
    for (int k = 1; k <= 16; ++k) {
      const BladePose next{Vec3d(-0.21, 1.0 - 2.0 * k / 16, -2), Vec3d(-0.21, 1.0 - 2.0 * k / 16, 2)};
      cut_step(s.model, s.cut, previous, next);
      for (PbdState* p : {&s.pbd, &lazy}) pbd_apply_cut(s.model, s.cut, p->model, p->data);
      previous = next;
      step();
    }
    for (int i = 0; i < 10; ++i) step();
    const PieceContacts& pc = s.pbd.data.piece_contacts;
    REQUIRE(built_at_sever != ~uint64_t(0));  // it severed
    CHECK(pc.counters.reps_ahead > 0);
    CHECK(lazy.data.piece_contacts.counters.reps_ahead == 0);
    CHECK(lazy_built_at_sever > 40);
    CHECK(3 * built_at_sever < lazy_built_at_sever);
    CHECK(compared > 1000);
    CHECK(pc.counters.contacts > 0);
    MESSAGE("contact points built in the step that severs: " << built_at_sever << " (on need only: " << lazy_built_at_sever
                                                              << "); built ahead over the run: " << pc.counters.reps_ahead);
  }
}

TEST_SUITE("contact") {
  TEST_CASE("the pair cache finds the pieces the grid finds while pieces move, appear, change body and die") {
    // Random boxes of a simulation voxel's size in a 12-voxel cube, in a few bodies; each step some
    // move a little (within the margin: their entries hold), a few jump (stale), a few are added or
    // die, a few change body, and now and then many change body at once (as a sever renumbers one
    // side: the cache is rebuilt). Every step the cached broad phase must mark the same pieces and list
    // the same partners as find_exposed_pieces over the candidates.
    SplitMix64 rng{20261206};
    std::vector<Vec3d> lo, hi;
    std::vector<double> reach;
    std::vector<uint32_t> body;
    std::vector<uint8_t> live;
    const auto add_piece = [&]() {
      const Vec3d a(rng.uniform(0.0, 12.0), rng.uniform(0.0, 12.0), rng.uniform(0.0, 12.0));
      lo.push_back(a);
      hi.push_back(a + Vec3d::Constant(rng.uniform(0.8, 1.2)));
      reach.push_back(rng.uniform(0.05, 0.3));
      body.push_back(uint32_t(rng.next() % 5));
      live.push_back(1);
    };
    for (int i = 0; i < 400; ++i) add_piece();
    PieceContactScratch cached, fresh;
    std::vector<uint8_t> exposed_cached, exposed_fresh;
    uint64_t builds_before = 0;
    for (int step = 0; step < 120; ++step) {
      const uint32_t n = uint32_t(lo.size());
      for (uint32_t i = 0; i < n; ++i) {
        if (!live[i]) continue;
        const double r = rng.uniform();
        Vec3d d = Vec3d::Zero();
        if (r < 0.5) d = Vec3d(rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05));
        else if (r < 0.53) d = Vec3d(rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0));
        lo[i] += d;
        hi[i] += d;
        if (rng.uniform() < 0.01) body[i] = uint32_t(rng.next() % 5);
        if (rng.uniform() < 0.001) live[i] = 0;
      }
      if (step % 7 == 3) {
        for (int k = 0; k < 5; ++k) add_piece();
      }
      if (step % 40 == 20) {  // a sever: one body's pieces in its upper half get a new body
        for (uint32_t i = 0; i < n; ++i) body[i] = (body[i] == 1 && lo[i].y() > 6.0) ? 7u : body[i];
      }
      if (step == 60 || step == 63) {  // a piece blown up (NaN) for three steps: the grid's rules for it
        for (const uint32_t i : {17u, 18u}) {
          const double v = step == 60 ? std::numeric_limits<double>::quiet_NaN() : 5.0 + i;
          lo[i] = Vec3d::Constant(v);
          hi[i] = lo[i] + Vec3d::Constant(1.0);
        }
      }
      if (step == 91) {  // every body renumbered: nearly all stale, rebuilt
        for (uint32_t& b : body) b += 10;
      }
      const uint32_t count = uint32_t(lo.size());
      // Candidates: the live pieces (a random third left out now and then, as the body phase does).
      std::vector<uint8_t> candidate(live);
      if (step % 5 == 0) {
        for (uint32_t i = 0; i < count; ++i) candidate[i] = candidate[i] && rng.uniform() < 0.67;
      }
      const uint32_t marked = find_exposed_pieces_cached(lo.data(), hi.data(), reach.data(), candidate.data(), body.data(), count,
                                                         0.25, exposed_cached, cached);
      const uint32_t expected = find_exposed_pieces(lo.data(), hi.data(), reach.data(), candidate.data(), body.data(), count,
                                                    exposed_fresh, fresh);
      REQUIRE(marked == expected);
      REQUIRE(exposed_cached == exposed_fresh);
      if (step < 60 || step > 62) {
        // Both go through the grid: every pair tested here instead (a NaN box meets only its cell's
        // boxes in the grid, so not while the blown-up pieces are NaN).
        std::vector<uint8_t> brute(count, 0);
        uint32_t brute_pairs = 0;
        for (uint32_t i = 0; i < count; ++i) {
          for (uint32_t j = i + 1; j < count && candidate[i]; ++j) {
            if (!candidate[j] || body[i] == body[j]) continue;
            const Vec3d a = lo[i] - Vec3d::Constant(reach[i]), b = hi[i] + Vec3d::Constant(reach[i]);
            const Vec3d c = lo[j] - Vec3d::Constant(reach[j]), d = hi[j] + Vec3d::Constant(reach[j]);
            if ((c.array() > b.array()).any() || (d.array() < a.array()).any()) continue;
            brute[i] = brute[j] = 1;
            ++brute_pairs;
          }
        }
        REQUIRE(brute == exposed_fresh);
        REQUIRE(fresh.partner_begin[count] == 2 * brute_pairs);
      }
      REQUIRE(cached.partner_begin == fresh.partner_begin);
      REQUIRE(cached.partners == fresh.partners);
      if (step == 90) builds_before = cached.pair_cache.builds;
    }
    // Most steps refreshed stale entries instead of rebuilding.
    MESSAGE("pair cache: " << cached.pair_cache.builds << " rebuilds, " << cached.pair_cache.updates << " refreshes in 120 steps");
    CHECK(builds_before < 20);
    CHECK(cached.pair_cache.builds > builds_before);  // the renumbering rebuilt it
    CHECK(cached.pair_cache.updates > 60);
  }
}
