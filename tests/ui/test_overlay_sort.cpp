// The solids drawn over the window's scene cache go far to near instead of being depth-tested among
// themselves (ui/overlay.h: sort_far_to_near), so the window need not clear its depth buffer.
#include "ui/overlay.h"

#include "render/camera.h"

#include <doctest/doctest.h>

#include <vector>

using namespace dvx;

namespace {

// A small triangle around (x, y, z), its colour's red channel `tag` (to follow it through the sort).
void add_triangle(std::vector<SolidVertex>& v, float x, float y, float z, float tag) {
  const float corners[3][2] = {{0.0f, 0.0f}, {0.1f, 0.0f}, {0.0f, 0.1f}};
  for (const auto& c : corners) v.push_back({{x + c[0], y + c[1], z}, {0.0f, 0.0f, 1.0f}, {tag, 0.0f, 0.0f, 1.0f}});
}

std::vector<float> tags(const std::vector<SolidVertex>& v) {
  std::vector<float> t;
  for (size_t k = 0; k < v.size(); k += 3) {
    // A triangle stays whole: its three corners carry the same tag.
    CHECK(v[k].color[0] == v[k + 1].color[0]);
    CHECK(v[k].color[0] == v[k + 2].color[0]);
    t.push_back(v[k].color[0]);
  }
  return t;
}

}  // namespace

TEST_SUITE("ui") {
TEST_CASE("overlay: the solids far to near along the camera's view axis, ties in their order") {
  // Eye space looks along -z: identity view, z -1 is near, z -5 far.
  std::vector<SolidVertex> v;
  add_triangle(v, 0.0f, 0.0f, -1.0f, 1.0f);
  add_triangle(v, 0.5f, 0.0f, -5.0f, 2.0f);
  add_triangle(v, 0.0f, 0.5f, -3.0f, 3.0f);
  add_triangle(v, 0.9f, 0.5f, -3.0f, 4.0f);  // as far as tag 3: stays after it
  std::vector<SolidVertex> sorted;
  std::vector<std::pair<float, uint32_t>> order;
  sort_far_to_near(v, Eigen::Matrix4f::Identity(), sorted, order);
  REQUIRE(sorted.size() == v.size());
  CHECK(tags(sorted) == std::vector<float>{2.0f, 3.0f, 4.0f, 1.0f});
  CHECK(sorted[0].position[0] == doctest::Approx(0.5f));  // the vertices travel with their triangle

  // The orbit camera from +x (yaw 90 degrees): what lies at larger x is nearer now.
  Camera camera;
  camera.target = Vec3f::Zero();
  camera.distance = 10.0f;
  camera.yaw = 1.5707963f;
  std::vector<SolidVertex> w;
  add_triangle(w, 2.0f, 0.0f, 0.0f, 1.0f);
  add_triangle(w, -2.0f, 0.0f, 0.0f, 2.0f);
  add_triangle(w, 0.0f, 0.0f, 0.0f, 3.0f);
  sort_far_to_near(w, view_matrix(camera), sorted, order);
  CHECK(tags(sorted) == std::vector<float>{2.0f, 3.0f, 1.0f});

  // Nothing to draw, nothing sorted.
  sort_far_to_near({}, Eigen::Matrix4f::Identity(), sorted, order);
  CHECK(sorted.empty());
}
}  // TEST_SUITE
