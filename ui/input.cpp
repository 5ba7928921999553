#include "ui/input.h"

#include "engine/errors.h"
#include "render/renderer.h"
#include "sim/cut.h"

#include <Eigen/Geometry>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>

namespace dvx {

Ray cursor_ray(const Camera& camera, const Viewport& viewport, const Eigen::Vector2f& pixel) {
  return {camera_eye(camera), ray_direction(camera, viewport, pixel)};
}

bool pick_surface(const Ray& ray, const std::vector<Vec3f>& positions, const std::vector<Tri>& triangles,
                  const std::vector<uint8_t>& flags, uint8_t skip_flags, float t_min, SurfaceHit& hit,
                  std::vector<Eigen::Vector2f>* scratch, Facing facing) {
  const uint32_t n = uint32_t(positions.size());
  const bool have_flags = flags.size() == triangles.size();
  float best = std::numeric_limits<float>::infinity();
  uint32_t best_tri = kDeadIndex;
  const Vec3f& o = ray.origin;
  const Vec3f& d = ray.direction;
  // Every vertex projected onto the plane across the ray (coordinates along two axes normal to it,
  // the ray at the origin): a triangle whose corners all lie on one side of an axis cannot be hit,
  // which rejects nearly all of them with a few comparisons before the exact test.
  std::vector<Eigen::Vector2f> local;
  std::vector<Eigen::Vector2f>& plane = scratch ? *scratch : local;
  const Vec3f u = d.unitOrthogonal(), w = d.cross(u);
  plane.resize(n);
  for (uint32_t v = 0; v < n; ++v) {
    const Vec3f q = positions[v] - o;
    plane[v] = Eigen::Vector2f(q.dot(u), q.dot(w));
  }
  for (uint32_t k = 0; k < uint32_t(triangles.size()); ++k) {
    const Tri& t = triangles[k];
    if (t[0] >= n || t[1] >= n || t[2] >= n) continue;  // dead slot
    if (have_flags && (flags[k] & skip_flags) != 0) continue;
    const Eigen::Vector2f &a = plane[t[0]], &b = plane[t[1]], &c = plane[t[2]];
    if ((a.x() > 0.0f && b.x() > 0.0f && c.x() > 0.0f) || (a.x() < 0.0f && b.x() < 0.0f && c.x() < 0.0f) ||
        (a.y() > 0.0f && b.y() > 0.0f && c.y() > 0.0f) || (a.y() < 0.0f && b.y() < 0.0f && c.y() < 0.0f)) {
      continue;
    }
    // Moller-Trumbore, two-sided.
    const Vec3f& p0 = positions[t[0]];
    const Vec3f e1 = positions[t[1]] - p0, e2 = positions[t[2]] - p0;
    const Vec3f q = d.cross(e2);
    const float det = e1.dot(q);
    if (!(std::abs(det) > 1e-20f)) continue;  // parallel, degenerate or NaN
    // det = -d . (e1 x e2): positive where the ray enters through the outward-facing side.
    if ((facing == Facing::kEntering && det < 0.0f) || (facing == Facing::kLeaving && det > 0.0f)) continue;
    const float inv = 1.0f / det;
    const Vec3f s = o - p0;
    const float u = s.dot(q) * inv;
    if (u < 0.0f || u > 1.0f) continue;
    const Vec3f r = s.cross(e1);
    const float v = d.dot(r) * inv;
    if (v < 0.0f || u + v > 1.0f) continue;
    const float dist = e2.dot(r) * inv;
    if (dist > t_min && dist < best) {
      best = dist;
      best_tri = k;
    }
  }
  if (best_tri == kDeadIndex) return false;
  hit.t = best;
  hit.triangle = best_tri;
  hit.point = o + best * d;
  return true;
}

bool nearest_surface_depth(const Ray& ray, const std::vector<Vec3f>& positions, const std::vector<Tri>& triangles,
                           float t_min, float& t) {
  const uint32_t n = uint32_t(positions.size());
  float best = std::numeric_limits<float>::infinity();  // tangent of the angle from the ray
  for (const Tri& tri : triangles) {
    if (tri[0] >= n || tri[1] >= n || tri[2] >= n) continue;  // dead slot
    for (uint32_t v : tri) {
      const Vec3f q = positions[v] - ray.origin;
      const float along = q.dot(ray.direction);
      if (!(along > t_min)) continue;  // behind, or NaN
      const float off = (q - along * ray.direction).norm() / along;
      if (off < best) {
        best = off;
        t = along;
      }
    }
  }
  return std::isfinite(best);
}

BladePose scalpel_pose(const Camera& camera, const Ray& ray, const Vec3f& entry, double depth, double lead,
                       float tilt) {
  // Tilt the ray toward the screen's bottom (rotate about the axis right x ray).
  const Vec3f down = -camera_up(camera);
  Vec3f side = down - down.dot(ray.direction) * ray.direction;
  Vec3f dir = ray.direction;
  if (side.squaredNorm() > 1e-12f) dir = std::cos(tilt) * ray.direction + std::sin(tilt) * side.normalized();
  const Vec3d e = entry.cast<double>(), u = dir.cast<double>().normalized();
  BladePose pose;
  pose.a = e - lead * u;
  pose.b = e + depth * u;
  return pose;
}

TissueUnderRay tissue_under_ray(const Camera& camera, const Ray& ray, const std::vector<Vec3f>& positions,
                                const std::vector<Tri>& triangles, const std::vector<uint8_t>& flags, bool dragging,
                                float voxel, std::vector<Eigen::Vector2f>* scratch) {
  TissueUnderRay t;
  const uint8_t skip = dragging ? kTriangleCut : 0;
  t.hit = pick_surface(ray, positions, triangles, flags, skip, camera.z_near, t.entry, scratch,
                       dragging ? Facing::kEntering : Facing::kBoth);
  if (!t.hit) return t;
  const BladePose line = scalpel_pose(camera, ray, t.entry.point, 1.0, 0.0);
  const Ray inward{t.entry.point, (line.b - line.a).cast<float>().normalized()};
  t.exits = pick_surface(inward, positions, triangles, flags, skip, 0.5f * voxel, t.exit, scratch, Facing::kLeaving);
  if (t.exits) t.through = t.exit.t + kReachPastFarSide * voxel;
  return t;
}

BladePose reach_through_along_blade(const BladePose& pose, const std::vector<Vec3f>& positions,
                                    const std::vector<Tri>& triangles, const std::vector<uint8_t>& flags, double voxel,
                                    double max_extra, std::vector<Eigen::Vector2f>* scratch) {
  const Vec3d d = pose.b - pose.a;
  const double length = d.norm();
  if (!(length > 0.0)) return pose;
  const Vec3f u = (d / length).cast<float>();
  // The first tissue the blade's line enters within the blade, and where the line leaves it.
  SurfaceHit entry, exit;
  const Ray line{pose.a.cast<float>(), u};
  if (!pick_surface(line, positions, triangles, flags, kTriangleCut, 0.0f, entry, scratch, Facing::kEntering) ||
      double(entry.t) >= length) {
    return pose;
  }
  const Ray inward{entry.point, u};
  if (!pick_surface(inward, positions, triangles, flags, kTriangleCut, 0.5f * float(voxel), exit, scratch,
                    Facing::kLeaving)) {
    return pose;
  }
  const double need = double(entry.t) + double(exit.t) + kReachPastFarSide * voxel;
  if (need <= length) return pose;
  BladePose out = pose;
  out.b = pose.a + std::min(need, length + max_extra) / length * d;
  return out;
}

BladePose cover_crossed_path(const Camera& camera, const Viewport& viewport, const Eigen::Vector2f& from_pixel,
                             const Eigen::Vector2f& to_pixel, const BladePose& from, const BladePose& to,
                             const std::vector<Vec3f>& positions, const std::vector<Tri>& triangles,
                             const std::vector<uint8_t>& flags, double depth, double voxel,
                             std::vector<Eigen::Vector2f>* scratch, CoverStats* stats, float step_pixels,
                             uint32_t max_samples) {
  CoverStats local;
  CoverStats& st = stats ? *stats : local;
  const float pixels = (to_pixel - from_pixel).norm();
  const Vec3d top_move = to.a - from.a, tip_move = to.b - from.b;
  const double blade = (to.b - to.a).norm();
  if (pixels <= step_pixels || blade <= 0.0 || top_move.squaredNorm() <= 0.0) return to;
  const Vec3d u = (to.b - to.a) / blade;  // the new pose's direction: into the tissue
  const uint32_t n = std::min(max_samples, uint32_t(pixels / step_pixels));
  double raise = 0.0, lower = 0.0;
  for (uint32_t i = 1; i <= n; ++i) {
    // The scalpel aimed at this point of the screen path, as aim_scalpel aims it at a frame.
    const float f = float(i) / float(n + 1);
    const Ray ray = cursor_ray(camera, viewport, from_pixel + f * (to_pixel - from_pixel));
    ++st.samples;
    const TissueUnderRay tissue = tissue_under_ray(camera, ray, positions, triangles, flags, true, float(voxel), scratch);
    if (!tissue.hit) continue;
    ++st.hits;
    const Vec3f entry = tissue.entry.point;
    const BladePose aim = scalpel_pose(camera, ray, entry, 1.0, 0.0);
    const double reach = tissue.exits ? std::max(depth, double(tissue.exit.t) + kReachPastFarSide * voxel) : depth;
    const Vec3d e = entry.cast<double>();
    const Vec3d reach_point = e + reach * (aim.b - aim.a).normalized();
    // Where along the sweep the blade passes this point: its projection on the top's path.
    const double s = std::clamp((e - from.a).dot(top_move) / top_move.squaredNorm(), 0.0, 1.0);
    if (s < 0.1) continue;
    // The top at s must lie `voxel` before the entry along the blade; raising the new top by r moves
    // the top at s by s r. Likewise the tip must lie past the reach point.
    const Vec3d top = from.a + s * top_move, tip = from.b + s * tip_move;
    raise = std::max(raise, (voxel - (e - top).dot(u)) / s);
    lower = std::max(lower, (-(tip - reach_point).dot(u)) / s);
  }
  // A sample far off the blade's line (another part of the organ behind the path) must not make a
  // blade many times longer: each end moves by at most twice the blade's length.
  raise = std::clamp(raise, 0.0, 2.0 * blade);
  lower = std::clamp(lower, 0.0, 2.0 * blade);
  st.raised = raise;
  st.lowered = lower;
  BladePose pose = to;
  pose.a -= raise * u;
  pose.b += lower * u;
  return pose;
}

void camera_orbit(Camera& camera, float dx, float dy, float radians_per_pixel) {
  constexpr float kPi = 3.14159265358979f;
  constexpr float kMaxPitch = 89.0f * kPi / 180.0f;
  camera.yaw = std::remainder(camera.yaw - dx * radians_per_pixel, 2.0f * kPi);
  camera.pitch = std::clamp(camera.pitch + dy * radians_per_pixel, -kMaxPitch, kMaxPitch);
}

void camera_pan(Camera& camera, const Viewport& viewport, float dx, float dy) {
  // World units per pixel at the target's depth.
  const float per_pixel = 2.0f * camera.distance * std::tan(0.5f * camera.fov_y) / float(std::max(viewport.height, 1));
  camera.target += per_pixel * (-dx * camera_right(camera) + dy * camera_up(camera));
}

void camera_zoom(Camera& camera, float factor, float radius) {
  if (!(factor > 0.0f) || !std::isfinite(factor)) return;
  radius = std::max(radius, 1e-6f);
  camera.distance = std::clamp(camera.distance * factor, 0.02f * radius, 200.0f * radius);
  camera.z_near = std::max(0.01f * camera.distance, 1e-5f * radius);
  camera.z_far = camera.distance + 4.0f * radius;
}

Vec3f drag_target(const Camera& camera, const Viewport& viewport, const Eigen::Vector2f& pixel, const Vec3f& anchor) {
  const Ray ray = cursor_ray(camera, viewport, pixel);
  const Vec3f forward = camera_forward(camera);
  const float depth = (anchor - ray.origin).dot(forward);
  const float along = ray.direction.dot(forward);
  if (along < 1e-6f) return anchor;
  return ray.origin + (depth / along) * ray.direction;
}

SceneEdit scene_edit_of(const Scene& scene) {
  SceneEdit e;
  std::snprintf(e.mesh, sizeof e.mesh, "%s", scene.mesh.c_str());
  e.resolution = scene.pbd.resolution;
  e.sim_resolution = scene.pbd.sim_resolution;
  e.physical = scene.pbd.elastic == ElasticModel::kNeoHookean;
  e.youngs_modulus = scene.pbd.youngs_modulus;
  e.poisson_ratio = scene.pbd.poisson_ratio;
  e.stiffness_damping = scene.pbd.stiffness_damping;
  e.global_step = scene.pbd.global_step;
  e.density = scene.pbd.density;
  e.stretch_compliance = scene.pbd.stretch_compliance;
  e.shape_stiffness = scene.pbd.shape_stiffness;
  e.dt = scene.pbd.dt;
  e.substeps = scene.pbd.substeps;
  e.iterations = scene.pbd.iterations;
  e.damping = scene.pbd.damping;
  for (int k = 0; k < 3; ++k) e.gravity[k] = scene.pbd.gravity[k];
  e.scalpel_length = scene.scalpel.length;
  return e;
}

bool apply_scene_edit(const Scene& base, const SceneEdit& e, Scene& out, std::string& error) {
  // Through the scene file's own writer and validation, so the panel accepts exactly what a file may
  // hold (and writes only the chosen material model's keys, as a file does).
  Scene edited = base;
  edited.mesh = e.mesh;
  PbdParams& p = edited.pbd;
  p.resolution = e.resolution;
  p.sim_resolution = e.sim_resolution;
  p.elastic = e.physical ? ElasticModel::kNeoHookean : ElasticModel::kPaper;
  p.density = e.density;
  p.youngs_modulus = e.youngs_modulus;
  p.poisson_ratio = e.poisson_ratio;
  p.stiffness_damping = e.stiffness_damping;
  p.global_step = e.physical && e.global_step;
  p.stretch_compliance = e.stretch_compliance;
  p.shape_stiffness = e.shape_stiffness;
  p.dt = e.dt;
  p.substeps = e.substeps;
  p.iterations = e.iterations;
  p.damping = e.damping;
  p.gravity = Vec3d(e.gravity[0], e.gravity[1], e.gravity[2]);
  edited.scalpel.length = e.scalpel_length;
  const nlohmann::json j = scene_to_json(edited);
  for (double v : {e.density, e.youngs_modulus, e.poisson_ratio, e.stiffness_damping, e.stretch_compliance,
                   e.shape_stiffness, e.dt, e.damping, e.scalpel_length, e.gravity[0], e.gravity[1], e.gravity[2]}) {
    if (!std::isfinite(v)) {
      error = "values must be finite numbers";
      return false;
    }
  }
  try {
    out = parse_scene(j, base.file);
  } catch (const InputError& ex) {
    error = ex.what();
    // Drop the "FILE: " prefix: the panel names the key.
    if (!base.file.empty() && error.rfind(base.file + ": ", 0) == 0) error = error.substr(base.file.size() + 2);
    return false;
  }
  return true;
}

}  // namespace dvx
