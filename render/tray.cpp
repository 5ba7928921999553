// Trays under the organ and the organ's planar shadow on them (render/renderer.h: TrayPlane).
#include "render/gl_program.h"
#include "render/renderer.h"

#include <Eigen/Geometry>
#include <glad/gl.h>

#include <algorithm>
#include <cmath>

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

// The tray: a square from gl_VertexID (a 4-vertex strip), lit by the camera's key light like the
// surface, with a darker lip along its border.
const char* kTrayVertexShader = R"(#version 450 core
layout(location = 0) uniform mat4 u_view_projection;
layout(location = 1) uniform mat4 u_view;
layout(location = 2) uniform vec3 u_centre;
layout(location = 3) uniform vec3 u_axis_u;
layout(location = 4) uniform vec3 u_axis_v;
out vec2 v_uv;
out vec3 v_eye_position;
void main() {
  vec2 c = vec2((gl_VertexID & 1) != 0 ? 1.0 : -1.0, (gl_VertexID & 2) != 0 ? 1.0 : -1.0);
  vec3 p = u_centre + c.x * u_axis_u + c.y * u_axis_v;
  v_uv = c;
  v_eye_position = (u_view * vec4(p, 1.0)).xyz;
  gl_Position = u_view_projection * vec4(p, 1.0);
}
)";

