#include "render/normals.h"

#include <Eigen/Geometry>

#include <cmath>

namespace dvx {
namespace {

// Normalises every non-zero vector of `v` in place (zero stays zero).
void normalise_all(std::vector<Vec3f>& v) {
  for (Vec3f& x : v) {
    const float len2 = x.squaredNorm();
    if (len2 > 0.0f) x /= std::sqrt(len2);
  }
}

// Per-thread scratch: the triangles' weights and the smoothing sums (the window's simulation thread
// calls this once per snapshot: no allocation after the first).
struct NormalScratch {
  std::vector<float> weight;                 // (triangle slots) |face| or 0: dead, degenerate, non-finite
  std::vector<Vec3f> surface_sum, cut_sum;   // (vertex slots)
};

}  // namespace

void split_vertex_normals(const std::vector<Vec3f>& positions, const std::vector<Tri>& triangles,
                          const std::vector<uint8_t>& flags, std::vector<Vec3f>& surface_normals,
                          std::vector<Vec3f>& cut_normals, int smoothing_passes) {
  thread_local NormalScratch scratch;
  const uint32_t n = uint32_t(positions.size());
  const size_t triangle_count = triangles.size();
  surface_normals.assign(n, Vec3f::Zero());
  cut_normals.assign(n, Vec3f::Zero());
  const bool have_flags = flags.size() == triangle_count;
  std::vector<float>& weight = scratch.weight;
  weight.assign(triangle_count, 0.0f);
  // Per triangle: its face's cross product (the unit normal times twice its area) added to its
  // corners' class sums. Area weights: a sliver's normal is noise, and with angle weights the
  // slivers dual contouring leaves along cuts and folds (a corner of up to 180 degrees, a normal
  // in any direction) turned whole vertex fans dark.
  for (size_t t = 0; t < triangle_count; ++t) {
    const Tri& tri = triangles[t];
    if (tri[0] >= n || tri[1] >= n || tri[2] >= n) continue;
    const Vec3f &p0 = positions[tri[0]], &p1 = positions[tri[1]], &p2 = positions[tri[2]];
    const Vec3f face = (p1 - p0).cross(p2 - p0);
    const float len2 = face.squaredNorm();
    if (!(len2 > 1e-30f) || !std::isfinite(len2)) continue;
    weight[t] = std::sqrt(len2);
    Vec3f* out = (have_flags && (flags[t] & 1) != 0 ? cut_normals : surface_normals).data();
    out[tri[0]] += face;
    out[tri[1]] += face;
    out[tri[2]] += face;
  }
  normalise_all(surface_normals);
  normalise_all(cut_normals);
  // Smoothing passes, each class on its own (the rims stay creases): a vertex's new normal is the
  // area-weighted sum over its triangles of their three vertices' normals, so each pass blends in
  // the one-ring. The surface of a coarse source mesh, contoured finely, keeps the source's flat
  // facets with their whole bend within one voxel: the one-ring normals alone shade them as facets
  // with blocky highlights; two passes spread each bend over a few voxels.
  std::vector<Vec3f>& surface_sum = scratch.surface_sum;
  std::vector<Vec3f>& cut_sum = scratch.cut_sum;
  for (int pass = 0; pass < smoothing_passes; ++pass) {
    surface_sum.assign(n, Vec3f::Zero());
    cut_sum.assign(n, Vec3f::Zero());
    for (size_t t = 0; t < triangle_count; ++t) {
      const float w = weight[t];
      if (w == 0.0f) continue;
      const Tri& tri = triangles[t];
      const bool cut = have_flags && (flags[t] & 1) != 0;
      const Vec3f* in = (cut ? cut_normals : surface_normals).data();
      const Vec3f s = w * (in[tri[0]] + in[tri[1]] + in[tri[2]]);
      Vec3f* out = (cut ? cut_sum : surface_sum).data();
      out[tri[0]] += s;
      out[tri[1]] += s;
      out[tri[2]] += s;
    }
    surface_normals.swap(surface_sum);
    cut_normals.swap(cut_sum);
    normalise_all(surface_normals);
    normalise_all(cut_normals);
  }
}

}  // namespace dvx
