// The window's input mapping, without a window: surface picking, the scalpel's pose, camera mouse
// moves, grab drags, scene panel validation.
#include "ui/input.h"

#include "engine/scene.h"
#include "sim/cut.h"
#include "sim/shapes.h"

#include <nlohmann/json.hpp>

#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>

using namespace dvx;

namespace {

Aabb unit_box() {
  Aabb b;
  b.grow(Vec3d(-1, -1, -1));
  b.grow(Vec3d(1, 1, 1));
  return b;
}

double distance_to_line(const Vec3d& p, const Vec3d& origin, const Vec3d& dir) {
  const Vec3d o = p - origin;
  return (o - o.dot(dir) * dir).norm();
}

}  // namespace

// Two unit squares facing +z at z = 0 and z = -1 (two triangles each), the back one flagged cut.
struct TwoSquares {
  std::vector<Vec3f> positions;
  std::vector<Tri> triangles;
  std::vector<uint8_t> flags;
  TwoSquares() {
    for (float z : {0.0f, -1.0f}) {
      const uint32_t b = uint32_t(positions.size());
      positions.insert(positions.end(), {Vec3f(-1, -1, z), Vec3f(1, -1, z), Vec3f(1, 1, z), Vec3f(-1, 1, z)});
      triangles.push_back({b, b + 1, b + 2});
      triangles.push_back({b, b + 2, b + 3});
    }
    flags = {0, 0, 1, 1};
  }
};

TEST_CASE("pick by facing: the faces a ray enters the tissue through, or leaves it through") {
  TwoSquares m;  // both face +z (outward normal +z)
  SurfaceHit hit;
  const std::vector<uint8_t> none(m.triangles.size(), 0);
  const Ray down{Vec3f(0.2f, 0.3f, 5.0f), Vec3f(0, 0, -1)};
  REQUIRE(pick_surface(down, m.positions, m.triangles, none, 0, 0.0f, hit, nullptr, Facing::kEntering));
  CHECK(hit.t == doctest::Approx(5.0f));
  CHECK_FALSE(pick_surface(down, m.positions, m.triangles, none, 0, 0.0f, hit, nullptr, Facing::kLeaving));
  // From below, the ray meets both squares' back sides: leaving only.
  const Ray up{Vec3f(0.2f, 0.3f, -5.0f), Vec3f(0, 0, 1)};
  CHECK_FALSE(pick_surface(up, m.positions, m.triangles, none, 0, 0.0f, hit, nullptr, Facing::kEntering));
  REQUIRE(pick_surface(up, m.positions, m.triangles, none, 0, 0.0f, hit, nullptr, Facing::kLeaving));
  CHECK(hit.t == doctest::Approx(4.0f));
}

TEST_CASE("off the tissue: the depth of the surface nearest the cursor on screen") {
  TwoSquares m;
  float t = 0.0f;
  // A ray passing beside the squares (x = 3): the corners at x = 1 are 2 off the ray; in perspective
  // the back square's (6 along the ray) appear nearer the cursor than the front one's (5 along it).
  REQUIRE(nearest_surface_depth({Vec3f(3, 0, 5), Vec3f(0, 0, -1)}, m.positions, m.triangles, 0.0f, t));
  CHECK(t == doctest::Approx(6.0f));
  // Beside the front square only (the back one shifted away): its depth.
  std::vector<Vec3f> shifted = m.positions;
  for (size_t v = 4; v < shifted.size(); ++v) shifted[v].x() -= 10.0f;
  REQUIRE(nearest_surface_depth({Vec3f(3, 0, 5), Vec3f(0, 0, -1)}, shifted, m.triangles, 0.0f, t));
  CHECK(t == doctest::Approx(5.0f));
  CHECK_FALSE(nearest_surface_depth({Vec3f(3, 0, 5), Vec3f(0, 0, 1)}, m.positions, m.triangles, 0.0f, t));  // all behind
  const std::vector<Tri> dead(m.triangles.size(), Tri{kDeadIndex, kDeadIndex, kDeadIndex});
  CHECK_FALSE(nearest_surface_depth({Vec3f(3, 0, 5), Vec3f(0, 0, -1)}, m.positions, dead, 0.0f, t));
}

