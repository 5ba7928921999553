// The window's simulation thread (ui/sim_runner.h), without a window: snapshots are published only
// once the renderer is done with the previous one (consecutive sequences, so every upload can be a
// dirty-range one), a held-back step goes out when the renderer catches up, and snapshots carry
// the split normals when asked.
#include "ui/sim_runner.h"

#include "engine/scene.h"
#include "render/normals.h"

#include <nlohmann/json.hpp>

#include <doctest/doctest.h>

#include <chrono>
#include <filesystem>
#include <thread>

using namespace dvx;

namespace {

// The next snapshot from the runner, waiting up to ~20 s (a loaded machine); nullptr if none came.
// The previous one is done with first (as the window does at the end of each frame's drawing).
const Snapshot* next_snapshot(SimRunner& sim) {
  sim.frame_done();
  for (int k = 0; k < 2000; ++k) {
    if (const Snapshot* s = sim.take()) return s;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return nullptr;
}

}  // namespace

TEST_SUITE("ui") {
TEST_CASE("sim runner: one snapshot per frame drawn, consecutive, of a later step, with its normals when asked") {
  const std::filesystem::path mesh = std::filesystem::path(DIVVOX_SOURCE_DIR) / "assets/meshes/bunny_npm.obj";
  REQUIRE(std::filesystem::exists(mesh));
  const Scene scene = parse_scene(nlohmann::json{{"mesh", mesh.string()}, {"resolution", 24}, {"sim_resolution", 6}},
                                  (std::filesystem::path(DIVVOX_SOURCE_DIR) / "scene.json").string());
  SimRunner sim;
  sim.set_cpu_normals(true);
  sim.open(scene, scene.pbd.dt);
  const Snapshot* first = next_snapshot(sim);
  REQUIRE(first != nullptr);
  uint64_t sequence = first->sequence;
  uint32_t step = first->step;
  for (int k = 0; k < 6; ++k) {
    // The renderer is slow: several steps run meanwhile, and no snapshot goes out before it is done.
    std::this_thread::sleep_for(std::chrono::milliseconds(120));
    CHECK(sim.take() == nullptr);
    const Snapshot* s = next_snapshot(sim);
    REQUIRE(s != nullptr);
    CHECK(s->sequence == sequence + 1);  // nothing published past the one not yet taken
    CHECK(s->step >= step);
    // The normals are those of this snapshot's own positions.
    REQUIRE(s->normals.size() == s->positions.size());
    REQUIRE(s->cut_normals.size() == s->positions.size());
    std::vector<Vec3f> surface, cut;
    split_vertex_normals(s->positions, s->triangles, s->triangle_flags, surface, cut);
    CHECK(surface == s->normals);
    sequence = s->sequence;
    step = s->step;
  }
  // The held-back step goes out once the renderer is done: a new snapshot of a later step arrives.
  const SimStatus status = sim.status();
  CHECK(status.step > step);
  const Snapshot* later = next_snapshot(sim);
  REQUIRE(later != nullptr);
  CHECK(later->step > step);
  sim.set_cpu_normals(false);
  const Snapshot* bare = next_snapshot(sim);  // the one already published may still carry them
  REQUIRE(bare != nullptr);
  const Snapshot* no_normals = next_snapshot(sim);
  REQUIRE(no_normals != nullptr);
  CHECK(no_normals->normals.empty());
  sim.stop();
}
}  // TEST_SUITE
