// Headless rendering: camera maths (no GL), then the renderer through an EGL surfaceless context
// (Mesa llvmpipe in CI) on a dual-contoured synthetic shape: coverage, PNG capture, cut colour,
// dirty-range uploads, dead triangle slots, wireframe, multisampling, growth, a real cut.
#include "render/camera.h"
#include "render/egl_context.h"
#include "render/renderer.h"
#include "sim/contour.h"
#include "sim/cut.h"
#include "sim/shapes.h"
#include "sim/voxelize.h"
#include "support.h"

#include <glad/gl.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <unistd.h>

using namespace dvx;

namespace {

constexpr int kWidth = 640, kHeight = 360;

// A CutSurface's slots with their dirty ranges (full = false), as the engine's snapshots hand them
// over; `normals` / `flags` sized like its slot arrays (render/ itself knows no CutSurface).
RenderMesh render_mesh_of(const CutSurface& surface, const std::vector<Vec3f>* normals = nullptr,
                          const std::vector<uint8_t>* flags = nullptr) {
  RenderMesh m;
  m.positions = surface.positions.data();
  m.vertex_count = uint32_t(surface.positions.size());
  m.normals = normals && normals->size() == surface.positions.size() ? normals->data() : nullptr;
  m.triangles = surface.triangles.data();
  m.triangle_count = uint32_t(surface.triangles.size());
  m.triangle_flags = flags && flags->size() == surface.triangles.size() ? flags->data() : nullptr;
  m.vertex_begin = surface.dirty_vertex_begin;
  m.vertex_end = surface.dirty_vertex_end;
  m.triangle_begin = surface.dirty_triangle_begin;
  m.triangle_end = surface.dirty_triangle_end;
  m.full = false;
  return m;
}

// The eight corners of a box.
std::vector<Vec3f> corners(const Aabb& box) {
  std::vector<Vec3f> out;
  for (int c = 0; c < 8; ++c)
    out.push_back(Vec3d(c & 1 ? box.max.x() : box.min.x(), c & 2 ? box.max.y() : box.min.y(),
                        c & 4 ? box.max.z() : box.min.z())
                      .cast<float>());
  return out;
}

// Clip-space position of a world point.
Eigen::Vector4f clip(const Camera& camera, float aspect, const Vec3f& p) {
  return projection_matrix(camera, aspect) * view_matrix(camera) * p.homogeneous();
}

// A torus (genus 1), voxelized and dual-contoured: the real SurfaceMesh path.
struct Shape {
  VoxelModel model;
  SurfaceMesh surface;
  std::vector<Vec3f> normals;
  Aabb box;
};

Shape make_shape(int resolution = 40) {
  Shape s;
  const TriMesh torus = make_torus(Vec3d(0.1, -0.2, 0.3), 1.0, 0.4, 48, 24);
  VoxelizeParams params;
  params.resolution = resolution;
  std::string error;
  REQUIRE_MESSAGE(voxelize(torus, params, s.model, error), error);
  s.surface = dual_contour(s.model);
  s.normals = vertex_normals(s.surface);
  for (const Vec3f& p : s.surface.positions) s.box.grow(p.cast<double>());
  REQUIRE(s.surface.triangles.size() > 500);
  return s;
}

// A current GL context for one test case; `ok` false (with a message) when EGL cannot give one.
// DIVVOX_REQUIRE_GL=1 turns that skip into a failure (for machines that must render).
struct GlScope {
  EglContext ctx;
  bool ok = false;
  GlScope() {
    std::string error;
    ok = create_egl_context(ctx, error);
    if (!ok) {
      DVX_SKIP_OR_FAIL_WITHOUT_GL(error);
    }
  }
  ~GlScope() { destroy_egl_context(ctx); }
};

// Background colour as the bytes the framebuffer holds.
std::array<int, 3> bytes_of(const Vec3f& c) {
  return {int(std::lround(c.x() * 255)), int(std::lround(c.y() * 255)), int(std::lround(c.z() * 255))};
}

// Fraction of pixels that differ from the background by more than 2 in any channel.
double coverage(const std::vector<uint8_t>& rgba, const Vec3f& background) {
  const auto bg = bytes_of(background);
  size_t hit = 0;
  for (size_t i = 0; i + 3 < rgba.size(); i += 4)
    if (std::abs(rgba[i] - bg[0]) > 2 || std::abs(rgba[i + 1] - bg[1]) > 2 || std::abs(rgba[i + 2] - bg[2]) > 2) ++hit;
  return double(hit) / double(rgba.size() / 4);
}

// Fraction of strongly red pixels (the test's cut colour on a grey surface).
double red_fraction(const std::vector<uint8_t>& rgba) {
  size_t hit = 0;
  for (size_t i = 0; i + 3 < rgba.size(); i += 4)
    if (rgba[i] > 60 && rgba[i] > 2 * rgba[i + 1] && rgba[i] > 2 * rgba[i + 2]) ++hit;
  return double(hit) / double(rgba.size() / 4);
}

// Draws and reads back, checking GL stayed error-free.
std::vector<uint8_t> draw(Renderer& r, const Camera& camera, const DrawOptions& options = {}) {
  renderer_draw(r, camera, options);
  std::vector<uint8_t> rgba;
  REQUIRE(renderer_read_pixels(r, rgba));
  std::string error;
  CHECK_MESSAGE(gl_check_errors(error), error);
  REQUIRE(rgba.size() == size_t(r.width) * r.height * 4);
  return rgba;
}

Renderer make_renderer(int samples = 0) {
  Renderer r;
  std::string error;
  REQUIRE_MESSAGE(renderer_init(r, kWidth, kHeight, error, samples), error);
  return r;
}

std::filesystem::path temp_dir() {
  const auto dir = std::filesystem::temp_directory_path() / ("divvox_render_test_" + std::to_string(getpid()));
  std::filesystem::create_directories(dir);
  return dir;
}

}  // namespace

