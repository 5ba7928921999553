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
#include <utility>
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
  // The solid overlay over a scene cache: its triangles far to near (sort_far_to_near's scratch).
  std::vector<SolidVertex> sorted;
  std::vector<std::pair<float, uint32_t>> order;
};
using LineOverlay = OverlayProgram;
using SolidOverlay = OverlayProgram;

bool overlay_init(LineOverlay& overlay, std::string& error);
// Draws `vertices` (pairs: GL_LINES) into the renderer's view (render/renderer.h: ViewTarget) with the camera.
void overlay_draw(LineOverlay& overlay, const ViewTarget& target, const Camera& camera,
                  const std::vector<LineVertex>& vertices, float line_width = 2.0f);

bool solid_overlay_init(SolidOverlay& overlay, std::string& error);
// Draws `vertices` (GL_TRIANGLES) into the view (which must have the scene's depth): first the
// parts behind the surface at `ghost_alpha`, then the visible parts opaque. With the scene's depth
// in a texture (ViewTarget::scene_depth: the scene cache) the window's depth buffer is not used at
// all (the window then need not clear it: on llvmpipe that clear cost its threads 2.5 ms a frame):
// the opaque parts are drawn far to near instead of depth-tested among themselves.
void solid_overlay_draw(SolidOverlay& overlay, const ViewTarget& target, const Camera& camera,
                        const std::vector<SolidVertex>& vertices, float ghost_alpha = 0.35f);

// The painter's order: the triangles of `vertices` (GL_TRIANGLES) into `sorted`, farthest from the
// camera first by their centroid's depth along the view axis (`view`: world to eye), ties in their
// original order. The solids drawn over the window (the scalpel's blade, neck and handle, markers)
// are small, convex or nearly so and do not intersect but at the seams they share, so drawing them
// far to near hides what a depth test would hide.
void sort_far_to_near(const std::vector<SolidVertex>& vertices, const Eigen::Matrix4f& view,
                      std::vector<SolidVertex>& sorted, std::vector<std::pair<float, uint32_t>>& order);
void overlay_destroy(OverlayProgram& overlay);

}  // namespace dvx
