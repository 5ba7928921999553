#include "ui/overlay.h"

#include <glad/gl.h>

#include <Eigen/Core>

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

uint32_t compile(GLenum type, const char* source, std::string& error) {
  const GLuint shader = glCreateShader(type);
  glShaderSource(shader, 1, &source, nullptr);
  glCompileShader(shader);
  GLint ok = 0;
  glGetShaderiv(shader, GL_COMPILE_STATUS, &ok);
  if (!ok) {
    char log[1024] = {};
    glGetShaderInfoLog(shader, sizeof log, nullptr, log);
    error = std::string("overlay shader: ") + log;
    glDeleteShader(shader);
    return 0;
  }
  return shader;
}

}  // namespace

bool overlay_init(LineOverlay& o, std::string& error) {
  const GLuint vs = compile(GL_VERTEX_SHADER, kVertex, error);
  if (vs == 0) return false;
  const GLuint fs = compile(GL_FRAGMENT_SHADER, kFragment, error);
  if (fs == 0) {
    glDeleteShader(vs);
    return false;
  }
  o.program = glCreateProgram();
  glAttachShader(o.program, vs);
  glAttachShader(o.program, fs);
  glLinkProgram(o.program);
  glDeleteShader(vs);
  glDeleteShader(fs);
  GLint ok = 0;
  glGetProgramiv(o.program, GL_LINK_STATUS, &ok);
  if (!ok) {
    error = "overlay program does not link";
    return false;
  }
  glCreateVertexArrays(1, &o.vertex_array);
  glCreateBuffers(1, &o.buffer);
  o.capacity = 256;
  glNamedBufferData(o.buffer, GLsizeiptr(o.capacity * sizeof(LineVertex)), nullptr, GL_DYNAMIC_DRAW);
  glVertexArrayVertexBuffer(o.vertex_array, 0, o.buffer, 0, sizeof(LineVertex));
  glEnableVertexArrayAttrib(o.vertex_array, 0);
  glEnableVertexArrayAttrib(o.vertex_array, 1);
  glVertexArrayAttribFormat(o.vertex_array, 0, 3, GL_FLOAT, GL_FALSE, offsetof(LineVertex, position));
  glVertexArrayAttribFormat(o.vertex_array, 1, 4, GL_FLOAT, GL_FALSE, offsetof(LineVertex, color));
  glVertexArrayAttribBinding(o.vertex_array, 0, 0);
  glVertexArrayAttribBinding(o.vertex_array, 1, 0);
  return true;
}

void overlay_draw(LineOverlay& o, uint32_t framebuffer, int width, int height, const Camera& camera,
                  const std::vector<LineVertex>& vertices, float line_width) {
  if (vertices.empty() || o.program == 0) return;
  if (vertices.size() > o.capacity) {
    while (o.capacity < vertices.size()) o.capacity *= 2;
    glNamedBufferData(o.buffer, GLsizeiptr(o.capacity * sizeof(LineVertex)), nullptr, GL_DYNAMIC_DRAW);
  }
  glNamedBufferSubData(o.buffer, 0, GLsizeiptr(vertices.size() * sizeof(LineVertex)), vertices.data());
  const Eigen::Matrix4f mvp = projection_matrix(camera, float(width) / float(std::max(height, 1))) * view_matrix(camera);
  glBindFramebuffer(GL_FRAMEBUFFER, framebuffer);
  glViewport(0, 0, width, height);
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

void overlay_destroy(LineOverlay& o) {
  if (o.buffer) glDeleteBuffers(1, &o.buffer);
  if (o.vertex_array) glDeleteVertexArrays(1, &o.vertex_array);
  if (o.program) glDeleteProgram(o.program);
  o = LineOverlay();
}

}  // namespace dvx