TEST_SUITE("render") {

TEST_CASE("camera: framing keeps every box corner inside the view frustum") {
  const Aabb boxes[] = {
      [] { Aabb b; b.grow(Vec3d(-1, -1, -1)); b.grow(Vec3d(1, 1, 1)); return b; }(),
      [] { Aabb b; b.grow(Vec3d(10, 2, -3)); b.grow(Vec3d(14, 2.5, 9)); return b; }(),    // long in z, off origin
      [] { Aabb b; b.grow(Vec3d(-0.01, 0, 0)); b.grow(Vec3d(0.01, 0.3, 0.001)); return b; }(),  // thin, tall
  };
  for (const Aabb& box : boxes) {
    for (float aspect : {16.0f / 9.0f, 1.0f, 0.5f}) {
      const Camera camera = frame_box(box, aspect);
      CHECK(camera.z_near > 0.0f);
      CHECK(camera.z_far > camera.z_near);
      CHECK(camera.pitch > 0.0f);  // from above
      float widest = 0.0f;
      for (const Vec3f& p : corners(box)) {
        const Eigen::Vector4f c = clip(camera, aspect, p);
        REQUIRE(c.w() > 0.0f);
        const Vec3f ndc = c.head<3>() / c.w();
        CHECK(std::abs(ndc.x()) < 1.0f / 1.1f + 1e-4f);  // inside, with the 10 % margin
        CHECK(std::abs(ndc.y()) < 1.0f / 1.1f + 1e-4f);
        CHECK(std::abs(ndc.z()) < 1.0f);
        widest = std::max({widest, std::abs(ndc.x()), std::abs(ndc.y())});
      }
      // Tight: some corner reaches the margin (the box is not framed from needlessly far away).
      CHECK(widest > 0.85f);
      // The box centre is the image centre.
      const Vec3f centre = (0.5 * (box.min + box.max)).cast<float>();
      const Eigen::Vector4f c = clip(camera, aspect, centre);
      CHECK(std::abs(c.x() / c.w()) < 1e-4f);
      CHECK(std::abs(c.y() / c.w()) < 1e-4f);
    }
  }
}

TEST_CASE("camera: view basis / eye / rays") {
  Camera camera;
  camera.target = Vec3f(1, 2, 3);
  camera.distance = 5.0f;
  camera.yaw = 0.7f;
  camera.pitch = -0.4f;
  // Orthonormal right-handed basis; the view matrix puts the eye at the origin and the target on -z.
  const Vec3f f = camera_forward(camera), r = camera_right(camera), u = camera_up(camera);
  CHECK(f.norm() == doctest::Approx(1.0f));
  CHECK(std::abs(f.dot(r)) < 1e-6f);
  CHECK(std::abs(f.dot(u)) < 1e-6f);
  CHECK(r.cross(u).dot(-f) == doctest::Approx(1.0f));
  const Eigen::Matrix4f view = view_matrix(camera);
  CHECK((view * camera_eye(camera).homogeneous()).head<3>().norm() < 1e-5f);
  const Vec3f t = (view * camera.target.homogeneous()).head<3>();
  CHECK(t.head<2>().norm() < 1e-5f);
  CHECK(t.z() == doctest::Approx(-5.0f));
  // Straight up and down: still a proper basis (no degenerate cross product at the poles).
  camera.pitch = 1.5707964f;
  CHECK(camera_up(camera).norm() == doctest::Approx(1.0f));

  // The ray through the image centre is the view direction; the ray through any pixel projects
  // back onto that pixel.
  camera.pitch = 0.3f;
  const Viewport viewport{1280, 720};
  CHECK((ray_direction(camera, viewport, Eigen::Vector2f(640, 360)) - camera_forward(camera)).norm() < 1e-6f);
  for (const Eigen::Vector2f& pixel : {Eigen::Vector2f(0.5f, 0.5f), Eigen::Vector2f(1000.5f, 77.5f),
                                      Eigen::Vector2f(13.0f, 700.0f)}) {
    const Vec3f d = ray_direction(camera, viewport, pixel);
    CHECK(d.norm() == doctest::Approx(1.0f));
    const Eigen::Vector4f c = clip(camera, viewport.aspect(), camera_eye(camera) + 3.0f * d);
    const float px = (c.x() / c.w() * 0.5f + 0.5f) * viewport.width;
    const float py = (0.5f - c.y() / c.w() * 0.5f) * viewport.height;
    CHECK(px == doctest::Approx(pixel.x()).epsilon(1e-3));
    CHECK(py == doctest::Approx(pixel.y()).epsilon(1e-3));
  }
}

TEST_CASE("egl: context is GL 4.5 core or fails with a one-line reason") {
  EglContext ctx;
  std::string error;
  if (!create_egl_context(ctx, error)) {
    CHECK(!error.empty());
    CHECK(error.find('\n') == std::string::npos);
    CHECK(ctx.display == nullptr);
    DVX_SKIP_OR_FAIL_WITHOUT_GL(error);
    return;
  }
  MESSAGE("EGL " << ctx.platform << ": " << ctx.gl_renderer << ", " << ctx.gl_version);
  CHECK(!ctx.gl_renderer.empty());
  // A second context beside the first (they share the display); destroying one leaves the other.
  EglContext second;
  REQUIRE_MESSAGE(create_egl_context(second, error), error);
  destroy_egl_context(second);
  CHECK(create_egl_context(second, error));
  destroy_egl_context(second);
  destroy_egl_context(ctx);
  CHECK(ctx.display == nullptr);
  destroy_egl_context(ctx);  // twice is harmless
}

TEST_CASE("renderer: lit surface fills part of the frame / PNG capture") {
  GlScope gl;
  if (!gl.ok) return;
  const Shape shape = make_shape();
  Renderer r = make_renderer();
  renderer_upload(r, render_mesh_of(shape.surface, &shape.normals));
  const DrawOptions options;
  const Camera camera = frame_box(shape.box, Viewport{kWidth, kHeight}.aspect());
  const std::vector<uint8_t> rgba = draw(r, camera, options);
  const double covered = coverage(rgba, options.background);
  MESSAGE("coverage " << covered);
  CHECK(covered > 0.05);
  CHECK(covered < 0.95);
  // Lighting varies across the surface (not one flat colour).
  int lo = 255, hi = 0;
  const auto bg = bytes_of(options.background);
  for (size_t i = 0; i < rgba.size(); i += 4) {
    if (rgba[i] == bg[0] && rgba[i + 1] == bg[1] && rgba[i + 2] == bg[2]) continue;
    lo = std::min<int>(lo, rgba[i]);
    hi = std::max<int>(hi, rgba[i]);
  }
  CHECK(hi - lo > 60);
  // The top-left corner is background (the object is framed with a margin), the alpha opaque.
  CHECK(rgba[0] == bg[0]);
  CHECK(rgba[3] == 255);

  // PNG on disk with its signature.
  const std::string path = (temp_dir() / "torus.png").string();
  std::string error;
  REQUIRE_MESSAGE(write_png(path, r.width, r.height, rgba, error), error);
  std::ifstream in(path, std::ios::binary);
  char signature[8] = {};
  in.read(signature, 8);
  CHECK(std::string(signature, 8) == std::string("\x89PNG\r\n\x1a\n", 8));
  CHECK(std::filesystem::file_size(path) > 1000);
  // Unwritable path: a one-line error naming it.
  CHECK_FALSE(write_png("/nonexistent-dir/x.png", r.width, r.height, rgba, error));
  CHECK(error.find("/nonexistent-dir/x.png") != std::string::npos);
  CHECK_FALSE(write_png(path, r.width, r.height + 1, rgba, error));
  std::filesystem::remove_all(temp_dir());
  renderer_destroy(r);
}

// The window's scene cache copies only the colour into the window; its overlays test against the
// scene's depth texture instead (ViewTarget::scene_depth), so that texture must hold the drawn depth.
TEST_CASE("renderer: single-sampled, the depth texture holds the surface's depth exactly where it is drawn") {
  GlScope gl;
  if (!gl.ok) return;
  const Shape shape = make_shape();
  Renderer r = make_renderer();
  REQUIRE(r.depth_texture != 0);
  renderer_upload(r, render_mesh_of(shape.surface, &shape.normals));
  const DrawOptions options;
  const Camera camera = frame_box(shape.box, Viewport{kWidth, kHeight}.aspect());
  const std::vector<uint8_t> rgba = draw(r, camera, options);
  CHECK(renderer_target(r).scene_depth == 0);  // not presented: the depth is the target's own
  std::vector<float> depth(size_t(kWidth) * kHeight, -1.0f);
  glPixelStorei(GL_PACK_ALIGNMENT, 4);
  glGetTextureImage(r.depth_texture, 0, GL_DEPTH_COMPONENT, GL_FLOAT, GLsizei(depth.size() * 4), depth.data());
  std::string error;
  REQUIRE_MESSAGE(gl_check_errors(error), error);
  // rgba's row 0 is the top, the texture's the bottom.
  const auto bg = bytes_of(options.background);
  size_t covered = 0, agree = 0;
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      const uint8_t* c = &rgba[(size_t(kHeight - 1 - y) * kWidth + x) * 4];
      const bool drawn = std::abs(c[0] - bg[0]) > 2 || std::abs(c[1] - bg[1]) > 2 || std::abs(c[2] - bg[2]) > 2;
      const float d = depth[size_t(y) * kWidth + x];
      covered += drawn ? 1 : 0;
      agree += (drawn == (d < 1.0f) && d >= 0.0f) ? 1 : 0;
    }
  }
  CHECK(covered > depth.size() / 20);
  CHECK(agree == depth.size());
  renderer_destroy(r);
}

