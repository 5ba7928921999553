#include "render/normals.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>

namespace dvx {
namespace {

// The angle between a and b. acos by Abramowitz & Stegun 4.4.45 (error < 7e-5 rad): the weights
// need no more, and std::acos is most of this loop's time (3 per triangle, once per frame).
float corner_angle(const Vec3f& a, const Vec3f& b) {
  const float d = std::clamp(a.dot(b) / std::sqrt(a.squaredNorm() * b.squaredNorm()), -1.0f, 1.0f);
  const float x = std::abs(d);
  const float r = std::sqrt(1.0f - x) * (1.5707288f + x * (-0.2121144f + x * (0.0742610f - 0.0187293f * x)));
  return d >= 0.0f ? r : 3.14159265f - r;
}

}  // namespace

void split_vertex_normals(const std::vector<Vec3f>& positions, const std::vector<Tri>& triangles,
                          const std::vector<uint8_t>& flags, std::vector<Vec3f>& surface_normals,
                          std::vector<Vec3f>& cut_normals) {
  const uint32_t n = uint32_t(positions.size());
  surface_normals.assign(n, Vec3f::Zero());
  cut_normals.assign(n, Vec3f::Zero());
  const bool have_flags = flags.size() == triangles.size();
  for (size_t t = 0; t < triangles.size(); ++t) {
    const Tri& tri = triangles[t];
    if (tri[0] >= n || tri[1] >= n || tri[2] >= n) continue;
    const Vec3f &p0 = positions[tri[0]], &p1 = positions[tri[1]], &p2 = positions[tri[2]];
    const Vec3f e01 = p1 - p0, e02 = p2 - p0, e12 = p2 - p1;
    Vec3f face = e01.cross(e02);
    const float len2 = face.squaredNorm();
    if (!(len2 > 1e-30f) || !std::isfinite(len2)) continue;
    face /= std::sqrt(len2);
    std::vector<Vec3f>& out = have_flags && (flags[t] & 1) != 0 ? cut_normals : surface_normals;
    out[tri[0]] += corner_angle(e01, e02) * face;
    out[tri[1]] += corner_angle(-e01, e12) * face;
    out[tri[2]] += corner_angle(-e02, -e12) * face;
  }
  for (std::vector<Vec3f>* v : {&surface_normals, &cut_normals}) {
    for (Vec3f& x : *v) {
      const float len = x.norm();
      x = len > 0.0f ? Vec3f(x / len) : Vec3f::Zero();
    }
  }
}

}  // namespace dvx
