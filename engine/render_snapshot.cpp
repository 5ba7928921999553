#include "engine/render_snapshot.h"

#include <Eigen/Geometry>

namespace dvx {
namespace {

// Area-weighted vertex normals over the live slots of a snapshot.
void slot_normals(const Snapshot& s, std::vector<Vec3f>& normals) {
  normals.assign(s.positions.size(), Vec3f::Zero());
  for (const Tri& t : s.triangles) {
    if (t[0] == kDeadIndex || t[0] >= s.positions.size() || t[1] >= s.positions.size() || t[2] >= s.positions.size()) {
      continue;
    }
    const Vec3f n = (s.positions[t[1]] - s.positions[t[0]]).cross(s.positions[t[2]] - s.positions[t[0]]);
    if (!n.allFinite()) continue;
    for (int c = 0; c < 3; ++c) normals[t[c]] += n;
  }
  for (Vec3f& n : normals) {
    const float len = n.norm();
    n = len > 0.0f ? Vec3f(n / len) : Vec3f(0, 1, 0);
  }
}

}  // namespace

RenderMesh snapshot_render_mesh(const Snapshot& s, bool full) {
  RenderMesh mesh;
  mesh.positions = s.positions.data();
  mesh.vertex_count = uint32_t(s.positions.size());
  mesh.triangles = s.triangles.data();
  mesh.triangle_count = uint32_t(s.triangles.size());
  mesh.triangle_flags = s.triangle_flags.data();
  mesh.vertex_begin = 0;
  mesh.vertex_end = mesh.vertex_count;
  mesh.triangle_begin = s.dirty_triangle_begin;
  mesh.triangle_end = s.dirty_triangle_end;
  mesh.full = full;
  return mesh;
}

void upload_snapshot(Renderer& renderer, const Snapshot& s, bool full, std::vector<Vec3f>& normals) {
  slot_normals(s, normals);
  RenderMesh mesh = snapshot_render_mesh(s, full);
  mesh.normals = normals.data();
  renderer_upload(renderer, mesh);
}

}  // namespace dvx
