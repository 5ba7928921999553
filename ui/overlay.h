// A tiny GL line renderer for the window's overlays (the scalpel blade and its swept trail):
// coloured 3D segments drawn into the renderer's resolved image, on top of the surface.
#pragma once

#include "render/camera.h"

#include <cstdint>
#include <string>
#include <vector>

namespace dvx {

struct LineVertex {
  float position[3];
  float color[4];
};

struct LineOverlay {
  uint32_t program = 0, vertex_array = 0, buffer = 0;
  size_t capacity = 0;  // vertices the buffer holds
};

bool overlay_init(LineOverlay& overlay, std::string& error);
// Draws `vertices` (pairs: GL_LINES) into `framebuffer` (width x height) with the camera.
void overlay_draw(LineOverlay& overlay, uint32_t framebuffer, int width, int height, const Camera& camera,
                  const std::vector<LineVertex>& vertices, float line_width = 2.0f);
void overlay_destroy(LineOverlay& overlay);

}  // namespace dvx
