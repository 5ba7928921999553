// The window's input mapping as plain maths (no GL, no GLFW, no ImGui), unit-tested without a
// window: the cursor ray, the scalpel pose under the cursor, the orbit camera's mouse moves, grab
// picking, and the validation of the scene panel's edits.
#pragma once

#include "engine/scene.h"
#include "render/camera.h"
#include "sim/blade_sweep.h"

#include <Eigen/Core>

#include <string>
#include <vector>

namespace dvx {

struct Ray {
  Vec3f origin = Vec3f::Zero();
  Vec3f direction = Vec3f(0, 0, -1);  // unit
};

// The ray from the eye through a pixel (image coordinates: x right, y down, origin top-left).
Ray cursor_ray(const Camera& camera, const Viewport& viewport, const Eigen::Vector2f& pixel);

// Slab test: the parameters where the ray enters and leaves the box (t_enter may be negative when
// the origin is inside). False when the ray misses the box or the box lies behind the origin.
bool ray_box(const Ray& ray, const Aabb& box, float& t_enter, float& t_exit);

// The scalpel under the cursor: the blade lies along the cursor ray, from its first hit with the
// object's bounding box (or `depth` along the ray when depth > 0: the depth set with ctrl+wheel)
// extending `length` deeper. A ray that misses the box (and no depth set) puts the blade's start
// at the depth of the camera target.
struct CursorBlade {
  BladePose pose;
  bool hits_box = false;
  float depth = 0.0f;  // distance from the eye to the blade's start along the ray
};
CursorBlade blade_from_cursor(const Camera& camera, const Viewport& viewport, const Eigen::Vector2f& pixel,
                              const Aabb& box, double length, float depth = 0.0f);

// Surface picking: the nearest triangle the ray crosses (either side; Moller-Trumbore) among live
// slots (kDeadIndex and non-finite corners skipped). Triangles whose flags share a bit with
// `skip_flags` are ignored (during a drag the scalpel ignores cut faces, so it does not dive into
// the slit it just opened). False when the ray hits nothing in front of `t_min`.
struct SurfaceHit {
  float t = 0.0f;        // distance along the ray
  uint32_t triangle = 0;  // slot
  Vec3f point = Vec3f::Zero();
};
bool pick_surface(const Ray& ray, const std::vector<Vec3f>& positions, const std::vector<Tri>& triangles,
                  const std::vector<uint8_t>& flags, uint8_t skip_flags, float t_min, SurfaceHit& hit);

// The scalpel aimed at a surface point: the blade enters at `entry` (on the surface under the
// cursor) and goes `depth` into the tissue along the cursor ray tilted by `tilt` radians toward the
// bottom of the screen (a pen-held scalpel: tilted, the blade's depth shows on screen; untilted it
// would be seen end-on). The sweep starts `lead` before the entry, so the surface itself is cut.
BladePose scalpel_pose(const Camera& camera, const Ray& ray, const Vec3f& entry, double depth, double lead,
                       float tilt = 0.35f);

// Camera moves by mouse. Orbit: yaw/pitch by pixels dragged (pitch kept within +-89 degrees);
// target and distance unchanged. Pan: the target moves in the view plane so the point under the
// cursor at the target's depth follows the cursor; distance and angles unchanged. Zoom: distance
// times `factor` (clamped), target and angles unchanged; clip planes follow (object radius `radius`).
void camera_orbit(Camera& camera, float dx_pixels, float dy_pixels, float radians_per_pixel = 0.006f);
void camera_pan(Camera& camera, const Viewport& viewport, float dx_pixels, float dy_pixels);
void camera_zoom(Camera& camera, float factor, float radius);

// Grab picking: the frontmost live position (finite) within `radius_pixels` of the cursor ray.
// False when none is.
bool pick_point(const Camera& camera, const Viewport& viewport, const Eigen::Vector2f& pixel,
                const std::vector<Vec3f>& positions, float radius_pixels, Vec3f& picked);
// Where a grabbed point goes when the cursor moves: the point of the cursor ray at the same view
// depth as `anchor` (the drag stays in the camera plane through the picked point).
Vec3f drag_target(const Camera& camera, const Viewport& viewport, const Eigen::Vector2f& pixel, const Vec3f& anchor);

// The scene panel's editable values.
struct SceneEdit {
  char mesh[512] = {};
  int resolution = 128;
  int sim_resolution = 16;
  double density = 1000.0, stretch_compliance = 1e-6, shape_stiffness = 1.0;
  double dt = 1.0 / 60.0;
  int substeps = 1, iterations = 10;
  double damping = 0.01;
  double gravity[3] = {0.0, -9.81, 0.0};
  double scalpel_length = 0.5;
};
SceneEdit scene_edit_of(const Scene& scene);
// The scene with the edits applied, validated by the scene file's own rules (parse_scene): false
// with the reason ("sim_resolution: ...") when a value is out of range.
bool apply_scene_edit(const Scene& base, const SceneEdit& edit, Scene& out, std::string& error);

// "WxH" with 16 <= W, H <= 8192.
bool parse_window_size(const std::string& text, int& width, int& height);

}  // namespace dvx