// The window spreads one image over two frames: the outer surface's first pieces, then the rest with
// the cut faces, into the second target of a double-buffered renderer while the last image is shown.
TEST_CASE("renderer: an image drawn in two halves equals it drawn at once, double buffering swaps the targets") {
  GlScope gl;
  if (!gl.ok) return;
  const Shape shape = make_shape();
  Renderer r = make_renderer();
  std::string error;
  REQUIRE_MESSAGE(renderer_double_buffer(r, error), error);
  REQUIRE(r.shown_framebuffer != 0);
  renderer_upload(r, render_mesh_of(shape.surface, &shape.normals));
  DrawOptions options;
  options.surface_pieces = 4;
  const Camera camera = frame_box(shape.box, Viewport{kWidth, kHeight}.aspect());
  const std::vector<uint8_t> whole = draw(r, camera, options);
  renderer_show_drawn(r);
  // Another view into the other target: the image read back is the one drawn, not the one shown.
  Camera side = camera;
  side.yaw += 1.2f;
  const std::vector<uint8_t> other = draw(r, side, options);
  CHECK(other != whole);
  // Two halves (the second neither clears nor skips the cut faces) into the target that held `whole`.
  renderer_show_drawn(r);
  options.pieces_end = 2;
  const std::vector<uint8_t> first = draw(r, camera, options);
  options.pieces_begin = 2;
  options.pieces_end = 64;
  const std::vector<uint8_t> both = draw(r, camera, options);
  CHECK(first != whole);
  CHECK(coverage(first, options.background) < coverage(whole, options.background));
  CHECK(both == whole);
  renderer_destroy(r);
}

