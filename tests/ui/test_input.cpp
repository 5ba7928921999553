// The window's input mapping, without a window: cursor ray -> blade pose, camera mouse moves,
// grab picking, scene panel validation.
#include "ui/input.h"

#include "engine/scene.h"

#include <nlohmann/json.hpp>

#include <doctest/doctest.h>

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

bool on_box_surface(const Vec3d& p, const Aabb& b, double tol) {
  bool inside = true, on_face = false;
  for (int a = 0; a < 3; ++a) {
    inside &= p[a] >= b.min[a] - tol && p[a] <= b.max[a] + tol;
    on_face |= std::abs(p[a] - b.min[a]) < tol || std::abs(p[a] - b.max[a]) < tol;
  }
  return inside && on_face;
}

}  // namespace

TEST_CASE("blade: the blade lies on the cursor ray, starts at the box entry, has the scene's length") {
  const Aabb box = unit_box();
  const Camera camera = frame_box(box, 16.0f / 9.0f);
  const Viewport viewport{1280, 720};
  for (const Eigen::Vector2f pixel : {Eigen::Vector2f(640, 360), Eigen::Vector2f(600.5f, 300.25f), Eigen::Vector2f(700, 420)}) {
    const CursorBlade blade = blade_from_cursor(camera, viewport, pixel, box, 0.75);
    CHECK(blade.hits_box);
    const Ray ray = cursor_ray(camera, viewport, pixel);
    const Vec3d o = ray.origin.cast<double>(), d = ray.direction.cast<double>();
    CHECK(distance_to_line(blade.pose.a, o, d) < 1e-5);
    CHECK(distance_to_line(blade.pose.b, o, d) < 1e-5);
    CHECK((blade.pose.b - blade.pose.a).norm() == doctest::Approx(0.75).epsilon(1e-6));
    CHECK((blade.pose.b - blade.pose.a).dot(d) > 0.0);  // points away from the eye
    CHECK(on_box_surface(blade.pose.a, box, 1e-4));
  }
  // The centre pixel's ray goes through the target (the box centre).
  const CursorBlade centre = blade_from_cursor(camera, viewport, Eigen::Vector2f(640, 360), box, 1.0);
  CHECK(distance_to_line(Vec3d::Zero(), cursor_ray(camera, viewport, {640, 360}).origin.cast<double>(),
                         cursor_ray(camera, viewport, {640, 360}).direction.cast<double>()) < 1e-3);
  CHECK(centre.depth < camera.distance);
}

TEST_CASE("blade: a set depth wins; a ray that misses the box lands at the target's depth") {
  const Aabb box = unit_box();
  const Camera camera = frame_box(box, 1.0f);
  const Viewport viewport{500, 500};
  const CursorBlade deep = blade_from_cursor(camera, viewport, {250, 250}, box, 0.5, 2.5f);
  CHECK(deep.depth == doctest::Approx(2.5f));
  CHECK((deep.pose.a - camera_eye(camera).cast<double>()).norm() == doctest::Approx(2.5).epsilon(1e-5));
  const CursorBlade miss = blade_from_cursor(camera, viewport, {1, 1}, box, 0.5);
  CHECK_FALSE(miss.hits_box);
  const float depth_along_forward = (miss.pose.a.cast<float>() - camera_eye(camera)).dot(camera_forward(camera));
  CHECK(depth_along_forward == doctest::Approx(camera.distance).epsilon(1e-4));
}

TEST_CASE("ray_box: entry, exit, misses and an origin inside") {
  const Aabb box = unit_box();
  float t0 = 0, t1 = 0;
  CHECK(ray_box({Vec3f(0, 0, 5), Vec3f(0, 0, -1)}, box, t0, t1));
  CHECK(t0 == doctest::Approx(4.0f));
  CHECK(t1 == doctest::Approx(6.0f));
  CHECK_FALSE(ray_box({Vec3f(0, 3, 5), Vec3f(0, 0, -1)}, box, t0, t1));
  CHECK_FALSE(ray_box({Vec3f(0, 0, 5), Vec3f(0, 0, 1)}, box, t0, t1));  // box behind
  CHECK(ray_box({Vec3f(0, 0, 0), Vec3f(1, 0, 0)}, box, t0, t1));
  CHECK(t0 < 0.0f);
  CHECK(t1 == doctest::Approx(1.0f));
  CHECK_FALSE(ray_box({Vec3f(0, 0, 5), Vec3f(0, 0, -1)}, Aabb(), t0, t1));  // empty box
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

TEST_CASE("pick: the frontmost point near the cursor ray; drags stay in the camera plane") {
  const Aabb box = unit_box();
  const Camera c = frame_box(box, 1.0f);
  const Viewport viewport{400, 400};
  const Vec3f eye = camera_eye(c), f = camera_forward(c);
  const Vec3f front = eye + 0.8f * c.distance * f, back = eye + 1.2f * c.distance * f;
  const float nan = std::nanf("");
  std::vector<Vec3f> points = {back, front, Vec3f(nan, nan, nan), Vec3f(5, 5, 5)};
  Vec3f picked;
  REQUIRE(pick_point(c, viewport, {200, 200}, points, 4.0f, picked));
  CHECK((picked - front).norm() < 1e-6f);
  CHECK_FALSE(pick_point(c, viewport, {10, 10}, points, 4.0f, picked));
  const Vec3f moved = drag_target(c, viewport, {260, 180}, front);
  CHECK((moved - eye).dot(f) == doctest::Approx((front - eye).dot(f)).epsilon(1e-4));
}

TEST_CASE("scene panel: edits pass the scene file's validation; bad values are rejected") {
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
  CHECK(out.resolution == 64);
  CHECK(out.sim_resolution == 8);
  CHECK(out.solver.iterations == 20);
  CHECK(out.gravity.y() == -3.0);
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

TEST_CASE("size: WxH within [16, 8192]") {
  int w = 0, h = 0;
  CHECK(parse_window_size("1280x720", w, h));
  CHECK(w == 1280);
  CHECK(h == 720);
  CHECK_FALSE(parse_window_size("1280", w, h));
  CHECK_FALSE(parse_window_size("8x8", w, h));
  CHECK_FALSE(parse_window_size("1280x720x3", w, h));
  CHECK_FALSE(parse_window_size("axb", w, h));
}
