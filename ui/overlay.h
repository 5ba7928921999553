// The window's overlays: coloured 3D segments (the blade's trail, the grab line, the entry mark)
// drawn on top of the surface, and small lit solids (the scalpel, the grabbed point) drawn into the
// renderer's framebuffer against its depth: hidden parts (the blade inside the tissue) show through
// as a faint ghost, so the blade's depth stays visible.
#pragma once

#include "render/blade_mesh.h"
#include "render/camera.h"
#include "render/renderer.h"

#include <cstdint>
#include <string>
#include <vector>

namespace dvx {

struct LineVertex {
  float position[3];
  float color[4];
};

// A program, its vertex array and a growing vertex buffer: the line overlay or the solid one.
struct OverlayProgram {
  uint32_t program = 0, vertex_array = 0, buffer = 0;
  size_t capacity = 0;  // vertices the buffer holds
};
using LineOverlay = OverlayProgram;
using SolidOverlay = OverlayProgram;

bool overlay_init(LineOverlay& overlay, std::string& error);
// Draws `vertices` (pairs: GL_LINES) into the renderer's view (render/renderer.h: ViewTarget) with the camera.
void overlay_draw(LineOverlay& overlay, const ViewTarget& target, const Camera& camera,
                  const std::vector<LineVertex>& vertices, float line_width = 2.0f);

bool solid_overlay_init(SolidOverlay& overlay, std::string& error);
// Draws `vertices` (GL_TRIANGLES) into the view (which must have the scene's depth): first the
// parts behind the surface at `ghost_alpha`, then the visible parts opaque.
void solid_overlay_draw(SolidOverlay& overlay, const ViewTarget& target, const Camera& camera,
                        const std::vector<SolidVertex>& vertices, float ghost_alpha = 0.35f);

void overlay_destroy(OverlayProgram& overlay);

}  // namespace dvx
