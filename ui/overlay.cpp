#include "ui/overlay.h"

#include "render/gl_program.h"

#include <glad/gl.h>

#include <Eigen/Core>

#include <algorithm>
#include <cstddef>

namespace dvx {
namespace {

const char* kVertex = R"(#version 450 core
layout(location = 0) in vec3 position;
layout(location = 1) in vec4 color;
uniform mat4 mvp;
out vec4 v_color;
void main() { gl_Position = mvp * vec4(position, 1.0); v_color = color; }
)";

const char* kFragment = R"(#version 450 core
in vec4 v_color;
out vec4 frag;
void main() { frag = v_color; }
)";

// Lit solids: a headlight plus a key light from the upper left, metallic highlights.
const char* kSolidVertex = R"(#version 450 core
layout(location = 0) in vec3 position;
layout(location = 1) in vec3 normal;
layout(location = 2) in vec4 color;
uniform mat4 mvp;
uniform mat4 view;
out vec4 v_color;
out vec3 v_normal;
out vec3 v_eye;
void main() {
  gl_Position = mvp * vec4(position, 1.0);
  v_color = color;
  v_normal = mat3(view) * normal;
  v_eye = (view * vec4(position, 1.0)).xyz;
}
)";

const char* kSolidFragment = R"(#version 450 core
in vec4 v_color;
in vec3 v_normal;
in vec3 v_eye;
uniform float alpha;
// The scene's depth as a texture (ViewTarget::scene_depth; scene_depth_on 0: in the depth buffer).
uniform int scene_depth_on;
uniform ivec2 scene_origin;
layout(binding = 1) uniform sampler2D scene_depth;
out vec4 frag;
void main() {
  if (scene_depth_on != 0 && gl_FragCoord.z > texelFetch(scene_depth, ivec2(gl_FragCoord.xy) - scene_origin, 0).r) discard;
  vec3 n = normalize(v_normal);
  vec3 v = normalize(-v_eye);
  if (dot(n, v) < 0.0) n = -n;
  const vec3 key = normalize(vec3(-0.4, 0.6, 0.7));
  float diffuse = 0.55 * max(dot(n, key), 0.0) + 0.35 * max(dot(n, v), 0.0);
  float spec = 0.6 * pow(max(dot(n, normalize(key + v)), 0.0), 40.0);
  frag = vec4(v_color.rgb * (0.25 + diffuse) + vec3(spec), alpha);
}
)";

// The program, the vertex array with `count` float attributes (sizes, byte offsets) read from one
// buffer of `stride`-byte vertices, and that buffer with room for `capacity` vertices.
bool init_overlay(OverlayProgram& o, const char* vertex, const char* fragment, size_t stride, const int* sizes,
                  const size_t* offsets, int count, size_t capacity, std::string& error) {
  o.program = gl_link_program(vertex, fragment, error);
  if (o.program == 0) {
    error = "overlay: " + error;
    return false;
  }
  glCreateVertexArrays(1, &o.vertex_array);
  glCreateBuffers(1, &o.buffer);
  o.capacity = capacity;
  glNamedBufferData(o.buffer, GLsizeiptr(capacity * stride), nullptr, GL_DYNAMIC_DRAW);
  glVertexArrayVertexBuffer(o.vertex_array, 0, o.buffer, 0, GLsizei(stride));
  for (int a = 0; a < count; ++a) {
    glEnableVertexArrayAttrib(o.vertex_array, GLuint(a));
    glVertexArrayAttribFormat(o.vertex_array, GLuint(a), sizes[a], GL_FLOAT, GL_FALSE, GLuint(offsets[a]));
    glVertexArrayAttribBinding(o.vertex_array, GLuint(a), 0);
  }
  return true;
}

// Grows `buffer` to hold `count` vertices of `stride` bytes and fills it.
void upload_vertices(uint32_t buffer, size_t& capacity, const void* data, size_t count, size_t stride) {
  if (count > capacity) {
    while (capacity < count) capacity *= 2;
    glNamedBufferData(buffer, GLsizeiptr(capacity * stride), nullptr, GL_DYNAMIC_DRAW);
  }
  glNamedBufferSubData(buffer, 0, GLsizeiptr(count * stride), data);
}

}  // namespace

bool overlay_init(LineOverlay& o, std::string& error) {
  const int sizes[2] = {3, 4};
  const size_t offsets[2] = {offsetof(LineVertex, position), offsetof(LineVertex, color)};
  return init_overlay(o, kVertex, kFragment, sizeof(LineVertex), sizes, offsets, 2, 256, error);
}

void overlay_draw(LineOverlay& o, const ViewTarget& target, const Camera& camera,
                  const std::vector<LineVertex>& vertices, float line_width) {
  if (vertices.empty() || o.program == 0) return;
  upload_vertices(o.buffer, o.capacity, vertices.data(), vertices.size(), sizeof(LineVertex));
  const Eigen::Matrix4f mvp = projection_matrix(camera, float(target.width) / float(std::max(target.height, 1))) * view_matrix(camera);
  glBindFramebuffer(GL_FRAMEBUFFER, target.framebuffer);
  glViewport(target.x, target.y, target.width, target.height);
  glDisable(GL_DEPTH_TEST);
  glDisable(GL_CULL_FACE);
  glEnable(GL_BLEND);
  glBlendFunc(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA);
  glLineWidth(line_width);
  glUseProgram(o.program);
  glUniformMatrix4fv(glGetUniformLocation(o.program, "mvp"), 1, GL_FALSE, mvp.data());
  glBindVertexArray(o.vertex_array);
  glDrawArrays(GL_LINES, 0, GLsizei(vertices.size()));
  glBindVertexArray(0);
  glUseProgram(0);
  glLineWidth(1.0f);
  glDisable(GL_BLEND);
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
}

