// Trays under the organ and the organ's planar shadow on them (render/renderer.h: TrayPlane).
#include "render/gl_program.h"
#include "render/renderer.h"

#include <Eigen/Geometry>
#include <glad/gl.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace dvx {

TrayPlane tray_under(const Vec3f& bounds_min, const Vec3f& bounds_max, const Vec3f& plane_point,
                     const Vec3f& plane_normal) {
  const Vec3f centre = 0.5f * (bounds_min + bounds_max);
  TrayPlane tray;
  tray.normal = plane_normal;
  tray.centre = centre - (centre - plane_point).dot(plane_normal) * plane_normal;
  tray.half_size = 1.5f * (bounds_max - bounds_min).maxCoeff();  // see renderer.h
  return tray;
}
namespace {

// The tray: a rectangle of its square from gl_VertexID (a 4-vertex strip): u_rect's corners in the
// square's coordinates ([-1, 1] along each axis), lit by the camera's key light like the surface, with
// a darker lip along its border. The square is drawn as a 3 x 3 grid of such rectangles (tray_draw):
// rectangles that share an edge compute its corners from the same floats, so they meet without cracks.
const char* kTrayVertexShader = R"(#version 450 core
layout(location = 0) uniform mat4 u_view_projection;
layout(location = 2) uniform vec3 u_centre;
layout(location = 3) uniform vec3 u_axis_u;
layout(location = 4) uniform vec3 u_axis_v;
layout(location = 5) uniform vec4 u_rect;  // (u0, v0, u1, v1)
out vec2 v_uv;
void main() {
  vec2 c = vec2((gl_VertexID & 1) != 0 ? u_rect.z : u_rect.x, (gl_VertexID & 2) != 0 ? u_rect.w : u_rect.y);
  vec3 p = u_centre + c.x * u_axis_u + c.y * u_axis_v;
  v_uv = c;
  gl_Position = u_view_projection * vec4(p, 1.0);
}
)";

// Flat and directionally lit, so its shade is one colour per tray (u_shade, from the CPU); per pixel
// only the lip and, in the SHADOW variant, the shadow (one bilinear fetch of the shadow grid). The
// tray covers much of the view and a software rasteriser pays per pixel: on llvmpipe the fetch over
// the whole tray cost ~1.5 ms of the rasteriser's threads per image, so only the rectangle around
// the shadow's cells (Renderer::shadow_box) samples it; outside, the grid is 0 and the flat variant
// gives the same colour.
const char* kTrayFragmentShader = R"(
layout(location = 6) uniform vec3 u_shade;
#if SHADOW
layout(location = 7) uniform float u_shadow_alpha;
layout(binding = 0) uniform sampler2D u_shadow;
#endif
in vec2 v_uv;
out vec4 frag_color;
void main() {
  float r = max(abs(v_uv.x), abs(v_uv.y));
#if SHADOW
  float shadow = u_shadow_alpha * texture(u_shadow, 0.5 * v_uv + 0.5).r;
#else
  float shadow = 0.0;
#endif
  frag_color = vec4(u_shade * ((r > 0.94 ? 0.6 : 1.0) * (1.0 - shadow)), 1.0);
}
)";

// Two unit vectors spanning the plane of normal n.
void plane_axes(const Vec3f& n, Vec3f& u, Vec3f& v) {
  const Vec3f helper = std::abs(n.x()) < 0.9f ? Vec3f::UnitX() : Vec3f::UnitY();
  u = n.cross(helper).normalized();
  v = n.cross(u);
}

}  // namespace

Vec3f tray_light(const Camera& camera, const Vec3f& normal) {
  const Eigen::Matrix3f rotation = view_matrix(camera).topLeftCorner<3, 3>();
  Vec3f light = rotation.transpose() * Vec3f(-0.4f, 0.6f, 0.7f).normalized();
  const Vec3f n = normal.normalized();
  if (light.dot(n) < 0.5f) light = (light + (0.5f - light.dot(n)) * n).normalized();
  return light;
}

