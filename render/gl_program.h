// Shader programs from GLSL sources, with one-line errors (the first line of the GL's log). Needs a
// current GL 4.5 context. Shared by the renderer and the window's overlays.
#pragma once

#include <cstdint>
#include <string>

namespace dvx {

// A vertex + fragment program; 0 with a reason in `error` on failure.
uint32_t gl_link_program(const char* vertex_source, const char* fragment_source, std::string& error);
// A compute program; 0 with a reason in `error` on failure.
uint32_t gl_link_compute(const char* compute_source, std::string& error);

}  // namespace dvx
