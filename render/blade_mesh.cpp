#include "render/blade_mesh.h"

#include <Eigen/Geometry>

#include <cmath>

namespace dvx {
namespace {

void add_triangle(std::vector<SolidVertex>& out, const Vec3f& a, const Vec3f& b, const Vec3f& c, const Vec3f& color) {
  Vec3f n = (b - a).cross(c - a);
  n = n.squaredNorm() > 0.0f ? Vec3f(n.normalized()) : Vec3f(0, 0, 1);
  for (const Vec3f* p : {&a, &b, &c}) {
    out.push_back({{p->x(), p->y(), p->z()}, {n.x(), n.y(), n.z()}, {color.x(), color.y(), color.z(), 1.0f}});
  }
}

// A prism: the convex polygon `ring` (counter-clockwise seen from +normal) extruded by +-half
// along `normal`, with side faces coloured per polygon edge.
void add_prism(std::vector<SolidVertex>& out, const std::vector<Vec3f>& ring, const Vec3f& normal, float half,
               const Vec3f& face_color, const std::vector<Vec3f>& side_colors) {
  const size_t n = ring.size();
  const Vec3f up = half * normal;
  for (size_t k = 1; k + 1 < n; ++k) {
    add_triangle(out, ring[0] + up, ring[k] + up, ring[k + 1] + up, face_color);
    add_triangle(out, ring[0] - up, ring[k + 1] - up, ring[k] - up, face_color);
  }
  for (size_t k = 0; k < n; ++k) {
    const Vec3f &p = ring[k], &q = ring[(k + 1) % n];
    const Vec3f& c = side_colors[k % side_colors.size()];
    add_triangle(out, p - up, q - up, q + up, c);
    add_triangle(out, p - up, q + up, p + up, c);
  }
}

}  // namespace

void scalpel_mesh(const Vec3f& back, const Vec3f& tip, const Vec3f& edge_dir, const ScalpelStyle& style,
                  std::vector<SolidVertex>& out) {
  const Vec3f axis = tip - back;
  const float length = axis.norm();
  if (!(length > 0.0f) || !std::isfinite(length)) return;
  const Vec3f u = axis / length;
  // The edge direction across the blade; any perpendicular when edge_dir is along the axis.
  Vec3f w = edge_dir - edge_dir.dot(u) * u;
  if (w.squaredNorm() < 1e-12f) w = u.unitOrthogonal();
  w.normalize();
  const Vec3f n = u.cross(w);
  const float h = 0.5f * style.blade_width;
  const auto at = [&](const Vec3f& origin, float along, float across) { return Vec3f(origin + along * u + across * w); };

  // Blade (#10 shape): a straight spine on -w, the curved belly (the edge) on +w rising to the tip.
  const std::vector<Vec3f> blade = {at(back, 0.0f, -h),          at(back, length, -h),
                                    at(back, 0.82f * length, 0.25f * h), at(back, 0.55f * length, 0.8f * h),
                                    at(back, 0.25f * length, h),  at(back, 0.0f, h)};
  add_prism(out, blade, n, 0.06f * h, style.blade_color,
            {style.blade_color, style.edge_color, style.edge_color, style.edge_color, style.edge_color, style.blade_color});
  // Handle: a flat bar behind the blade, a little narrower, with a rounded-looking bevelled end.
  const float hl = style.handle_length, hw = 0.7f * h;
  const std::vector<Vec3f> handle = {at(back, -hl, -hw * 0.8f), at(back, 0.0f, -hw), at(back, 0.0f, hw),
                                     at(back, -hl, hw * 0.8f), at(back, -hl - 0.6f * hw, 0.0f)};
  add_prism(out, handle, n, 0.35f * hw, style.handle_color, {style.handle_color});
}

void marker_mesh(const Vec3f& c, float r, const Vec3f& color, std::vector<SolidVertex>& out) {
  const Vec3f x(r, 0, 0), y(0, r, 0), z(0, 0, r);
  const Vec3f px = c + x, nx = c - x, py = c + y, ny = c - y, pz = c + z, nz = c - z;
  add_triangle(out, px, py, pz, color);
  add_triangle(out, py, nx, pz, color);
  add_triangle(out, nx, ny, pz, color);
  add_triangle(out, ny, px, pz, color);
  add_triangle(out, py, px, nz, color);
  add_triangle(out, nx, py, nz, color);
  add_triangle(out, ny, nx, nz, color);
  add_triangle(out, px, ny, nz, color);
}

}  // namespace dvx
