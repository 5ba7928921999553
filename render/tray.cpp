// Trays under the organ and the organ's planar shadow on them (render/renderer.h: TrayPlane).
#include "render/gl_program.h"
#include "render/renderer.h"

#include <Eigen/Geometry>
#include <glad/gl.h>

#include <algorithm>
#include <cmath>

namespace dvx {
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

const char* kTrayFragmentShader = R"(#version 450 core
layout(location = 5) uniform vec3 u_eye_normal;
layout(location = 6) uniform vec3 u_tray_color;
in vec2 v_uv;
in vec3 v_eye_position;
out vec4 frag_color;
void main() {
  vec3 n = u_eye_normal;
  vec3 v = normalize(-v_eye_position);
  if (dot(n, v) < 0.0) n = -n;
  const vec3 key = normalize(vec3(-0.4, 0.6, 0.7));
  float diffuse = 0.55 * max(dot(n, key), 0.0);
  float nh = max(dot(n, normalize(key + v)), 0.0);
  float nh2 = nh * nh, nh4 = nh2 * nh2, nh8 = nh4 * nh4;
  float r = max(abs(v_uv.x), abs(v_uv.y));
  float lip = smoothstep(0.93, 0.95, r);
  vec3 c = u_tray_color * (0.30 + diffuse) * (1.0 - 0.4 * lip) + vec3(0.18 * nh8 * nh8);
  frag_color = vec4(c, 1.0);
}
)";

// The shadow: each surface vertex slid along the light onto the plane.
const char* kShadowVertexShader = R"(#version 450 core
layout(location = 0) in vec3 a_position;
layout(location = 0) uniform mat4 u_view_projection;
layout(location = 2) uniform vec3 u_point;
layout(location = 3) uniform vec3 u_normal;
layout(location = 4) uniform vec3 u_light;
void main() {
  float h = dot(a_position - u_point, u_normal);
  vec3 p = a_position - (h / dot(u_light, u_normal)) * u_light;
  gl_Position = u_view_projection * vec4(p, 1.0);
}
)";

const char* kShadowFragmentShader = R"(#version 450 core
layout(location = 5) uniform float u_alpha;
out vec4 frag_color;
void main() { frag_color = vec4(0.0, 0.0, 0.0, u_alpha); }
)";

// Two unit vectors spanning the plane of normal n.
void plane_axes(const Vec3f& n, Vec3f& u, Vec3f& v) {
  const Vec3f helper = std::abs(n.x()) < 0.9f ? Vec3f::UnitX() : Vec3f::UnitY();
  u = n.cross(helper).normalized();
  v = n.cross(u);
}

}  // namespace

bool tray_init(Renderer& r, std::string& error) {
  r.tray_program = gl_link_program(kTrayVertexShader, kTrayFragmentShader, error);
  if (r.tray_program) r.shadow_program = gl_link_program(kShadowVertexShader, kShadowFragmentShader, error);
  if (!r.shadow_program) return false;
  glCreateVertexArrays(1, &r.empty_vertex_array);
  return true;
}

void tray_destroy(Renderer& r) {
  if (r.tray_program) glDeleteProgram(r.tray_program);
  if (r.shadow_program) glDeleteProgram(r.shadow_program);
  if (r.empty_vertex_array) glDeleteVertexArrays(1, &r.empty_vertex_array);
  r.tray_program = r.shadow_program = r.empty_vertex_array = 0;
}

void tray_draw(Renderer& r, const Camera& camera, const DrawOptions& options) {
  if (options.trays.empty() || !r.tray_program || !r.shadow_program) return;
  const Eigen::Matrix4f view = view_matrix(camera);
  const Eigen::Matrix4f view_projection = projection_matrix(camera, Viewport{r.width, r.height}.aspect()) * view;
  const Eigen::Matrix3f rotation = view.topLeftCorner<3, 3>();
  const Vec3f eye = camera_eye(camera);
  // The key light (fixed to the camera, as in the surface shader) in world space.
  const Vec3f key_world = rotation.transpose() * Vec3f(-0.4f, 0.6f, 0.7f).normalized();
  glProgramUniformMatrix4fv(r.tray_program, 0, 1, GL_FALSE, view_projection.data());
  glProgramUniformMatrix4fv(r.tray_program, 1, 1, GL_FALSE, view.data());
  glProgramUniform3fv(r.tray_program, 6, 1, options.tray_color.data());
  glProgramUniformMatrix4fv(r.shadow_program, 0, 1, GL_FALSE, view_projection.data());
  glProgramUniform1f(r.shadow_program, 5, options.shadow_alpha);
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LEQUAL);
  glEnable(GL_STENCIL_TEST);
  glDisable(GL_CULL_FACE);
  const GLsizei index_count = GLsizei(std::min<uint64_t>(uint64_t(r.triangle_count) * 3, INT32_MAX / 3 * 3));
  for (const TrayPlane& tray : options.trays) {
    const Vec3f n = tray.normal.normalized();
    Vec3f u, v;
    plane_axes(n, u, v);
    // The tray, marking its visible pixels in the stencil.
    const Vec3f axis_u = tray.half_size * u, axis_v = tray.half_size * v, eye_normal = rotation * n;
    glProgramUniform3fv(r.tray_program, 2, 1, tray.centre.data());
    glProgramUniform3fv(r.tray_program, 3, 1, axis_u.data());
    glProgramUniform3fv(r.tray_program, 4, 1, axis_v.data());
    glProgramUniform3fv(r.tray_program, 5, 1, eye_normal.data());
    glStencilFunc(GL_ALWAYS, 1, 0xFF);
    glStencilOp(GL_KEEP, GL_KEEP, GL_REPLACE);
    glDepthMask(GL_TRUE);
    glUseProgram(r.tray_program);
    glBindVertexArray(r.empty_vertex_array);
    glDrawArrays(GL_TRIANGLE_STRIP, 0, 4);
    // The shadow, seen from above the plane only: the surface's light-facing triangles (front faces
    // once flattened: half the triangles) darken each tray pixel once (the stencil goes back to 0).
    const bool above = (eye - tray.centre).dot(n) > 0.0f;
    if (!options.shadows || !above || r.triangle_count == 0) continue;
    Vec3f light = key_world;
    if (light.dot(n) < 0.5f) light = (light + (0.5f - light.dot(n)) * n).normalized();
    glProgramUniform3fv(r.shadow_program, 2, 1, tray.centre.data());
    glProgramUniform3fv(r.shadow_program, 3, 1, n.data());
    glProgramUniform3fv(r.shadow_program, 4, 1, light.data());
    glStencilFunc(GL_EQUAL, 1, 0xFF);
    glStencilOp(GL_KEEP, GL_KEEP, GL_ZERO);
    glDepthMask(GL_FALSE);
    glEnable(GL_POLYGON_OFFSET_FILL);
    glPolygonOffset(-1.0f, -8.0f);
    glEnable(GL_BLEND);
    glBlendFunc(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA);
    glEnable(GL_CULL_FACE);
    glCullFace(GL_BACK);
    glFrontFace(GL_CCW);
    glUseProgram(r.shadow_program);
    glBindVertexArray(r.vertex_array);
    glDrawElements(GL_TRIANGLES, index_count, GL_UNSIGNED_INT, nullptr);
    glDisable(GL_CULL_FACE);
    glDisable(GL_BLEND);
    glDisable(GL_POLYGON_OFFSET_FILL);
  }
  glDepthMask(GL_TRUE);
  glDisable(GL_STENCIL_TEST);
  glUseProgram(0);
  glBindVertexArray(0);
}

}  // namespace dvx
