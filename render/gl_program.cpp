#include "render/gl_program.h"

#include <glad/gl.h>

#include <algorithm>

namespace dvx {
namespace {

// First line of a shader or program info log, for one-line errors.
std::string first_line(const std::string& log) {
  const size_t end = log.find('\n');
  return end == std::string::npos ? log : log.substr(0, end);
}

const char* stage_name(GLenum stage) {
  return stage == GL_VERTEX_SHADER ? "vertex" : stage == GL_FRAGMENT_SHADER ? "fragment" : "compute";
}

// Compiles one stage; 0 with the log's first line in `error` on failure.
GLuint compile_shader(GLenum stage, const char* source, std::string& error) {
  GLuint shader = glCreateShader(stage);
  glShaderSource(shader, 1, &source, nullptr);
  glCompileShader(shader);
  GLint ok = 0;
  glGetShaderiv(shader, GL_COMPILE_STATUS, &ok);
  if (!ok) {
    GLint length = 0;
    glGetShaderiv(shader, GL_INFO_LOG_LENGTH, &length);
    std::string log(size_t(std::max(length, 1)), '\0');
    glGetShaderInfoLog(shader, length, nullptr, log.data());
    error = std::string("GL: ") + stage_name(stage) + " shader does not compile: " + first_line(log.c_str());
    glDeleteShader(shader);
    return 0;
  }
  return shader;
}

// Compiles and links `count` stages.
GLuint link_stages(const GLenum* stages, const char* const* sources, int count, std::string& error) {
  GLuint shaders[2] = {0, 0};
  for (int k = 0; k < count; ++k) {
    shaders[k] = compile_shader(stages[k], sources[k], error);
    if (!shaders[k]) {
      for (int j = 0; j < k; ++j) glDeleteShader(shaders[j]);
      return 0;
    }
  }
  GLuint program = glCreateProgram();
  for (int k = 0; k < count; ++k) glAttachShader(program, shaders[k]);
  glLinkProgram(program);
  for (int k = 0; k < count; ++k) glDeleteShader(shaders[k]);
  GLint ok = 0;
  glGetProgramiv(program, GL_LINK_STATUS, &ok);
  if (!ok) {
    GLint length = 0;
    glGetProgramiv(program, GL_INFO_LOG_LENGTH, &length);
    std::string log(size_t(std::max(length, 1)), '\0');
    glGetProgramInfoLog(program, length, nullptr, log.data());
    error = "GL: program does not link: " + first_line(log.c_str());
    glDeleteProgram(program);
    return 0;
  }
  return program;
}

}  // namespace

uint32_t gl_link_program(const char* vertex_source, const char* fragment_source, std::string& error) {
  const GLenum stages[2] = {GL_VERTEX_SHADER, GL_FRAGMENT_SHADER};
  const char* const sources[2] = {vertex_source, fragment_source};
  return link_stages(stages, sources, 2, error);
}

uint32_t gl_link_compute(const char* compute_source, std::string& error) {
  const GLenum stage = GL_COMPUTE_SHADER;
  return link_stages(&stage, &compute_source, 1, error);
}

}  // namespace dvx
