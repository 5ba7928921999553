#include "render/normals.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>

namespace dvx {
namespace {

// atan2(y, x) for y >= 0 (a corner's angle from its sine and cosine, both scaled by the same
// lengths), by an odd polynomial in the smaller ratio (error < 1e-5 rad): one division and no
// square root, where the angle from acos of the normalised dot product took two square roots
// and a division per corner (most of this loop's time: it runs once per snapshot shown).
inline float corner_angle(float y, float x) {
  const float ax = std::abs(x);
  const float lo = std::min(ax, y), hi = std::max(ax, y);
  const float t = hi > 0.0f ? lo / hi : 0.0f, t2 = t * t;
  float a = t * (0.99997726f + t2 * (-0.33262347f + t2 * (0.19354346f + t2 * (-0.11643287f + t2 * (0.05265332f - 0.01172120f * t2)))));
  a = y > ax ? 1.57079633f - a : a;
  return x < 0.0f ? 3.14159265f - a : a;
}

}  // namespace

void split_vertex_normals(const std::vector<Vec3f>& positions, const std::vector<Tri>& triangles,
                          const std::vector<uint8_t>& flags, std::vector<Vec3f>& surface_normals,
                          std::vector<Vec3f>& cut_normals) {
  const uint32_t n = uint32_t(positions.size());
  surface_normals.assign(n, Vec3f::Zero());
  cut_normals.assign(n, Vec3f::Zero());
  const bool have_flags = flags.size() == triangles.size();
  // Per triangle: the unit face normal times each corner's angle. The corner's sine is |face| /
  // (|a| |b|) and its cosine a.b / (|a| |b|): the angle is atan2(|face|, a.b), the lengths cancel.
  for (size_t t = 0; t < triangles.size(); ++t) {
    const Tri& tri = triangles[t];
    if (tri[0] >= n || tri[1] >= n || tri[2] >= n) continue;
    const Vec3f &p0 = positions[tri[0]], &p1 = positions[tri[1]], &p2 = positions[tri[2]];
    const Vec3f e01 = p1 - p0, e02 = p2 - p0, e12 = p2 - p1;
    Vec3f face = e01.cross(e02);
    const float len2 = face.squaredNorm();
    if (!(len2 > 1e-30f) || !std::isfinite(len2)) continue;
    const float len = std::sqrt(len2);
    face /= len;
    Vec3f* out = (have_flags && (flags[t] & 1) != 0 ? cut_normals : surface_normals).data();
    out[tri[0]] += corner_angle(len, e01.dot(e02)) * face;
    out[tri[1]] += corner_angle(len, -e01.dot(e12)) * face;
    out[tri[2]] += corner_angle(len, e02.dot(e12)) * face;
  }
  for (std::vector<Vec3f>* v : {&surface_normals, &cut_normals}) {
    for (Vec3f& x : *v) {
      const float len2 = x.squaredNorm();
      if (len2 > 0.0f) x /= std::sqrt(len2);
    }
  }
}

}  // namespace dvx
