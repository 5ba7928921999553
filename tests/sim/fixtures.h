// Small fixtures shared by the sim tests.
#pragma once

#include "sim/cut.h"
#include "sim/pbd.h"
#include "sim/voxelize.h"
#include "sim/world.h"

#include <doctest/doctest.h>

#include <algorithm>
#include <string>
#include <thread>
#include <vector>

namespace dvx_test {

// The voxel model of a mesh at a resolution (fails the test when voxelization refuses it).
inline dvx::VoxelModel voxelized(const dvx::TriMesh& mesh, int resolution) {
  dvx::VoxelModel model;
  std::string error;
  dvx::VoxelizeParams params;
  params.resolution = resolution;
  REQUIRE_MESSAGE(dvx::voxelize(mesh, params, model, error), error);
  return model;
}

// A voxelized mesh with its uncut state and PBD model (the sim tests' physics fixture).
struct PbdScene {
  dvx::VoxelModel model;
  dvx::CutState cut;
  dvx::PbdState pbd;
};

// Voxelizes `mesh` at `resolution`, builds the uncut state and the PBD model at `sim_resolution`.
inline void make_pbd_scene(PbdScene& scene, const dvx::TriMesh& mesh, int resolution, int sim_resolution,
                           dvx::PbdParams params) {
  scene.model = voxelized(mesh, resolution);
  dvx::init_cut_state(scene.model, scene.cut);
  params.resolution = resolution;
  params.sim_resolution = sim_resolution;
  std::string error;
  REQUIRE_MESSAGE(dvx::init_pbd(scene.model, scene.cut, params, scene.pbd.model, scene.pbd.data, error), error);
}

// A voxelized mesh as the product steps it (sim/world.h): the world's model and its state.
struct WorldScene {
  dvx::WorldModel model;
  dvx::WorldState state;
  dvx::PbdState& pbd() { return *state.pbd; }
  const dvx::VoxelModel& voxels() const { return model.voxels; }
};

// Voxelizes `mesh` at `resolution` and builds the world's state with the physics at `sim_resolution`.
inline void make_world(WorldScene& scene, const dvx::TriMesh& mesh, int resolution, int sim_resolution, dvx::PbdParams params) {
  scene.model.voxels = voxelized(mesh, resolution);
  params.resolution = resolution;
  params.sim_resolution = sim_resolution;
  scene.model.params = params;
  scene.model.physics = true;
  std::string error;
  REQUIRE_MESSAGE(dvx::world_init(scene.model, scene.state, error), error);
}

// One world step that sweeps the blade from `from` to `to`, cutting: a blade elsewhere (or none) is
// first moved to `from` without cutting, keeping what the sweep carries when it is already there.
inline dvx::StepReport world_cut_step(const dvx::WorldModel& model, dvx::WorldState& state, const dvx::BladePose& from,
                                      const dvx::BladePose& to, const dvx::TaskRunner& tasks = {}) {
  if (!state.have_blade || !(state.blade.a == from.a && state.blade.b == from.b)) {
    state.blade = from;
    state.have_blade = true;
    dvx::reset_sweep(state.sweep);
  }
  state.cutting = true;
  dvx::StepCommands commands;
  commands.has_blade = true;
  commands.blade = to;
  commands.cutting = true;
  dvx::StepContext context;
  context.tasks = tasks;
  dvx::StepReport report;
  dvx::world_step(model, state, commands, context, &report);
  return report;
}

// Moves the blade from `from` to `to` in `steps` equal cut steps, calling after(step) after each.
template <typename After>
void sweep_steps(const dvx::VoxelModel& model, dvx::CutState& state, const dvx::BladePose& from, const dvx::BladePose& to,
                 int steps, After&& after) {
  dvx::BladePose previous = from;
  for (int s = 1; s <= steps; ++s) {
    const double f = double(s) / steps;
    const dvx::BladePose next{from.a + f * (to.a - from.a), from.b + f * (to.b - from.b)};
    dvx::cut_step(model, state, previous, next);
    previous = next;
    after(s);
  }
}

// A task runner over std::thread (sim owns no threads; the engine has its own pool). It splits every
// loop into `workers` chunks whatever the grain, so a test with 2 workers always runs concurrently.
struct ThreadRunner {
  int workers = 2;
  uint64_t splits = 0;  // batches run on several threads (a test that compares worker counts checks some were)
  static void run(void* context, uint32_t count, uint32_t /*grain*/, void (*fn)(uint32_t, uint32_t, void*), void* user) {
    const uint32_t workers = uint32_t(std::max(1, static_cast<ThreadRunner*>(context)->workers));
    if (workers > 1 && count > 1) ++static_cast<ThreadRunner*>(context)->splits;
    const uint32_t chunk = std::max<uint32_t>(1, (count + workers - 1) / workers);
    std::vector<std::thread> threads;
    for (uint32_t begin = chunk; begin < count; begin += chunk) {
      threads.emplace_back(fn, begin, std::min(count, begin + chunk), user);
    }
    fn(0, std::min(count, chunk), user);
    for (std::thread& t : threads) t.join();
  }
  dvx::TaskRunner runner() { return dvx::TaskRunner{this, &ThreadRunner::run}; }
};

}  // namespace dvx_test