TEST_CASE("pick: the nearest triangle on the ray, either side, dead slots, NaN and skipped classes ignored") {
  TwoSquares m;
  SurfaceHit hit;
  const Ray ray{Vec3f(0.2f, 0.3f, 5.0f), Vec3f(0, 0, -1)};
  REQUIRE(pick_surface(ray, m.positions, m.triangles, m.flags, 0, 0.0f, hit));
  CHECK(hit.t == doctest::Approx(5.0f));
  CHECK(hit.triangle < 2);
  CHECK((hit.point - Vec3f(0.2f, 0.3f, 0.0f)).norm() < 1e-5f);
  // From behind (the back side of the cut square) and skipping cut faces.
  const Ray back{Vec3f(0.2f, 0.3f, -5.0f), Vec3f(0, 0, 1)};
  REQUIRE(pick_surface(back, m.positions, m.triangles, m.flags, 0, 0.0f, hit));
  CHECK(hit.t == doctest::Approx(4.0f));
  CHECK(hit.triangle >= 2);
  REQUIRE(pick_surface(back, m.positions, m.triangles, m.flags, 1, 0.0f, hit));
  CHECK(hit.t == doctest::Approx(5.0f));
  // t_min: hits nearer than it do not count.
  REQUIRE(pick_surface(ray, m.positions, m.triangles, m.flags, 0, 5.5f, hit));
  CHECK(hit.t == doctest::Approx(6.0f));
  // Misses: beside the squares, pointing away, dead slots, NaN corners.
  CHECK_FALSE(pick_surface({Vec3f(3, 0, 5), Vec3f(0, 0, -1)}, m.positions, m.triangles, m.flags, 0, 0.0f, hit));
  CHECK_FALSE(pick_surface({Vec3f(0, 0, 5), Vec3f(0, 0, 1)}, m.positions, m.triangles, m.flags, 0, 0.0f, hit));
  const std::vector<Tri> dead(m.triangles.size(), Tri{kDeadIndex, kDeadIndex, kDeadIndex});
  CHECK_FALSE(pick_surface(ray, m.positions, dead, m.flags, 0, 0.0f, hit));
  const std::vector<Vec3f> nan_positions(m.positions.size(), Vec3f::Constant(std::nanf("")));
  CHECK_FALSE(pick_surface(ray, nan_positions, m.triangles, m.flags, 0, 0.0f, hit));
}

TEST_CASE("scalpel: the blade enters at the picked point, reaches the set depth, tilts toward the screen's bottom") {
  const Aabb box = unit_box();
  const Camera camera = frame_box(box, 16.0f / 9.0f);
  const Viewport viewport{1280, 720};
  const Ray ray = cursor_ray(camera, viewport, {700, 400});
  const Vec3f entry = ray.origin + 3.0f * ray.direction;
  for (const float tilt : {0.0f, 0.35f}) {
    const BladePose pose = scalpel_pose(camera, ray, entry, 0.8, 0.05, tilt);
    const Vec3d e = entry.cast<double>(), u = (pose.b - pose.a).normalized();
    CHECK((pose.b - e).norm() == doctest::Approx(0.8).epsilon(1e-5));   // depth past the entry
    CHECK((e - pose.a).norm() == doctest::Approx(0.05).epsilon(1e-4));  // starts a little before it
    CHECK(distance_to_line(e, pose.a, u) < 1e-5);                       // through the entry
    const double angle = std::acos(std::clamp(u.dot(ray.direction.cast<double>()), -1.0, 1.0));
    CHECK(angle == doctest::Approx(tilt).epsilon(1e-3));
    if (tilt > 0) CHECK(u.dot(camera_up(camera).cast<double>()) < 0.0);  // toward the bottom of the screen
  }
}

