// Mesh files in and out through assimp (OBJ, PLY, STL, glTF/GLB, and whatever else assimp reads).
#pragma once

#include "sim/mesh.h"
#include "sim/surface_mesh.h"

#include <string>

namespace dvx {

struct LoadedMesh {
  TriMesh mesh;                   // welded, all sub-meshes merged in scene coordinates
  uint32_t dropped_triangles = 0;  // degenerate (repeated index) triangles removed
};

// Loads and validates a triangle mesh. Throws InputError naming the file for: a missing or
// unreadable file, an unknown format, a file assimp cannot parse, no triangles, face
// indices out of range, NaN/Inf coordinates, a zero-size bounding box.
// With `progress`, reports on stderr how far reading has got (every 10 %, from assimp's progress
// callback: a mesh of millions of triangles takes seconds) and each later phase.
LoadedMesh load_mesh(const std::string& path, bool progress = false);

// Writes a surface as PLY (binary little endian). Throws std::runtime_error on failure.
void save_ply(const std::string& path, const SurfaceMesh& mesh);

}  // namespace dvx
