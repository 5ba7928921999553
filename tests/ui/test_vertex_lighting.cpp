// The window on a software rasteriser lights the tissue per vertex (DrawOptions::vertex_lighting,
// render/renderer_shaders.inc: VERTEX_LIT): the same image as per-pixel lighting within a fraction
// of an 8-bit step on average, outer surface and cut faces alike, and only with back faces culled.
#include "render/camera.h"
#include "render/egl_context.h"
#include "render/normals.h"
#include "render/renderer.h"
#include "sim/shapes.h"
#include "support.h"

#include <doctest/doctest.h>

#include <cstdlib>
#include <vector>

using namespace dvx;

namespace {

// Draws and reads back the image (RGBA8).
std::vector<uint8_t> draw_image(Renderer& r, const Camera& camera, const DrawOptions& options) {
  renderer_draw(r, camera, options);
  std::vector<uint8_t> rgba;
  REQUIRE(renderer_read_pixels(r, rgba));
  return rgba;
}

// Mean absolute difference of the colour channels (of 255).
double mean_difference(const std::vector<uint8_t>& a, const std::vector<uint8_t>& b) {
  double sum = 0.0;
  for (size_t i = 0; i < a.size(); ++i) sum += (i % 4 == 3) ? 0 : std::abs(int(a[i]) - int(b[i]));
  return sum / double(a.size() / 4 * 3);
}

}  // namespace

TEST_CASE("vertex lighting: within an 8-bit step of per-pixel lighting on a finely meshed ball with cut faces") {
  EglContext ctx;
  std::string error;
  if (!create_egl_context(ctx, error)) {
    DVX_SKIP_OR_FAIL_WITHOUT_GL(error);
    return;
  }
  // A ball of ~20 k triangles, a few pixels each at 320 x 240 (as the liver's in the window), its
  // front cap flagged as cut faces.
  const TriMesh ball = make_icosphere(Vec3d::Zero(), 1.0, 5);
  std::vector<Vec3f> positions;
  for (const Vec3d& p : ball.positions) positions.push_back(p.cast<float>());
  std::vector<uint8_t> flags(ball.triangles.size(), 0);
  for (size_t t = 0; t < ball.triangles.size(); ++t) flags[t] = positions[ball.triangles[t][0]].z() > 0.6f ? 1 : 0;
  std::vector<Vec3f> normals, cut_normals;
  split_vertex_normals(positions, ball.triangles, flags, normals, cut_normals);
  RenderMesh mesh;
  mesh.positions = positions.data();
  mesh.normals = normals.data();
  mesh.cut_normals = cut_normals.data();
  mesh.vertex_count = uint32_t(positions.size());
  mesh.triangles = ball.triangles.data();
  mesh.triangle_count = uint32_t(ball.triangles.size());
  mesh.triangle_flags = flags.data();
  Renderer r;
  REQUIRE_MESSAGE(renderer_init(r, 320, 240, error), error);
  renderer_upload(r, mesh);
  Aabb box;
  for (const Vec3f& p : positions) box.grow(p.cast<double>());
  const Camera camera = frame_box(box, 320.0f / 240.0f);
  DrawOptions options;
  options.cull_back_faces = true;
  const std::vector<uint8_t> per_pixel = draw_image(r, camera, options);
  options.vertex_lighting = true;
  const std::vector<uint8_t> per_vertex = draw_image(r, camera, options);
  const double difference = mean_difference(per_pixel, per_vertex);
  MESSAGE("mean difference " << difference << " of 255");
  CHECK(difference > 0.0);  // the per-vertex programs ran
  CHECK(difference < 0.5);
  // Without culling the per-pixel programs draw (a back face seen through a hole flips its normal
  // per pixel): the same image as without the option.
  options.cull_back_faces = false;
  const std::vector<uint8_t> two_sided = draw_image(r, camera, options);
  options.vertex_lighting = false;
  CHECK(mean_difference(two_sided, draw_image(r, camera, options)) == 0.0);
  std::string gl_error;
  CHECK_MESSAGE(gl_check_errors(gl_error), gl_error);
  renderer_destroy(r);
  destroy_egl_context(ctx);
}