// Issue 29, fast drags: a drag of 240 px across a sphere in one frame. The straight sweep between the
// two frames' poses passes under the surface the cursor crossed (its top dips below the entries by
// about the chord's sagitta); lengthened by cover_crossed_path it passes above every one of them, and
// its tip through the tissue under each.
TEST_CASE("scalpel: a fast drag's sweep covers the surface the cursor crossed") {
  const TriMesh sphere = make_icosphere(Vec3d::Zero(), 1.0, 4);
  std::vector<Vec3f> positions;
  for (const Vec3d& p : sphere.positions) positions.push_back(p.cast<float>());
  const std::vector<uint8_t> flags(sphere.triangles.size(), 0);
  const Camera camera = frame_box(unit_box(), 16.0f / 9.0f);
  const Viewport viewport{1280, 720};
  const double voxel = 0.02, depth = 0.3;
  const auto aim = [&](const Eigen::Vector2f& pixel, Vec3f& entry) {
    const Ray ray = cursor_ray(camera, viewport, pixel);
    // As the window aims it: the set depth, or through the tissue under the cursor and a voxel.
    const TissueUnderRay tissue = tissue_under_ray(camera, ray, positions, sphere.triangles, flags, true, float(voxel));
    REQUIRE(tissue.hit);
    REQUIRE(tissue.exits);
    entry = tissue.entry.point;
    return scalpel_pose(camera, ray, entry, std::max(depth, double(tissue.exit.t) + voxel), 2.0 * voxel);
  };
  const Eigen::Vector2f from_pixel(520, 360), to_pixel(760, 360);
  Vec3f e0, e1;
  const BladePose from = aim(from_pixel, e0), to = aim(to_pixel, e1);
  // How far above (positive) the sweep's top passes each entry under the path, the worst of 32.
  const auto worst_clearance = [&](const BladePose& end) {
    const Vec3d top_move = end.a - from.a, u = (end.b - end.a).normalized();
    double worst = 1e300, worst_depth = 1e300;
    for (int i = 1; i < 32; ++i) {
      Vec3f e;
      const BladePose at = aim(from_pixel + (float(i) / 32.0f) * (to_pixel - from_pixel), e);
      const double s = std::clamp((e.cast<double>() - from.a).dot(top_move) / top_move.squaredNorm(), 0.0, 1.0);
      const Vec3d top = from.a + s * top_move, tip = from.b + s * (end.b - from.b);
      worst = std::min(worst, (e.cast<double>() - top).dot(u));
      worst_depth = std::min(worst_depth, (tip - at.b).dot(u));
    }
    return std::pair<double, double>(worst, worst_depth);
  };
  const auto [plain, plain_depth] = worst_clearance(to);
  MESSAGE("straight sweep: the top passes " << -plain << " below the lowest entry crossed");
  CHECK(plain < -3.0 * voxel);  // the dashes: the top under the surface by several voxels
  CoverStats stats;
  const BladePose covered = cover_crossed_path(camera, viewport, from_pixel, to_pixel, from, to, positions,
                                               sphere.triangles, flags, depth, voxel, nullptr, &stats);
  const auto [clear, clear_depth] = worst_clearance(covered);
  MESSAGE("covered: the top raised " << stats.raised << ", the tip lowered " << stats.lowered << ", clearance " << clear
                                     << ", depth margin " << clear_depth << " (" << stats.hits << "/" << stats.samples
                                     << " samples on the tissue)");
  CHECK(stats.hits == 8);
  CHECK(clear > 0.0);               // every entry crossed lies under the sweep's top
  CHECK(plain_depth < -3.0 * voxel);  // the tip, too, stops short of the far side
  CHECK(clear_depth > -voxel);  // covered: past the far side under every point (each aim reaches a voxel beyond it)
  // Along the new pose's own line: the same blade, longer.
  const Vec3d u0 = (to.b - to.a).normalized(), u1 = (covered.b - covered.a).normalized();
  CHECK(u0.dot(u1) > 1.0 - 1e-9);
  CHECK(distance_to_line(covered.a, to.a, u0) < 1e-9);
  // A slow drag (under a step) is sent as it is.
  const BladePose slow = cover_crossed_path(camera, viewport, from_pixel, from_pixel + Eigen::Vector2f(5, 0), from, to,
                                            positions, sphere.triangles, flags, depth, voxel);
  CHECK(slow.a == to.a);
  CHECK(slow.b == to.b);
}

// A stroke off the tissue keeps its reach, but a lobe can lie along the blade's line past it: the blade
// is lengthened to kReachPastFarSide voxels past the far side of the tissue its line enters, within
// its length, by at most max_extra; else it is left as it is.
TEST_CASE("scalpel: off the tissue the blade reaches through the tissue along its own line") {
  const TriMesh sphere = make_icosphere(Vec3d::Zero(), 1.0, 4);
  std::vector<Vec3f> positions;
  for (const Vec3d& p : sphere.positions) positions.push_back(p.cast<float>());
  const std::vector<uint8_t> flags(sphere.triangles.size(), 0);
  const double voxel = 0.02;
  // From above the sphere straight down, the tip inside it: lengthened to the far side (y = -1).
  BladePose pose{Vec3d(0.0, 2.0, 0.0), Vec3d(0.0, 0.5, 0.0)};
  const BladePose through = reach_through_along_blade(pose, positions, sphere.triangles, flags, voxel, 10.0);
  CHECK(through.a == pose.a);
  CHECK(std::abs(through.b.x()) < 1e-9);
  CHECK(through.b.y() == doctest::Approx(-1.0 - kReachPastFarSide * voxel).epsilon(0.01));
  // At most max_extra longer.
  const BladePose capped = reach_through_along_blade(pose, positions, sphere.triangles, flags, voxel, 0.5);
  CHECK((capped.b - capped.a).norm() == doctest::Approx(2.0));
  // A blade whose line enters no tissue within its length, or that already reaches past: unchanged.
  const BladePose short_pose{Vec3d(0.0, 3.0, 0.0), Vec3d(0.0, 1.5, 0.0)};
  CHECK(reach_through_along_blade(short_pose, positions, sphere.triangles, flags, voxel, 10.0).b == short_pose.b);
  const BladePose long_pose{Vec3d(0.0, 2.0, 0.0), Vec3d(0.0, -2.0, 0.0)};
  CHECK(reach_through_along_blade(long_pose, positions, sphere.triangles, flags, voxel, 10.0).b == long_pose.b);
  const BladePose beside{Vec3d(3.0, 2.0, 0.0), Vec3d(3.0, -2.0, 0.0)};
  CHECK(reach_through_along_blade(beside, positions, sphere.triangles, flags, voxel, 10.0).b == beside.b);
}