namespace {

// Sums of `values` (g x g, row-major) over every rectangle of cells: (g + 1) x (g + 1), entry
// (y, x) the sum over the cells above and left of it.
void summed_area(const std::vector<float>& values, int g, std::vector<double>& table) {
  table.assign(size_t(g + 1) * size_t(g + 1), 0.0);
  for (int y = 0; y < g; ++y) {
    double row = 0.0;
    for (int x = 0; x < g; ++x) {
      row += values[size_t(y) * g + size_t(x)];
      table[size_t(y + 1) * (g + 1) + size_t(x + 1)] = table[size_t(y) * (g + 1) + size_t(x + 1)] + row;
    }
  }
}

// The sum over the square of cells within `r` (cells) of (x, y), cut to the grid (outside is empty).
double box_sum(const std::vector<double>& table, int g, int x, int y, int r) {
  const int x0 = std::max(x - r, 0), x1 = std::min(x + r + 1, g), y0 = std::max(y - r, 0), y1 = std::min(y + r + 1, g);
  const size_t w = size_t(g + 1);
  return table[size_t(y1) * w + size_t(x1)] - table[size_t(y0) * w + size_t(x1)] - table[size_t(y1) * w + size_t(x0)] +
         table[size_t(y0) * w + size_t(x0)];
}

// A box blur of `in` into `out` whose half-width at each cell is radius[cell] (cells, fractional:
// the blend of the two whole widths around it; outside the grid counts as empty).
void variable_blur(const std::vector<float>& in, const std::vector<float>& radius, int g, std::vector<double>& table,
                   std::vector<float>& out) {
  summed_area(in, g, table);
  out.resize(in.size());
  for (int y = 0; y < g; ++y) {
    for (int x = 0; x < g; ++x) {
      const float r = radius[size_t(y) * g + size_t(x)];
      const int r0 = int(r);
      const float f = r - float(r0);
      const double side0 = 2 * r0 + 1, side1 = side0 + 2;
      const double a = box_sum(table, g, x, y, r0) / (side0 * side0);
      const double b = f > 0.0f ? box_sum(table, g, x, y, r0 + 1) / (side1 * side1) : a;
      out[size_t(y) * g + size_t(x)] = float((1.0 - f) * a + f * b);
    }
  }
}

}  // namespace

