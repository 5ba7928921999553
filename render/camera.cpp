#include "render/camera.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>

namespace dvx {

Vec3f camera_forward(const Camera& c) {
  // The eye's offset from the target is (cos p sin y, sin p, cos p cos y); forward is its opposite.
  const float cp = std::cos(c.pitch), sp = std::sin(c.pitch);
  return -Vec3f(cp * std::sin(c.yaw), sp, cp * std::cos(c.yaw));
}

Vec3f camera_right(const Camera& c) { return Vec3f(std::cos(c.yaw), 0.0f, -std::sin(c.yaw)); }

Vec3f camera_up(const Camera& c) { return camera_right(c).cross(camera_forward(c)); }

Vec3f camera_eye(const Camera& c) { return c.target - c.distance * camera_forward(c); }

Eigen::Matrix4f view_matrix(const Camera& c) {
  // Rows: right, up, -forward (eye space looks along -z), then the eye moved to the origin.
  const Vec3f r = camera_right(c), u = camera_up(c), f = camera_forward(c), eye = camera_eye(c);
  Eigen::Matrix4f m = Eigen::Matrix4f::Identity();
  m.block<1, 3>(0, 0) = r.transpose();
  m.block<1, 3>(1, 0) = u.transpose();
  m.block<1, 3>(2, 0) = -f.transpose();
  m(0, 3) = -r.dot(eye);
  m(1, 3) = -u.dot(eye);
  m(2, 3) = f.dot(eye);
  return m;
}

Eigen::Matrix4f projection_matrix(const Camera& c, float aspect) {
  const float f = 1.0f / std::tan(0.5f * c.fov_y);
  const float n = c.z_near, fa = c.z_far;
  Eigen::Matrix4f m = Eigen::Matrix4f::Zero();
  m(0, 0) = f / aspect;
  m(1, 1) = f;
  m(2, 2) = (fa + n) / (n - fa);
  m(2, 3) = 2.0f * fa * n / (n - fa);
  m(3, 2) = -1.0f;
  return m;
}

Camera frame_box(const Aabb& box, float aspect) {
  Camera c;
  c.yaw = 25.0f * 3.14159265f / 180.0f;
  c.pitch = 20.0f * 3.14159265f / 180.0f;
  if (box.empty()) return c;
  c.target = (0.5 * (box.min + box.max)).cast<float>();
  // The nearest eye distance at which every corner projects inside 1/1.1 of the half-image on both
  // axes: a corner at offset o from the target lies at depth d + o.f, so it needs
  // |o.r| <= tan_x (d + o.f) / 1.1 and |o.u| <= tan_y (d + o.f) / 1.1.
  const Vec3f f = camera_forward(c), r = camera_right(c), u = camera_up(c);
  const float tan_y = std::tan(0.5f * c.fov_y), tan_x = aspect * tan_y;
  const Vec3f half = (0.5 * box.extent()).cast<float>();
  const float radius = std::max(half.norm(), 1e-6f);
  float distance = 1.1f * radius;  // never inside the bounding sphere
  for (int k = 0; k < 8; ++k) {
    const Vec3f o(k & 1 ? half.x() : -half.x(), k & 2 ? half.y() : -half.y(), k & 4 ? half.z() : -half.z());
    distance = std::max(distance, 1.1f * std::abs(o.dot(r)) / tan_x - o.dot(f));
    distance = std::max(distance, 1.1f * std::abs(o.dot(u)) / tan_y - o.dot(f));
  }
  c.distance = distance;
  // The object's nearest point is beyond distance - radius > 0.09 distance; near leaves room to
  // zoom in, far to zoom out.
  c.z_near = 0.05f * c.distance;
  c.z_far = c.distance + 4.0f * radius;
  return c;
}

Vec3f ray_direction(const Camera& c, const Viewport& viewport, const Eigen::Vector2f& pixel) {
  // Pixel -> normalised device coordinates (y up), then through the view frustum.
  const float w = float(std::max(viewport.width, 1)), h = float(std::max(viewport.height, 1));
  const float ndc_x = 2.0f * pixel.x() / w - 1.0f;
  const float ndc_y = 1.0f - 2.0f * pixel.y() / h;
  const float t = std::tan(0.5f * c.fov_y);
  const Vec3f d = camera_forward(c) + ndc_x * t * (w / h) * camera_right(c) + ndc_y * t * camera_up(c);
  return d.normalized();
}

}  // namespace dvx