TEST_CASE("renderer: cut triangles are drawn in the cut colour") {
  GlScope gl;
  if (!gl.ok) return;
  const Shape shape = make_shape();
  Renderer r = make_renderer();
  DrawOptions options;
  options.surface_color = Vec3f(0.7f, 0.7f, 0.7f);
  options.cut_color = Vec3f(0.9f, 0.05f, 0.05f);
  const Camera camera = frame_box(shape.box, Viewport{kWidth, kHeight}.aspect());

  std::vector<uint8_t> flags(shape.surface.triangles.size(), 0);
  renderer_upload(r, render_mesh_of(shape.surface, &shape.normals, &flags));
  const double red_none = red_fraction(draw(r, camera, options));
  // Every other triangle cut (spread over the whole surface), then all of them.
  for (size_t i = 0; i < flags.size(); i += 2) flags[i] = kTriangleCut;
  renderer_upload(r, render_mesh_of(shape.surface, &shape.normals, &flags));
  const std::vector<uint8_t> half = draw(r, camera, options);
  const double red_half = red_fraction(half);
  const double covered = coverage(half, options.background);
  MESSAGE("red fraction: none " << red_none << ", half " << red_half << " of coverage " << covered);
  CHECK(red_none == 0.0);
  CHECK(red_half > 0.2 * covered);
  CHECK(red_half < 0.8 * covered);
  std::fill(flags.begin(), flags.end(), kTriangleCut);
  renderer_upload(r, render_mesh_of(shape.surface, &shape.normals, &flags));
  CHECK(red_fraction(draw(r, camera, options)) > 0.9 * covered);
  renderer_destroy(r);
}

