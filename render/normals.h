// Smooth vertex normals of a surface with cut faces, on the CPU: per vertex slot, the area-weighted
// normals of its outer-surface triangles and, separately, of its cut-face triangles, so a cut's rim
// stays a crisp crease (the renderer shades each triangle with its class's normal), then smoothed
// over the neighbouring vertices of the same class (kNormalSmoothingPasses). The same result as the
// renderer's GPU passes (renderer.h: gpu_normals), for software rasterisers, where those passes run
// on the same CPU cores many times slower than this loop.
#pragma once

#include "sim/mesh.h"

#include <cstdint>
#include <vector>

namespace dvx {

// Smoothing passes: each replaces a vertex's normal by the area-weighted sum, over its triangles of
// its class, of their three vertices' normals (normalised). A coarse source mesh contoured finely
// keeps its flat facets, bent within one voxel; two passes spread the bend over a few voxels.
constexpr int kNormalSmoothingPasses = 2;

// `flags` (per triangle slot, bit 0: cut face) may be empty (no cut faces). Dead slots (an index
// past the positions) and degenerate or non-finite triangles add nothing; a vertex with none of a
// class gets a zero normal for it.
void split_vertex_normals(const std::vector<Vec3f>& positions, const std::vector<Tri>& triangles,
                          const std::vector<uint8_t>& flags, std::vector<Vec3f>& surface_normals,
                          std::vector<Vec3f>& cut_normals, int smoothing_passes = kNormalSmoothingPasses);

}  // namespace dvx