TEST_CASE("camera: orbit keeps target and distance, pan keeps distance and angles, zoom keeps target") {
  Aabb box = unit_box();
  Camera c = frame_box(box, 1.5f);
  const Vec3f target = c.target;
  const float distance = c.distance;
  camera_orbit(c, 120.0f, -40.0f);
  CHECK((c.target - target).norm() < 1e-6f);
  CHECK(c.distance == distance);
  CHECK((camera_eye(c) - c.target).norm() == doctest::Approx(distance).epsilon(1e-5));
  // Pitch stays within +-89 degrees whatever the drag.
  camera_orbit(c, 0.0f, 1e6f);
  CHECK(c.pitch <= 89.0f * 3.14159265f / 180.0f + 1e-6f);
  CHECK(camera_forward(c).allFinite());
  camera_orbit(c, 0.0f, -2e6f);
  CHECK(c.pitch >= -89.0f * 3.14159265f / 180.0f - 1e-6f);

  Camera p = frame_box(box, 1.5f);
  const float yaw = p.yaw, pitch = p.pitch;
  const Viewport viewport{900, 600};
  // The point under the cursor at the target's depth follows the cursor.
  const Eigen::Vector2f from(500, 250), to(560, 310);
  const Vec3f before = drag_target(p, viewport, from, p.target);
  camera_pan(p, viewport, to.x() - from.x(), to.y() - from.y());
  const Vec3f after = drag_target(p, viewport, to, p.target);
  CHECK((after - before).norm() < 1e-3f * p.distance);
  CHECK(p.distance == distance);
  CHECK(p.yaw == yaw);
  CHECK(p.pitch == pitch);
  // The pan moved the target in the view plane only.
  CHECK(std::abs((p.target - target).dot(camera_forward(p))) < 1e-5f);

  Camera z = frame_box(box, 1.5f);
  camera_zoom(z, 0.5f, 1.0f);
  CHECK(z.distance == doctest::Approx(0.5f * distance));
  CHECK((z.target - target).norm() < 1e-6f);
  CHECK(z.z_near < z.distance - 1.0f + 1e-3f);  // the object stays beyond the near plane
  CHECK(z.z_far > z.distance + 1.0f);
  camera_zoom(z, 1e-9f, 1.0f);
  CHECK(z.distance > 0.0f);
  camera_zoom(z, std::nanf(""), 1.0f);
  CHECK(std::isfinite(z.distance));
}

TEST_CASE("grab: drags stay in the camera plane") {
  const Aabb box = unit_box();
  const Camera c = frame_box(box, 1.0f);
  const Viewport viewport{400, 400};
  const Vec3f eye = camera_eye(c), f = camera_forward(c);
  const Vec3f front = eye + 0.8f * c.distance * f;
  const Vec3f moved = drag_target(c, viewport, {260, 180}, front);
  CHECK((moved - eye).dot(f) == doctest::Approx((front - eye).dot(f)).epsilon(1e-4));
}