TEST_CASE("renderer: dirty-range uploads change only what they cover") {
  GlScope gl;
  if (!gl.ok) return;
  Shape shape = make_shape();
  Renderer r = make_renderer();
  const DrawOptions options;
  const Camera camera = frame_box(shape.box, Viewport{kWidth, kHeight}.aspect());
  renderer_upload(r, render_mesh_of(shape.surface, &shape.normals));
  const std::vector<uint8_t> before = draw(r, camera, options);
  REQUIRE(coverage(before, options.background) > 0.05);

  // Positions moved far off screen, but an empty dirty range: nothing is sent, the image stays.
  const uint32_t nv = uint32_t(shape.surface.positions.size());
  const std::vector<Vec3f> original = shape.surface.positions;
  for (Vec3f& p : shape.surface.positions) p.x() += 1000.0f;
  RenderMesh mesh = render_mesh_of(shape.surface, &shape.normals);
  mesh.full = false;
  renderer_upload(r, mesh);
  CHECK(r.last_upload_bytes == 0);
  CHECK(draw(r, camera, options) == before);

  // Half the vertices dirty: only they move (triangles stretch away), coverage changes.
  mesh.vertex_begin = 0;
  mesh.vertex_end = nv / 2;
  renderer_upload(r, mesh);
  CHECK(r.last_upload_bytes == uint64_t(nv / 2) * 24);
  const std::vector<uint8_t> partial = draw(r, camera, options);
  CHECK(partial != before);

  // All dirty: the object is gone.
  mesh.vertex_end = nv;
  renderer_upload(r, mesh);
  CHECK(coverage(draw(r, camera, options), options.background) < 0.001);

  // Back in place with a dirty range: the first image again, exactly.
  shape.surface.positions = original;
  mesh.positions = shape.surface.positions.data();
  renderer_upload(r, mesh);
  CHECK(draw(r, camera, options) == before);
  renderer_destroy(r);

  // A fresh renderer's first upload is full, whatever its ranges say.
  Renderer fresh = make_renderer();
  mesh.vertex_begin = mesh.vertex_end = mesh.triangle_begin = mesh.triangle_end = 0;
  renderer_upload(fresh, mesh);
  CHECK(draw(fresh, camera, options) == before);
  renderer_destroy(fresh);
}

TEST_CASE("renderer: dead triangle slots draw nothing / also in wireframe") {
  GlScope gl;
  if (!gl.ok) return;
  Shape shape = make_shape();
  Renderer r = make_renderer();
  DrawOptions options;
  const Camera camera = frame_box(shape.box, Viewport{kWidth, kHeight}.aspect());
  renderer_upload(r, render_mesh_of(shape.surface, &shape.normals));
  const double full = coverage(draw(r, camera, options), options.background);

  // Slots of one half dead (the half whose centroid has x above the centre), via a dirty range.
  const float mid = float(0.5 * (shape.box.min.x() + shape.box.max.x()));
  const uint32_t nt = uint32_t(shape.surface.triangles.size());
  for (Tri& t : shape.surface.triangles) {
    const Vec3f c = (shape.surface.positions[t[0]] + shape.surface.positions[t[1]] + shape.surface.positions[t[2]]) / 3;
    if (c.x() > mid) t = Tri{kDeadIndex, kDeadIndex, kDeadIndex};
  }
  RenderMesh mesh = render_mesh_of(shape.surface, &shape.normals);
  mesh.full = false;
  mesh.triangle_begin = 0;
  mesh.triangle_end = nt;
  renderer_upload(r, mesh);
  const double half = coverage(draw(r, camera, options), options.background);
  MESSAGE("coverage full " << full << ", half dead " << half);
  CHECK(half < 0.75 * full);
  CHECK(half > 0.25 * full);

  // Every slot dead: an empty image, filled or wireframe.
  for (Tri& t : shape.surface.triangles) t = Tri{kDeadIndex, kDeadIndex, kDeadIndex};
  renderer_upload(r, mesh);
  CHECK(coverage(draw(r, camera, options), options.background) == 0.0);
  options.wireframe = true;
  CHECK(coverage(draw(r, camera, options), options.background) == 0.0);
  renderer_destroy(r);
}

