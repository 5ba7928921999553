#include "sim/surface_mesh.h"

#include <Eigen/Geometry>

#include <cmath>

namespace dvx {

std::vector<Vec3f> vertex_normals(const SurfaceMesh& mesh) {
  const size_t nv = mesh.positions.size();
  std::vector<Vec3d> sum(nv, Vec3d::Zero());
  for (const Tri& t : mesh.triangles) {
    if (t[0] >= nv || t[1] >= nv || t[2] >= nv) continue;
    const Vec3d p0 = mesh.positions[t[0]].cast<double>();
    const Vec3d p1 = mesh.positions[t[1]].cast<double>();
    const Vec3d p2 = mesh.positions[t[2]].cast<double>();
    const Vec3d n = (p1 - p0).cross(p2 - p0);  // |n| = 2 * area: area weighting
    sum[t[0]] += n;
    sum[t[1]] += n;
    sum[t[2]] += n;
  }
  std::vector<Vec3f> out(nv, Vec3f::Zero());
  for (size_t i = 0; i < nv; ++i) {
    const double len = sum[i].norm();
    if (len > 0.0 && std::isfinite(len)) out[i] = (sum[i] / len).cast<float>();
  }
  return out;
}

TriMesh to_trimesh(const SurfaceMesh& mesh) {
  TriMesh out;
  out.positions.reserve(mesh.positions.size());
  for (const Vec3f& p : mesh.positions) out.positions.push_back(p.cast<double>());
  out.triangles = mesh.triangles;
  return out;
}

}  // namespace dvx
