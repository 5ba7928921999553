// The surface handed to metrics, output and (later) the renderer: dual-contoured vertices
// with the voxel each belongs to (the surface-voxel correspondence the paper relies on).
#pragma once

#include "sim/mesh.h"

#include <cstdint>
#include <vector>

namespace dvx {

struct SurfaceMesh {
  std::vector<Vec3f> positions;      // (nverts)
  std::vector<uint32_t> vertex_voxel;  // (nverts) lattice voxel id the vertex lives in
  std::vector<Tri> triangles;        // (ntris) counter-clockwise seen from outside
};

// Vertex normals (area-weighted average of incident triangle normals).
std::vector<Vec3f> vertex_normals(const SurfaceMesh& mesh);

// The surface as a double-precision TriMesh (for distance queries and export).
TriMesh to_trimesh(const SurfaceMesh& mesh);

}  // namespace dvx
