// Split smooth normals (render/normals.h: area weights, smoothing passes) and the renderer's GPU
// passes that compute the same, and
// the scalpel's mesh (render/blade_mesh.h).
#include "render/blade_mesh.h"
#include "render/egl_context.h"
#include "render/normals.h"
#include "render/renderer.h"
#include "sim/contour.h"
#include "sim/cut.h"
#include "sim/shapes.h"
#include "sim/voxelize.h"

#include <glad/gl.h>

#include <doctest/doctest.h>

#include <Eigen/Geometry>

#include <cmath>
#include <cstdlib>

using namespace dvx;

TEST_SUITE("render") {
TEST_CASE("normals: cut faces and the outer surface are averaged apart, so the rim is a crease") {
  // A roof: two triangles meeting at 90 degrees along the ridge (vertices 0, 1).
  const std::vector<Vec3f> p = {Vec3f(0, 0, 0), Vec3f(0, 0, 1), Vec3f(1, -1, 0.5f), Vec3f(-1, -1, 0.5f)};
  const std::vector<Tri> t = {{0, 1, 2}, {1, 0, 3}};
  const Vec3f n0 = (p[1] - p[0]).cross(p[2] - p[0]).normalized(), n1 = (p[0] - p[1]).cross(p[3] - p[1]).normalized();
  std::vector<Vec3f> surface, cut;
  // No cut faces: the ridge vertices average both faces.
  split_vertex_normals(p, t, {}, surface, cut);
  CHECK((surface[0] - (n0 + n1).normalized()).norm() < 1e-5f);
  CHECK(cut[0].norm() == 0.0f);
  // The second face cut: each class keeps its own face's normal at the shared ridge.
  split_vertex_normals(p, t, {0, 1}, surface, cut);
  for (uint32_t v : {0u, 1u}) {
    CHECK((surface[v] - n0).norm() < 1e-5f);
    CHECK((cut[v] - n1).norm() < 1e-5f);
  }
  CHECK(cut[2].norm() == 0.0f);     // only on the outer face
  CHECK(surface[3].norm() == 0.0f);  // only on the cut face
  // Dead slots, degenerate and NaN triangles add nothing.
  const std::vector<Vec3f> q = {p[0], p[1], p[2], Vec3f::Constant(std::nanf(""))};
  split_vertex_normals(q, {{0, 1, 2}, {kDeadIndex, kDeadIndex, kDeadIndex}, {0, 0, 1}, {0, 1, 3}}, {}, surface, cut);
  CHECK((surface[0] - n0).norm() < 1e-5f);
  CHECK(surface[3].norm() == 0.0f);
}

TEST_CASE("normals: area weights, so a sliver cannot turn a vertex's normal (the dark pits)") {
  // Vertex 0 in the plane z = 0 with a fan of six triangles around it, plus a sliver: its corner at
  // vertex 0 is nearly 180 degrees and its normal tilted 45 degrees. Angle weights gave the sliver
  // half the say (a pit of shade around the vertex); area weights give it almost none.
  std::vector<Vec3f> p = {Vec3f::Zero()};
  std::vector<Tri> t;
  for (int k = 0; k < 6; ++k) p.push_back(Vec3f(std::cos(1.0471976f * k), std::sin(1.0471976f * k), 0.0f));
  for (uint32_t k = 0; k < 6; ++k) t.push_back({0, 1 + k, 1 + (k + 1) % 6});
  p.push_back(Vec3f(0.5f, 0.001f, 0.5f));
  p.push_back(Vec3f(-0.5f, 0.0f, -0.5f));
  t.push_back({0, 7, 8});
  std::vector<Vec3f> surface, cut;
  split_vertex_normals(p, t, {}, surface, cut, 0);
  CHECK(surface[0].z() > std::cos(0.02f));
  split_vertex_normals(p, t, {}, surface, cut);
  CHECK(surface[0].z() > std::cos(0.05f));
}

TEST_CASE("normals: the smoothing passes spread a crease over the neighbouring vertices") {
  // A strip of unit squares (x 0..10, y 0..3) bent 20 degrees about the line x = 5.
  const float bend = 0.349066f;
  std::vector<Vec3f> p;
  std::vector<Tri> t;
  for (int y = 0; y <= 3; ++y) {
    for (int x = 0; x <= 10; ++x) {
      const float d = float(x) - 5.0f;
      p.push_back(d <= 0.0f ? Vec3f(d, float(y), 0.0f) : Vec3f(d * std::cos(bend), float(y), d * std::sin(bend)));
    }
  }
  for (uint32_t y = 0; y < 3; ++y) {
    for (uint32_t x = 0; x < 10; ++x) {
      const uint32_t a = y * 11 + x;
      t.push_back({a, a + 1, a + 12});
      t.push_back({a, a + 12, a + 11});
    }
  }
  std::vector<Vec3f> surface, cut;
  const auto tilt = [&](int x) { return std::acos(std::clamp(surface[size_t(11 + x)].dot(Vec3f::UnitZ()), -1.0f, 1.0f)); };
  // One ring only: the crease's vertices are bent, their neighbours keep their facet's normal.
  split_vertex_normals(p, t, {}, surface, cut, 0);
  CHECK(tilt(4) < 1e-5f);
  CHECK(tilt(5) > 0.1f);
  // Smoothed: the bend reaches the next vertices on both sides, and runs the right way.
  split_vertex_normals(p, t, {}, surface, cut);
  CHECK(tilt(4) > 0.03f);
  CHECK(tilt(6) < bend - 0.03f);
  CHECK(tilt(3) < tilt(4));
  CHECK(tilt(4) < tilt(5));
  CHECK(tilt(5) < tilt(6));
  CHECK(tilt(1) < 1e-3f);  // far from the crease, still flat
}

TEST_CASE("normals: the GPU passes give the CPU's split normals") {
  EglContext ctx;
  std::string error;
  if (!create_egl_context(ctx, error)) {
    const char* require = std::getenv("DIVVOX_REQUIRE_GL");
    if (require && std::string(require) == "1") FAIL("EGL context required: " << error);
    MESSAGE("skipped: " << error);
    return;
  }
  {
    // A dual-contoured torus, its triangles with x > 0.4 flagged as cut faces, one dead slot.
    VoxelModel model;
    VoxelizeParams params;
    params.resolution = 32;
    REQUIRE(voxelize(make_torus(Vec3d::Zero(), 1.0, 0.4, 48, 24), params, model, error));
    SurfaceMesh mesh = dual_contour(model);
    mesh.triangles.push_back({kDeadIndex, kDeadIndex, kDeadIndex});
    std::vector<uint8_t> flags(mesh.triangles.size(), 0);
    for (size_t k = 0; k + 1 < mesh.triangles.size(); ++k) {
      const Tri& tri = mesh.triangles[k];
      flags[k] = mesh.positions[tri[0]].x() + mesh.positions[tri[1]].x() + mesh.positions[tri[2]].x() > 1.2f ? 1 : 0;
    }
    std::vector<Vec3f> surface, cut;
    split_vertex_normals(mesh.positions, mesh.triangles, flags, surface, cut);

    Renderer r;
    REQUIRE_MESSAGE(renderer_init(r, 64, 64, error), error);
    RenderMesh m = render_mesh_of(mesh, nullptr, &flags);
    m.gpu_normals = true;
    renderer_upload(r, m);
    renderer_update_normals(r);
    std::vector<Vec3f> gpu_surface(mesh.positions.size()), gpu_cut(mesh.positions.size());
    glGetNamedBufferSubData(r.normal_buffer, 0, GLsizeiptr(gpu_surface.size() * 12), gpu_surface.data());
    glGetNamedBufferSubData(r.cut_normal_buffer, 0, GLsizeiptr(gpu_cut.size() * 12), gpu_cut.data());
    float worst = 0.0f;
    size_t with_cut = 0;
    for (size_t v = 0; v < surface.size(); ++v) {
      worst = std::max({worst, (gpu_surface[v] - surface[v]).norm(), (gpu_cut[v] - cut[v]).norm()});
      with_cut += cut[v].norm() > 0.5f ? 1 : 0;
    }
    CHECK(with_cut > 10);
    CHECK(worst < 1e-3f);
    CHECK_MESSAGE(gl_check_errors(error), error);
    renderer_destroy(r);
  }
  destroy_egl_context(ctx);
}

TEST_CASE("scalpel mesh: the blade reaches the tip from the back, the handle leans off the blade's plane") {
  const Vec3f back(1, 2, 3), tip(1, 2, 1);  // the blade points along -z, 2 long, its edge along +x
  ScalpelStyle style;
  style.blade_width = 0.4f;
  style.handle_length = 1.5f;
  std::vector<SolidVertex> v;
  scalpel_mesh(back, tip, Vec3f(1, 0, 0), style, v);
  REQUIRE(v.size() % 3 == 0);
  REQUIRE(v.size() > 30);
  float deepest = 1e9f, highest = -1e9f, widest = 0.0f, leaning = -1e9f, other_side = 1e9f;
  for (const SolidVertex& x : v) {
    const Vec3f p(x.position[0], x.position[1], x.position[2]);
    deepest = std::min(deepest, p.z());
    highest = std::max(highest, p.z());
    widest = std::max(widest, std::abs(p.x() - 1.0f));
    leaning = std::max(leaning, p.y() - 2.0f);
    other_side = std::min(other_side, p.y() - 2.0f);
    CHECK(Vec3f(x.normal[0], x.normal[1], x.normal[2]).norm() == doctest::Approx(1.0f).epsilon(1e-4));
  }
  CHECK(deepest == doctest::Approx(tip.z()).epsilon(1e-5));  // the tip is the blade's deepest point
  CHECK(widest <= 0.5f * style.blade_width + 1e-5f);         // no wider than the blade
  // The handle continues behind the back (the neck, then cos 50 degrees of its length) and leans
  // off the blade's plane (x = 1) toward -n = -(axis x edge) = +y by sin 50 degrees of its length,
  // so seen along the blade it stands beside the incision (which runs along x), not over it.
  const float lean = style.handle_lean, hl = style.handle_length;
  CHECK(highest > back.z() + 0.15f * hl + 0.95f * std::cos(lean) * hl);
  CHECK(leaning > 0.95f * std::sin(lean) * hl);
  CHECK(other_side > -0.2f * style.blade_width);  // only its thickness on the other side
  // In line with the blade (no lean), the handle runs straight back along the axis.
  style.handle_lean = 0.0f;
  v.clear();
  scalpel_mesh(back, tip, Vec3f(1, 0, 0), style, v);
  highest = -1e9f;
  for (const SolidVertex& x : v) highest = std::max(highest, x.position[2]);
  CHECK(highest > back.z() + 1.15f * hl);
  // Nothing for a zero-length blade; the marker is a closed octahedron.
  std::vector<SolidVertex> none;
  scalpel_mesh(back, back, Vec3f(1, 0, 0), style, none);
  CHECK(none.empty());
  marker_mesh(back, 0.1f, Vec3f(1, 1, 1), none);
  CHECK(none.size() == 24);
}
}