void sort_far_to_near(const std::vector<SolidVertex>& vertices, const Eigen::Matrix4f& view,
                      std::vector<SolidVertex>& sorted, std::vector<std::pair<float, uint32_t>>& order) {
  const size_t triangles = vertices.size() / 3;
  order.resize(triangles);
  // Eye space looks along -z: the farther, the more negative its z.
  const Eigen::RowVector4f z_row = view.row(2);
  for (size_t t = 0; t < triangles; ++t) {
    float z = 0.0f;
    for (size_t c = 0; c < 3; ++c) {
      const float* p = vertices[3 * t + c].position;
      z += z_row.dot(Eigen::Vector4f(p[0], p[1], p[2], 1.0f));
    }
    order[t] = {z, uint32_t(t)};
  }
  std::stable_sort(order.begin(), order.end(),
                   [](const std::pair<float, uint32_t>& a, const std::pair<float, uint32_t>& b) { return a.first < b.first; });
  sorted.resize(3 * triangles);
  for (size_t k = 0; k < triangles; ++k) {
    for (size_t c = 0; c < 3; ++c) sorted[3 * k + c] = vertices[3 * size_t(order[k].second) + c];
  }
}

void overlay_destroy(OverlayProgram& o) {
  if (o.buffer) glDeleteBuffers(1, &o.buffer);
  if (o.vertex_array) glDeleteVertexArrays(1, &o.vertex_array);
  if (o.program) glDeleteProgram(o.program);
  o = OverlayProgram();
}

bool solid_overlay_init(SolidOverlay& o, std::string& error) {
  const int sizes[3] = {3, 3, 4};
  const size_t offsets[3] = {offsetof(SolidVertex, position), offsetof(SolidVertex, normal), offsetof(SolidVertex, color)};
  return init_overlay(o, kSolidVertex, kSolidFragment, sizeof(SolidVertex), sizes, offsets, 3, 512, error);
}

void solid_overlay_draw(SolidOverlay& o, const ViewTarget& target, const Camera& camera,
                        const std::vector<SolidVertex>& vertices, float ghost_alpha) {
  if (vertices.empty() || o.program == 0) return;
  const Eigen::Matrix4f view = view_matrix(camera);
  const Eigen::Matrix4f mvp = projection_matrix(camera, float(target.width) / float(std::max(target.height, 1))) * view;
  // Over a scene cache the window's depth buffer holds nothing of this frame (it is not cleared):
  // the triangles go far to near and nothing is depth-tested in the depth buffer.
  const bool painter = target.scene_depth != 0;
  if (painter) sort_far_to_near(vertices, view, o.sorted, o.order);
  const std::vector<SolidVertex>& drawn = painter ? o.sorted : vertices;
  upload_vertices(o.buffer, o.capacity, drawn.data(), drawn.size(), sizeof(SolidVertex));
  glBindFramebuffer(GL_FRAMEBUFFER, target.framebuffer);
  glViewport(target.x, target.y, target.width, target.height);
  glDisable(GL_CULL_FACE);
  glUseProgram(o.program);
  glUniformMatrix4fv(glGetUniformLocation(o.program, "mvp"), 1, GL_FALSE, mvp.data());
  glUniformMatrix4fv(glGetUniformLocation(o.program, "view"), 1, GL_FALSE, view.data());
  glBindVertexArray(o.vertex_array);
  const GLint alpha = glGetUniformLocation(o.program, "alpha");
  const GLint depth_on = glGetUniformLocation(o.program, "scene_depth_on");
  glUniform1i(depth_on, 0);
  glUniform2i(glGetUniformLocation(o.program, "scene_origin"), target.x, target.y);
  // Pass 1: the parts behind the surface, faint (no depth test, no depth writes).
  glEnable(GL_BLEND);
  glBlendFunc(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA);
  glDisable(GL_DEPTH_TEST);
  glDepthMask(GL_FALSE);
  glUniform1f(alpha, ghost_alpha);
  glDrawArrays(GL_TRIANGLES, 0, GLsizei(drawn.size()));
  // Pass 2: the visible parts, opaque, depth-tested against the surface (in the shader when the
  // scene's depth is a texture) and among themselves (the depth buffer, or the painter's order).
  glDisable(GL_BLEND);
  if (painter) {
    glBindTextureUnit(1, target.scene_depth);
    glUniform1i(depth_on, 1);
  } else {
    glEnable(GL_DEPTH_TEST);
    glDepthFunc(GL_LEQUAL);
    glDepthMask(GL_TRUE);
  }
  glUniform1f(alpha, 1.0f);
  glDrawArrays(GL_TRIANGLES, 0, GLsizei(drawn.size()));
  if (painter) glBindTextureUnit(1, 0);
  glDepthMask(GL_TRUE);
  glBindVertexArray(0);
  glUseProgram(0);
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
}

}  // namespace dvx