// Flat and directionally lit, so its shade is one colour per tray (u_shade, from the CPU); per pixel
// only the lip and the shadow (one bilinear fetch of the shadow grid): the tray covers much of the
// view and a software rasteriser pays per pixel.
const char* kTrayFragmentShader = R"(#version 450 core
layout(location = 6) uniform vec3 u_shade;
layout(location = 7) uniform float u_shadow_alpha;  // 0: no shadow on this tray
layout(binding = 0) uniform sampler2D u_shadow;
in vec2 v_uv;
in vec3 v_eye_position;
out vec4 frag_color;
void main() {
  float r = max(abs(v_uv.x), abs(v_uv.y));
  float shadow = u_shadow_alpha > 0.0 ? u_shadow_alpha * texture(u_shadow, 0.5 * v_uv + 0.5).r : 0.0;
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

void tray_shadow_grid(const Vec3f* positions, uint32_t count, const TrayPlane& tray, const Vec3f& light,
                      std::vector<float>& grid, std::vector<float>& scratch) {
  constexpr int g = kTrayShadowGrid;
  grid.assign(size_t(g) * g, 0.0f);
  const Vec3f n = tray.normal.normalized();
  Vec3f u, v;
  plane_axes(n, u, v);
  const float ln = light.dot(n), scale = 0.5f * float(g) / tray.half_size;
  // Splat: every surface vertex slid along the light onto the plane marks its cell (every
  // stride-th one on big surfaces: ~64k points cover the grid's 9k cells many times over).
  const uint32_t stride = std::max(1u, count / 65536u);
  for (uint32_t k = 0; k < count; k += stride) {
    const Vec3f& p = positions[k];
    if (!p.allFinite() || !(ln > 0.0f)) continue;
    const Vec3f q = p - ((p - tray.centre).dot(n) / ln) * light - tray.centre;
    const int x = int(std::floor(q.dot(u) * scale + 0.5f * float(g)));
    const int y = int(std::floor(q.dot(v) * scale + 0.5f * float(g)));
    if (x >= 0 && y >= 0 && x < g && y < g) grid[size_t(y) * g + size_t(x)] = 1.0f;
  }
  // Two 3x3 box blurs: closes the gaps between splats and softens the edge (a penumbra).
  scratch.resize(grid.size());
  for (int pass = 0; pass < 2; ++pass) {
    for (int y = 0; y < g; ++y) {
      for (int x = 0; x < g; ++x) {
        float sum = 0.0f;
        for (int dy = -1; dy <= 1; ++dy) {
          for (int dx = -1; dx <= 1; ++dx) {
            const int xx = std::clamp(x + dx, 0, g - 1), yy = std::clamp(y + dy, 0, g - 1);
            sum += grid[size_t(yy) * g + size_t(xx)];
          }
        }
        scratch[size_t(y) * g + size_t(x)] = std::min(sum * (pass == 0 ? 0.5f : 1.0f / 9.0f), 1.0f);
      }
    }
    grid.swap(scratch);
  }
}

bool tray_init(Renderer& r, std::string& error) {
  r.tray_program = gl_link_program(kTrayVertexShader, kTrayFragmentShader, error);
  if (!r.tray_program) return false;
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
  if (r.empty_vertex_array) glDeleteVertexArrays(1, &r.empty_vertex_array);
  if (r.shadow_texture) glDeleteTextures(1, &r.shadow_texture);
  r.tray_program = r.empty_vertex_array = r.shadow_texture = 0;
  r.shadow_valid = false;
}

void tray_shadow_update(Renderer& r, const Vec3f* positions, uint32_t count, const Camera& camera,
                        const DrawOptions& options) {
  r.shadow_valid = false;
  if (!r.shadow_texture || options.trays.empty() || !options.shadows || positions == nullptr) return;
  const TrayPlane& tray = options.trays.front();
  tray_shadow_grid(positions, count, tray, tray_light(camera, tray.normal), r.shadow_grid, r.shadow_scratch);
  r.shadow_bytes.resize(r.shadow_grid.size());
  for (size_t k = 0; k < r.shadow_grid.size(); ++k) r.shadow_bytes[k] = uint8_t(std::lround(255.0f * r.shadow_grid[k]));
  glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
  glTextureSubImage2D(r.shadow_texture, 0, 0, 0, kTrayShadowGrid, kTrayShadowGrid, GL_RED, GL_UNSIGNED_BYTE,
                      r.shadow_bytes.data());
  r.shadow_valid = true;
}

void tray_draw(Renderer& r, const Camera& camera, const DrawOptions& options) {
  if (options.trays.empty() || !r.tray_program) return;
  const ViewTarget target = renderer_target(r);
  glBindFramebuffer(GL_FRAMEBUFFER, target.framebuffer);
  glViewport(target.x, target.y, target.width, target.height);
  const Eigen::Matrix4f view = view_matrix(camera);
  const Eigen::Matrix4f view_projection = projection_matrix(camera, Viewport{r.width, r.height}.aspect()) * view;
  const Eigen::Matrix3f rotation = view.topLeftCorner<3, 3>();
  const Vec3f eye = camera_eye(camera);
  const Vec3f key_eye = Vec3f(-0.4f, 0.6f, 0.7f).normalized();  // the surface shader's key light
  glProgramUniformMatrix4fv(r.tray_program, 0, 1, GL_FALSE, view_projection.data());
  glProgramUniformMatrix4fv(r.tray_program, 1, 1, GL_FALSE, view.data());
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LEQUAL);
  glDepthMask(GL_TRUE);
  glDisable(GL_CULL_FACE);
  glDisable(GL_BLEND);
  glUseProgram(r.tray_program);
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
    // The shadow: the first tray's.
    const bool shadow = k == 0 && r.shadow_valid && options.shadows;
    glProgramUniform3fv(r.tray_program, 2, 1, tray.centre.data());
    glProgramUniform3fv(r.tray_program, 3, 1, axis_u.data());
    glProgramUniform3fv(r.tray_program, 4, 1, axis_v.data());
    glProgramUniform3fv(r.tray_program, 6, 1, shade.data());
    glProgramUniform1f(r.tray_program, 7, shadow ? options.shadow_alpha : 0.0f);
    glDrawArrays(GL_TRIANGLE_STRIP, 0, 4);
  }
  glBindTextureUnit(0, 0);
  glUseProgram(0);
  glBindVertexArray(0);
}

}  // namespace dvx