TEST_CASE("renderer: wireframe overlay / flat shading / multisampling / empty mesh") {
  GlScope gl;
  if (!gl.ok) return;
  const Shape shape = make_shape();
  const Camera camera = frame_box(shape.box, Viewport{kWidth, kHeight}.aspect());
  DrawOptions options;
  options.wire_color = Vec3f(0.0f, 1.0f, 0.0f);
  Renderer r = make_renderer();

  // Empty: background only.
  renderer_upload(r, RenderMesh{});
  CHECK(coverage(draw(r, camera, options), options.background) == 0.0);

  renderer_upload(r, render_mesh_of(shape.surface, &shape.normals));
  const std::vector<uint8_t> lit = draw(r, camera, options);
  auto green = [](const std::vector<uint8_t>& rgba) {
    size_t n = 0;
    for (size_t i = 0; i < rgba.size(); i += 4) n += rgba[i + 1] == 255 && rgba[i] == 0 && rgba[i + 2] == 0;
    return double(n) / double(rgba.size() / 4);
  };
  CHECK(green(lit) == 0.0);
  options.wireframe = true;
  const std::vector<uint8_t> wire = draw(r, camera, options);
  MESSAGE("wire pixels " << green(wire));
  CHECK(green(wire) > 0.02);
  CHECK(coverage(wire, options.background) == doctest::Approx(coverage(lit, options.background)).epsilon(0.05));
  options.wireframe = false;

  // Flat shading (no normals): same silhouette, different shading.
  renderer_upload(r, render_mesh_of(shape.surface));
  const std::vector<uint8_t> flat = draw(r, camera, options);
  CHECK(flat != lit);
  CHECK(coverage(flat, options.background) == doctest::Approx(coverage(lit, options.background)).epsilon(0.01));
  renderer_destroy(r);

  // 4x multisampling: same coverage within the antialiased rim.
  Renderer msaa = make_renderer(4);
  renderer_upload(msaa, render_mesh_of(shape.surface, &shape.normals));
  const std::vector<uint8_t> smooth = draw(msaa, camera, options);
  CHECK(coverage(smooth, options.background) == doctest::Approx(coverage(lit, options.background)).epsilon(0.05));

  // Blit (the window mode's path): resolves and copies the image into another framebuffer.
  Renderer target = make_renderer();
  renderer_blit(msaa, target.framebuffer, target.width, target.height);
  std::vector<uint8_t> copied;
  REQUIRE(renderer_read_pixels(target, copied));
  CHECK(copied == smooth);
  renderer_destroy(target);

  // Resize keeps the mesh.
  std::string error;
  REQUIRE_MESSAGE(renderer_resize(msaa, 320, 200, error), error);
  const std::vector<uint8_t> small = draw(msaa, frame_box(shape.box, 320.0f / 200.0f), options);
  CHECK(small.size() == size_t(320) * 200 * 4);
  CHECK(coverage(small, options.background) > 0.05);
  CHECK_FALSE(renderer_resize(msaa, 0, 10, error));
  CHECK(!error.empty());
  renderer_destroy(msaa);
}

TEST_CASE("renderer: buffers grow past capacity / incremental cut uploads match a full upload") {
  GlScope gl;
  if (!gl.ok) return;
  const Shape small_shape = make_shape(12);
  const Shape shape = make_shape(48);
  const Camera camera = frame_box(shape.box, Viewport{kWidth, kHeight}.aspect());
  const DrawOptions options;

  // A small mesh, then a larger one sent as a (too small) dirty range: growth forces a full upload.
  Renderer r = make_renderer();
  renderer_upload(r, render_mesh_of(small_shape.surface));
  RenderMesh grown = render_mesh_of(shape.surface);
  grown.full = false;
  grown.vertex_begin = grown.vertex_end = 0;
  grown.triangle_begin = grown.triangle_end = 0;
  renderer_upload(r, grown);
  CHECK(r.vertex_capacity >= shape.surface.positions.size());
  CHECK(r.triangle_capacity >= shape.surface.triangles.size());
  Renderer fresh = make_renderer();
  renderer_upload(fresh, render_mesh_of(shape.surface));
  CHECK(draw(r, camera, options) == draw(fresh, camera, options));

  // Cut the ring through both sides, step by step; each step sends only the CutSurface's dirty
  // slots. Flat shading, so the image depends on the slots' contents alone.
  CutState state;
  init_cut_state(shape.model, state);
  Renderer incremental = make_renderer();
  renderer_upload(incremental, render_mesh_of(state.surface));
  state.surface.clear_dirty();
  const double x0 = 0.4;
  BladePose previous{Vec3d(x0, -2.0, -1.0), Vec3d(x0, -2.0, 1.5)};
  uint64_t sent = 0;
  for (int step = 1; step <= 8; ++step) {
    const double y = -2.0 + 4.0 * step / 8.0;
    const BladePose next{Vec3d(x0, y, -1.0), Vec3d(x0, y, 1.5)};
    cut_step(shape.model, state, previous, next);
    previous = next;
    renderer_upload(incremental, render_mesh_of(state.surface));
    sent += incremental.last_upload_bytes;
    state.surface.clear_dirty();
  }
  renderer_upload(fresh, render_mesh_of(state.surface));
  const std::vector<uint8_t> a = draw(incremental, camera, options);
  const std::vector<uint8_t> b = draw(fresh, camera, options);
  CHECK(a == b);
  CHECK(a != draw(r, camera, options));  // the cut changed the surface
  MESSAGE("incremental bytes " << sent << " vs one full upload " << fresh.last_upload_bytes);
  renderer_destroy(r);
  renderer_destroy(fresh);
  renderer_destroy(incremental);
}