void tray_shadow_grid(const Vec3f* positions, uint32_t count, const Tri* triangles, uint32_t triangle_count,
                      const TrayPlane& tray, const Vec3f& light, std::vector<float>& grid, ShadowScratch& scratch) {
  constexpr int g = kTrayShadowGrid;
  const size_t cells = size_t(g) * g;
  grid.assign(cells, 0.0f);
  scratch.area.assign(cells, 0.0f);
  scratch.height.assign(cells, 0.0f);
  const Vec3f n = tray.normal.normalized();
  Vec3f u, v;
  plane_axes(n, u, v);
  const float ln = light.dot(n), scale = 0.5f * float(g) / tray.half_size;  // cells per unit length
  if (!(ln > 0.0f)) return;
  // Every vertex slid along the light onto the plane, in cells (x, y), and its height above the plane.
  scratch.projected.resize(count);
  for (uint32_t k = 0; k < count; ++k) {
    const Vec3f& p = positions[k];
    const float h = (p - tray.centre).dot(n);
    const Vec3f q = p - (h / ln) * light - tray.centre;
    scratch.projected[k] = p.allFinite() ? Vec3f(q.dot(u) * scale + 0.5f * float(g), q.dot(v) * scale + 0.5f * float(g),
                                                 std::max(h, 0.0f))
                                         : Vec3f::Constant(std::numeric_limits<float>::quiet_NaN());
  }
  // The occluders' projected area per cell (cells^2) and its height sum. A closed surface covers its
  // shadow twice (a near side and a far side), so half of each triangle's projected area counts:
  // a cell wholly in the shadow gets 1 and one a small piece covers a part of it that part. Without
  // triangles each vertex covers its whole cell (the splat of a point cloud).
  const auto add = [&](float x, float y, float area, float height) {
    if (!(x >= 0.0f && y >= 0.0f && x < float(g) && y < float(g))) return;
    const size_t cell = size_t(int(y)) * g + size_t(int(x));
    scratch.area[cell] += area;
    scratch.height[cell] += area * height;
  };
  if (triangles != nullptr) {
    for (uint32_t t = 0; t < triangle_count; ++t) {
      const Tri& tri = triangles[t];
      if (tri[0] >= count || tri[1] >= count || tri[2] >= count) continue;
      const Vec3f &a = scratch.projected[tri[0]], &b = scratch.projected[tri[1]], &c = scratch.projected[tri[2]];
      const float area = 0.25f * std::abs((b.x() - a.x()) * (c.y() - a.y()) - (b.y() - a.y()) * (c.x() - a.x()));
      if (!(area > 0.0f) || !std::isfinite(area)) continue;
      const Vec3f m = (a + b + c) * (1.0f / 3.0f);
      // A triangle within a cell's width goes to its centroid's cell; a larger one is shared out
      // between its corners' and its centroid's.
      const float extent = std::max({std::abs(b.x() - a.x()), std::abs(c.x() - a.x()), std::abs(b.y() - a.y()),
                                     std::abs(c.y() - a.y())});
      if (extent < 1.0f) {
        add(m.x(), m.y(), area, m.z());
      } else {
        for (const Vec3f* p : {&a, &b, &c, &m}) add(p->x(), p->y(), 0.25f * area, m.z());
      }
    }
  } else {
    for (uint32_t k = 0; k < count; ++k) {
      const Vec3f& p = scratch.projected[k];
      if (!p.allFinite()) continue;
      const int cx = int(std::floor(p.x())), cy = int(std::floor(p.y()));
      if (cx < 0 || cy < 0 || cx >= g || cy >= g) continue;
      const size_t cell = size_t(cy) * g + size_t(cx);
      if (scratch.area[cell] == 0.0f) {  // the cell's first vertex gives its height
        scratch.area[cell] = 1.0f;
        scratch.height[cell] = p.z();
      }
    }
  }
  // The penumbra: its half-width grows with the occluders' height above the tray (a light of about
  // 7 degrees' radius), from one cell at contact: the mean height of the occluders within 6 cells.
  std::vector<float>& radius = scratch.radius;
  radius.resize(cells);
  summed_area(scratch.area, g, scratch.table);
  std::vector<double>& height_table = scratch.height_table;
  summed_area(scratch.height, g, height_table);
  for (int y = 0; y < g; ++y) {
    for (int x = 0; x < g; ++x) {
      const double area = box_sum(scratch.table, g, x, y, 6);
      const double height = area > 0.0 ? box_sum(height_table, g, x, y, 6) / area : 0.0;
      radius[size_t(y) * g + size_t(x)] = std::min(1.0f + kTrayPenumbra * float(height) * scale, 10.0f);
    }
  }
  // Coverage blurred twice by the penumbra's box, at most 1 after the first (the corners' shares fall
  // unevenly on cells smaller than a triangle: clamped first, the uneven cells left holes): a piece's
  // shadow is as dark as the share of the penumbra's area it covers, so a small piece casts a small,
  // faint shadow.
  variable_blur(scratch.area, radius, g, scratch.table, scratch.blurred);
  for (float& a : scratch.blurred) a = std::min(a, 1.0f);
  variable_blur(scratch.blurred, radius, g, scratch.table, grid);
  for (float& a : grid) a = std::min(a, 1.0f);
}

