// The scalpel drawn at the blade's pose: a small lit triangle mesh (a tapered steel blade whose
// belly is the cutting edge, and a handle behind it), built on the CPU each frame (a few dozen
// triangles). Pure maths, no GL: ui/overlay.cpp draws it.
#pragma once

#include "sim/mesh.h"

#include <vector>

namespace dvx {

struct SolidVertex {
  float position[3];
  float normal[3];
  float color[4];
};

struct ScalpelStyle {
  float blade_width = 0.2f;    // across the blade, scene units
  float handle_length = 1.0f;  // the handle's bar (after a neck 0.15 x as long), scene units
  // The handle's angle off the blade's axis, radians, leaning away from the blade's plane toward -n
  // (n = axis x edge direction): on screen the handle stands beside the incision instead of over it.
  float handle_lean = 0.87f;   // 50 degrees
  Vec3f blade_color = Vec3f(0.80f, 0.83f, 0.88f);
  Vec3f edge_color = Vec3f(0.95f, 0.97f, 1.0f);
  Vec3f handle_color = Vec3f(0.46f, 0.52f, 0.60f);
};

// Appends the scalpel's triangles (3 vertices each, outward normals) to `out`: the blade from `back`
// (where it leaves the handle) to `tip` (its deepest point), its sharp edge facing `edge_dir`
// (orthogonalised against the blade's axis; any vector not along it), and the handle continuing from
// `back` away from the tip through a narrow neck, then leaning off the blade's plane (ScalpelStyle::
// handle_lean; 0: in line with the blade). Nothing is added for a zero-length blade.
void scalpel_mesh(const Vec3f& back, const Vec3f& tip, const Vec3f& edge_dir, const ScalpelStyle& style,
                  std::vector<SolidVertex>& out);

// Appends a small octahedron (a marker, e.g. the grabbed point) of `radius` at `centre`.
void marker_mesh(const Vec3f& centre, float radius, const Vec3f& color, std::vector<SolidVertex>& out);

}  // namespace dvx