// An icosphere's positions (float) and triangles, for the shadow grid.
struct Ball {
  std::vector<Vec3f> positions;
  std::vector<Tri> triangles;
};
Ball make_ball(const Vec3f& centre, float radius) {
  const TriMesh mesh = make_icosphere(centre.cast<double>(), radius, 4);
  Ball b;
  for (const Vec3d& p : mesh.positions) b.positions.push_back(p.cast<float>());
  b.triangles = mesh.triangles;
  return b;
}

TEST_CASE("tray shadow grid: dark under the object along the light, clear far from it") {
  // A ball of radius 1, its centre 1.5 above the plane y = 0, the light straight up: the shadow is a
  // disc under it (its penumbra 0.15 x 1.5 wide).
  Ball ball = make_ball(Vec3f(0, 1.5f, 0), 1.0f);
  ball.positions.push_back(Vec3f(NAN, NAN, NAN));  // a free slot is skipped
  ball.triangles.push_back({kDeadIndex, kDeadIndex, kDeadIndex});
  const uint32_t nv = uint32_t(ball.positions.size()), nt = uint32_t(ball.triangles.size());
  TrayPlane tray;
  tray.centre = Vec3f::Zero();
  tray.half_size = 4.0f;
  std::vector<float> grid;
  ShadowScratch scratch;
  const int g = kTrayShadowGrid;
  const auto at = [&](float along_u, float along_v) {  // the cell at tray coordinates in [-1, 1]
    const int x = std::clamp(int((0.5f * along_u + 0.5f) * float(g)), 0, g - 1);
    const int y = std::clamp(int((0.5f * along_v + 0.5f) * float(g)), 0, g - 1);
    return grid[size_t(y) * size_t(g) + size_t(x)];
  };
  tray_shadow_grid(ball.positions.data(), nv, ball.triangles.data(), nt, tray, Vec3f::UnitY(), grid, scratch);
  REQUIRE(grid.size() == size_t(g) * size_t(g));
  CHECK(at(0.0f, 0.0f) > 0.95f);  // under the ball's centre
  CHECK(at(0.6f, 0.0f) == 0.0f);  // 2.4 away, the ball's radius is 1
  CHECK(at(0.0f, -0.6f) == 0.0f);
  // The vertices alone (no triangles) cast it too.
  tray_shadow_grid(ball.positions.data(), nv, nullptr, 0, tray, Vec3f::UnitY(), grid, scratch);
  CHECK(at(0.0f, 0.0f) > 0.8f);
  CHECK(at(0.6f, 0.0f) == 0.0f);
  // A slanted light moves the shadow away from under the ball, opposite to the light's tilt.
  const Vec3f light = Vec3f(1.0f, 1.0f, 0.0f).normalized();
  tray_shadow_grid(ball.positions.data(), nv, ball.triangles.data(), nt, tray, light, grid, scratch);
  float sum = 0.0f, moment = 0.0f;
  Vec3f u = tray.normal.cross(std::abs(tray.normal.x()) < 0.9f ? Vec3f::UnitX() : Vec3f::UnitY()).normalized();
  for (int y = 0; y < g; ++y) {
    for (int x = 0; x < g; ++x) {
      const float w = grid[size_t(y) * size_t(g) + size_t(x)];
      const Vec3f cell = u * ((float(x) + 0.5f) / float(g) * 2.0f - 1.0f) * tray.half_size +
                         tray.normal.cross(u) * ((float(y) + 0.5f) / float(g) * 2.0f - 1.0f) * tray.half_size;
      sum += w;
      moment += w * cell.x();
    }
  }
  REQUIRE(sum > 0.0f);
  MESSAGE("shadow centre x " << moment / sum << " (the ball at 1.5 above, light at 45 degrees: -1.5)");
  CHECK(moment / sum == doctest::Approx(-1.5f).epsilon(0.1));
}