bool tray_init(Renderer& r, std::string& error) {
  const std::string flat = std::string("#version 450 core\n#define SHADOW 0\n") + kTrayFragmentShader;
  const std::string shadow = std::string("#version 450 core\n#define SHADOW 1\n") + kTrayFragmentShader;
  r.tray_program = gl_link_program(kTrayVertexShader, shadow.c_str(), error);
  if (r.tray_program) r.tray_flat_program = gl_link_program(kTrayVertexShader, flat.c_str(), error);
  if (!r.tray_program || !r.tray_flat_program) return false;
  glCreateVertexArrays(1, &r.empty_vertex_array);
  glCreateTextures(GL_TEXTURE_2D, 1, &r.shadow_texture);
  glTextureStorage2D(r.shadow_texture, 1, GL_R8, kTrayShadowGrid, kTrayShadowGrid);
  glTextureParameteri(r.shadow_texture, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
  glTextureParameteri(r.shadow_texture, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
  glTextureParameteri(r.shadow_texture, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
  glTextureParameteri(r.shadow_texture, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
  return true;
}

void tray_destroy(Renderer& r) {
  if (r.tray_program) glDeleteProgram(r.tray_program);
  if (r.tray_flat_program) glDeleteProgram(r.tray_flat_program);
  if (r.empty_vertex_array) glDeleteVertexArrays(1, &r.empty_vertex_array);
  if (r.shadow_texture) glDeleteTextures(1, &r.shadow_texture);
  r.tray_program = r.tray_flat_program = r.empty_vertex_array = r.shadow_texture = 0;
  r.shadow_valid = false;
}

void tray_shadow_update(Renderer& r, const Vec3f* positions, uint32_t count, const Camera& camera,
                        const DrawOptions& options) {
  r.shadow_valid = false;
  if (!r.shadow_texture || options.trays.empty() || !options.shadows || positions == nullptr) return;
  const TrayPlane& tray = options.trays.front();
  // The uploaded triangles when the positions are the uploaded mesh's vertex slots.
  const bool triangles = count == r.vertex_count && r.shadow_triangles.size() >= r.triangle_count;
  tray_shadow_grid(positions, count, triangles ? r.shadow_triangles.data() : nullptr, triangles ? r.triangle_count : 0,
                   tray, tray_light(camera, tray.normal), r.shadow_grid, r.shadow_scratch);
  r.shadow_bytes.resize(r.shadow_grid.size());
  for (size_t k = 0; k < r.shadow_grid.size(); ++k) {
    r.shadow_bytes[k] = uint8_t(std::lround(255.0f * std::clamp(r.shadow_grid[k], 0.0f, 1.0f)));
  }
  r.shadow_box = tray_shadow_box(r.shadow_bytes.data(), kTrayShadowGrid);
  glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
  glTextureSubImage2D(r.shadow_texture, 0, 0, 0, kTrayShadowGrid, kTrayShadowGrid, GL_RED, GL_UNSIGNED_BYTE,
                      r.shadow_bytes.data());
  r.shadow_valid = true;
}

ShadowBox tray_shadow_box(const uint8_t* cells, int g) {
  ShadowBox box{g, g, 0, 0};
  for (int y = 0; y < g; ++y) {
    for (int x = 0; x < g; ++x) {
      if (cells[size_t(y) * size_t(g) + size_t(x)] == 0) continue;
      box.x0 = std::min(box.x0, x);
      box.y0 = std::min(box.y0, y);
      box.x1 = std::max(box.x1, x + 1);
      box.y1 = std::max(box.y1, y + 1);
    }
  }
  if (box.x0 >= box.x1) return ShadowBox{};
  // Bilinear filtering reaches half a cell past a shaded cell.
  return ShadowBox{std::max(box.x0 - 1, 0), std::max(box.y0 - 1, 0), std::min(box.x1 + 1, g), std::min(box.y1 + 1, g)};
}

void tray_draw(Renderer& r, const Camera& camera, const DrawOptions& options) {
  if (options.trays.empty() || !r.tray_program || !r.tray_flat_program) return;
  const ViewTarget target = renderer_target(r);
  glBindFramebuffer(GL_FRAMEBUFFER, target.framebuffer);
  glViewport(target.x, target.y, target.width, target.height);
  const Eigen::Matrix4f view = view_matrix(camera);
  const Eigen::Matrix4f view_projection = projection_matrix(camera, Viewport{r.width, r.height}.aspect()) * view;
  const Eigen::Matrix3f rotation = view.topLeftCorner<3, 3>();
  const Vec3f eye = camera_eye(camera);
  const Vec3f key_eye = Vec3f(-0.4f, 0.6f, 0.7f).normalized();  // the surface shader's key light
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LEQUAL);
  glDepthMask(GL_TRUE);
  glDisable(GL_CULL_FACE);
  glDisable(GL_BLEND);
  glBindVertexArray(r.empty_vertex_array);
  glBindTextureUnit(0, r.shadow_texture);
  for (size_t k = 0; k < options.trays.size(); ++k) {
    const TrayPlane& tray = options.trays[k];
    const Vec3f n = tray.normal.normalized();
    // Seen from below, a tray would hide the object: it is drawn from above only.
    if ((eye - tray.centre).dot(n) <= 0.0f) continue;
    Vec3f u, v;
    plane_axes(n, u, v);
    const Vec3f axis_u = tray.half_size * u, axis_v = tray.half_size * v;
    // Its shade: ambient + the key light's diffuse.
    const Vec3f facing = rotation * n;
    const Vec3f shade = options.tray_color * (0.30f + 0.55f * std::max(facing.dot(key_eye), 0.0f));
    for (const uint32_t program : {r.tray_program, r.tray_flat_program}) {
      glProgramUniformMatrix4fv(program, 0, 1, GL_FALSE, view_projection.data());
      glProgramUniform3fv(program, 2, 1, tray.centre.data());
      glProgramUniform3fv(program, 3, 1, axis_u.data());
      glProgramUniform3fv(program, 4, 1, axis_v.data());
      glProgramUniform3fv(program, 6, 1, shade.data());
    }
    // The shadow (the first tray's) in the rectangle around its cells, the rest flat: a 3 x 3 grid
    // of rectangles (the middle one shadowed), from the lines at the square's edges and the box's.
    const ShadowBox& b = r.shadow_box;
    const bool shadow = k == 0 && r.shadow_valid && options.shadows && b.x0 < b.x1 && b.y0 < b.y1;
    const float g = float(kTrayShadowGrid);
    const float us[4] = {-1.0f, shadow ? 2.0f * float(b.x0) / g - 1.0f : 1.0f,
                         shadow ? 2.0f * float(b.x1) / g - 1.0f : 1.0f, 1.0f};
    const float vs[4] = {-1.0f, shadow ? 2.0f * float(b.y0) / g - 1.0f : 1.0f,
                         shadow ? 2.0f * float(b.y1) / g - 1.0f : 1.0f, 1.0f};
    if (shadow) glProgramUniform1f(r.tray_program, 7, options.shadow_alpha);
    for (int j = 0; j < 3; ++j) {
      for (int i = 0; i < 3; ++i) {
        if (us[i] >= us[i + 1] || vs[j] >= vs[j + 1]) continue;  // empty (no shadow: one rectangle)
        const uint32_t program = shadow && i == 1 && j == 1 ? r.tray_program : r.tray_flat_program;
        glUseProgram(program);
        glProgramUniform4f(program, 5, us[i], vs[j], us[i + 1], vs[j + 1]);
        glDrawArrays(GL_TRIANGLE_STRIP, 0, 4);
      }
    }
  }
  glBindTextureUnit(0, 0);
  glUseProgram(0);
  glBindVertexArray(0);
}

}  // namespace dvx
