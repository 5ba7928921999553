// Topological and geometric checks of a triangle surface (used after every cut in tests
// and in every report): closedness, manifoldness, components, enclosed volume.
#pragma once

#include "sim/mesh.h"
#include "sim/surface_mesh.h"

#include <cstdint>

namespace dvx {

struct SurfaceStats {
  uint32_t vertices = 0;           // vertices used by at least one triangle
  uint32_t triangles = 0;
  uint32_t boundary_edges = 0;     // undirected edges used by exactly one triangle
  uint32_t nonmanifold_edges = 0;  // undirected edges used by more than two triangles
  uint32_t misoriented_edges = 0;  // manifold edges whose two triangles use it in the same direction
  uint32_t components = 0;         // connected components (triangles sharing a vertex)
  int64_t euler = 0;               // V - E + F
  double volume = 0.0;             // signed enclosed volume
  double area = 0.0;
};

SurfaceStats surface_stats(const std::vector<Vec3d>& positions, const std::vector<Tri>& triangles);
SurfaceStats surface_stats(const TriMesh& mesh);
SurfaceStats surface_stats(const SurfaceMesh& mesh);

// Component id per triangle (0..components-1, in order of first triangle), by union-find
// over shared vertices.
std::vector<uint32_t> triangle_components(const std::vector<Tri>& triangles, uint32_t vertex_count,
                                          uint32_t& components);

}  // namespace dvx