TEST_CASE("tray shadow grid: a small piece casts a shadow as small and faint as itself") {
  // The ball of radius 1 hanging 1.5 above the tray, and a crumb of radius 0.05 (a grid cell is 0.0625)
  // lying on it 3.2 away: the crumb's shadow stays within four of its own radii and is faint (the
  // grid once made it a dark blob of 5 x 5 cells); a piece of radius 0.3 lying there casts a dark
  // shadow within twice its radius.
  const Ball ball = make_ball(Vec3f(0, 1.5f, 0), 1.0f);
  TrayPlane tray;
  tray.half_size = 4.0f;
  const int g = kTrayShadowGrid;
  const float cell = 2.0f * tray.half_size / float(g);
  std::vector<float> grid;
  ShadowScratch scratch;
  for (const float r : {0.05f, 0.3f}) {
    Ball both = ball;
    const Ball piece = make_ball(Vec3f(3.2f, r, 0), r);
    const uint32_t offset = uint32_t(both.positions.size());
    both.positions.insert(both.positions.end(), piece.positions.begin(), piece.positions.end());
    for (const Tri& t : piece.triangles) both.triangles.push_back({t[0] + offset, t[1] + offset, t[2] + offset});
    tray_shadow_grid(both.positions.data(), uint32_t(both.positions.size()), both.triangles.data(),
                     uint32_t(both.triangles.size()), tray, Vec3f::UnitY(), grid, scratch);
    // The piece's shadow: the cells nearer to it than to the ball's shadow.
    float darkest = 0.0f, reach = 0.0f;
    for (int y = 0; y < g; ++y) {
      for (int x = 0; x < g; ++x) {
        const Eigen::Vector2f c((float(x) + 0.5f) * cell - tray.half_size, (float(y) + 0.5f) * cell - tray.half_size);
        const float w = grid[size_t(y) * size_t(g) + size_t(x)];
        // The tray's axes: u = n x (1,0,0) = (0,0,-1), v = n x u = (-1,0,0): the piece is at v = -3.2.
        const float from_piece = (c - Eigen::Vector2f(0.0f, -3.2f)).norm();
        if (from_piece > 1.0f || w < 0.02f) continue;
        darkest = std::max(darkest, w);
        reach = std::max(reach, from_piece);
      }
    }
    MESSAGE("piece of radius " << r << ": shadow up to " << darkest << ", reaching " << reach);
    if (r < 0.1f) {
      CHECK(darkest < 0.35f);
      CHECK(reach < 4.0f * r);
    } else {
      CHECK(darkest > 0.8f);
      CHECK(reach < 2.0f * r);
    }
  }
}

TEST_CASE("renderer: a tray under the surface, darker where its shadow falls") {
  GlScope gl;
  if (!gl.ok) return;
  const Shape shape = make_shape();
  Renderer r = make_renderer();
  renderer_upload(r, render_mesh_of(shape.surface, &shape.normals));
  Camera camera = frame_box(shape.box, Viewport{kWidth, kHeight}.aspect());
  DrawOptions options;
  const Vec3d centre = 0.5 * (shape.box.min + shape.box.max);
  TrayPlane tray;
  tray.centre = Vec3f(float(centre.x()), float(shape.box.min.y()) - 0.01f, float(centre.z()));
  tray.half_size = float(shape.box.extent().maxCoeff());
  options.trays.push_back(tray);
  const std::vector<uint8_t> bare = draw(r, camera, DrawOptions());
  options.shadows = false;
  const std::vector<uint8_t> lit = draw(r, camera, options);
  options.shadows = true;
  tray_shadow_update(r, shape.surface.positions.data(), uint32_t(shape.surface.positions.size()), camera, options);
  REQUIRE(r.shadow_valid);
  const std::vector<uint8_t> shadowed = draw(r, camera, options);
  // The tray covers background; the shadow only darkens (never lightens) tray pixels, and some.
  CHECK(coverage(lit, options.background) > coverage(bare, options.background) + 0.05);
  size_t darker = 0, lighter = 0;
  for (size_t i = 0; i < lit.size(); i += 4) {
    darker += shadowed[i] + 8 < lit[i] ? 1 : 0;
    lighter += shadowed[i] > lit[i] + 1 ? 1 : 0;
  }
  MESSAGE("shadowed pixels " << darker);
  CHECK(darker > 200);
  CHECK(lighter == 0);
  renderer_destroy(r);
}

}  // TEST_SUITE