TEST_CASE("scene panel: edits pass the scene file's validation, bad values are rejected") {
  Scene base = parse_scene(nlohmann::json{{"mesh", "m.obj"}}, "/tmp/scene.json");
  SceneEdit e = scene_edit_of(base);
  Scene out;
  std::string error;
  CHECK(apply_scene_edit(base, e, out, error));
  e.resolution = 64;
  e.sim_resolution = 8;
  e.iterations = 20;
  e.gravity[1] = -3.0;
  REQUIRE(apply_scene_edit(base, e, out, error));
  CHECK(out.pbd.resolution == 64);
  CHECK(out.pbd.sim_resolution == 8);
  CHECK(out.pbd.iterations == 20);
  CHECK(out.pbd.gravity.y() == -3.0);
  CHECK(out.mesh_path == "/tmp/m.obj");

  const auto rejected = [&](auto&& change, const char* key) {
    SceneEdit bad = scene_edit_of(base);
    change(bad);
    std::string why;
    Scene ignored;
    const bool ok = apply_scene_edit(base, bad, ignored, why);
    CHECK_MESSAGE(!ok, key);
    CHECK_MESSAGE(why.find(key) != std::string::npos, why);
  };
  rejected([](SceneEdit& s) { s.resolution = 0; }, "resolution");
  rejected([](SceneEdit& s) { s.resolution = 5000; }, "resolution");
  rejected([](SceneEdit& s) { s.resolution = 128; s.sim_resolution = 24; }, "sim_resolution");
  rejected([](SceneEdit& s) { s.density = -1.0; }, "density");
  rejected([](SceneEdit& s) { s.shape_stiffness = 1.5; }, "shape_stiffness");
  rejected([](SceneEdit& s) { s.dt = 0.0; }, "dt");
  rejected([](SceneEdit& s) { s.iterations = 0; }, "iterations");
  rejected([](SceneEdit& s) { s.scalpel_length = 0.0; }, "length");
  rejected([](SceneEdit& s) { s.mesh[0] = 0; }, "mesh");
  SceneEdit nan_edit = scene_edit_of(base);
  nan_edit.gravity[0] = std::nan("");
  CHECK_FALSE(apply_scene_edit(base, nan_edit, out, error));
}

TEST_CASE("scene panel: a physical material stays one, its E, nu and damping are edited, the model can switch") {
  const Scene base = parse_scene(
      nlohmann::json{{"mesh", "m.obj"},
                     {"material", {{"youngs_modulus", 5400.0}, {"poisson_ratio", 0.47}, {"density", 1060.0}, {"stiffness_damping", 0.01}}}},
      "/tmp/scene.json");
  REQUIRE(base.pbd.elastic == ElasticModel::kNeoHookean);
  SceneEdit e = scene_edit_of(base);
  CHECK(e.physical);
  Scene out;
  std::string error;
  // Unchanged: the same material, not the paper's model (what the panel wrote before).
  REQUIRE(apply_scene_edit(base, e, out, error));
  CHECK(out.pbd.elastic == ElasticModel::kNeoHookean);
  CHECK(out.pbd.youngs_modulus == 5400.0);
  CHECK(out.pbd.poisson_ratio == 0.47);
  CHECK(out.pbd.stiffness_damping == 0.01);
  CHECK(out.pbd.density == 1060.0);
  e.youngs_modulus = 20000.0;
  e.poisson_ratio = 0.3;
  e.stiffness_damping = 0.002;
  REQUIRE(apply_scene_edit(base, e, out, error));
  CHECK(out.pbd.youngs_modulus == 20000.0);
  CHECK(out.pbd.poisson_ratio == 0.3);
  CHECK(out.pbd.stiffness_damping == 0.002);
  // Bad values are named by their key.
  for (const auto& [change, key] : std::vector<std::pair<void (*)(SceneEdit&), const char*>>{
           {[](SceneEdit& s) { s.poisson_ratio = 0.5; }, "poisson_ratio"},
           {[](SceneEdit& s) { s.youngs_modulus = -1.0; }, "youngs_modulus"},
           {[](SceneEdit& s) { s.stiffness_damping = 100.0; }, "stiffness_damping"}}) {
    SceneEdit bad = scene_edit_of(base);
    change(bad);
    std::string why;
    CHECK_FALSE(apply_scene_edit(base, bad, out, why));
    CHECK_MESSAGE(why.find(key) != std::string::npos, why);
  }
  // Switching to the paper's model writes its keys (and back again).
  e.physical = false;
  e.shape_stiffness = 0.5;
  REQUIRE(apply_scene_edit(base, e, out, error));
  CHECK(out.pbd.elastic == ElasticModel::kPaper);
  CHECK(out.pbd.shape_stiffness == 0.5);
  SceneEdit back = scene_edit_of(out);
  CHECK_FALSE(back.physical);
  back.physical = true;
  REQUIRE(apply_scene_edit(out, back, out, error));
  CHECK(out.pbd.elastic == ElasticModel::kNeoHookean);
}
