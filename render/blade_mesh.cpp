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
  // Neck: a narrow stem continuing the blade's axis behind its back end.
  const float hl = style.handle_length, hw = 0.7f * h, neck = 0.15f * hl;
  const std::vector<Vec3f> stem = {at(back, -neck, -0.25f * h), at(back, 0.0f, -0.3f * h), at(back, 0.0f, 0.3f * h),
                                   at(back, -neck, 0.25f * h)};
  add_prism(out, stem, n, 0.2f * hw, style.handle_color, {style.handle_color});
  // Handle: a flat bar from the neck, leaning off the blade's plane (toward -n, by handle_lean), with
  // a rounded-looking bevelled end. The incision runs in the blade's plane, and the eye looks nearly
  // along the blade, so a handle in line with it covered the line just cut whenever the stroke moved
  // down the screen; leaning off the plane, it stands beside the line whichever way the blade moves.
  const Vec3f root = back - neck * u;
  const Vec3f handle_axis = (u * std::cos(style.handle_lean) + n * std::sin(style.handle_lean)).normalized();
  const Vec3f across = handle_axis.cross(w);  // the handle's own plane normal (as n is the blade's)
  const auto on_handle = [&](float along, float side) { return Vec3f(root + along * handle_axis + side * w); };
  const std::vector<Vec3f> handle = {on_handle(-hl, -hw * 0.8f), on_handle(0.0f, -hw), on_handle(0.0f, hw),
                                     on_handle(-hl, hw * 0.8f), on_handle(-hl - 0.6f * hw, 0.0f)};
  add_prism(out, handle, across, 0.35f * hw, style.handle_color, {style.handle_color});
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
