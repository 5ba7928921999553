#include "engine/session.h"
#include "engine/options.h"

#include "engine/errors.h"
#include "engine/voxelize_job.h"
#include "sim/voxelize.h"

#include <chrono>
#include <cstdlib>

namespace dvx {
namespace {

// The engine's clock lent to the step (sim/ reads none).
double steady_ms(void*) {
  return std::chrono::duration<double, std::milli>(Clock::now().time_since_epoch()).count();
}

}  // namespace

PbdParams pbd_params(const Scene& scene, double dt) {
  PbdParams p = scene.pbd;
  p.dt = dt;
  return p;
}

void open_session(const Scene& scene, double dt, bool physics, int workers, Session& s, bool progress) {
  s.scene = scene;
  s.dt = dt;
  s.input = load_mesh(scene.mesh_path, progress);
  // The mesh's unit into metres (the scene's lengths are scaled already: scene.h).
  if (scene.metres_per_unit != 1.0) {
    for (Vec3d& p : s.input.mesh.positions) p *= scene.metres_per_unit;
  }
  check_voxelize_memory(scene.mesh_path, mesh_bounds(s.input.mesh), s.input.mesh.triangles.size(), scene.pbd.resolution);
  VoxelizeParams params;
  params.resolution = scene.pbd.resolution;
  std::string error;
  if (!voxelize(s.input.mesh, params, s.world.voxels, error)) throw_input(scene.mesh_path, error);
  s.world.params = pbd_params(scene, dt);
  s.world.physics = physics;
  // The workers build the surface and update it with each cut, and run the solver.
  s.pool = std::make_unique<TaskPool>(workers);
  const Clock::time_point t0 = Clock::now();
  if (!world_init(s.world, s.state, error, s.pool->runner())) throw_input(scene.file, error);
  s.init_ms = ms_between(t0, Clock::now());
  if (physics) {
    // DIVVOX_CHUNK_WORK: the work per chunk of a step's shared batches (sim/pbd.h kDefaultChunkWork;
    // lower splits smaller batches across the workers, the same bits either way).
    const EnvOptions env = read_env_options();
    if (env.chunk_work != 0) s.state.pbd->data.chunk_work = env.chunk_work;
    // The bodies side by side (sim/pbd.h PbdCache::halves) only where a second thread can take a
    // half; DIVVOX_BODY_HALVES forces it (the same bits either way).
    s.state.pbd->data.body_halves = env.body_halves >= 0 ? env.body_halves == 1 : s.pool->workers() > 1;
    s.initial_mass = total_mass(s.state.pbd->model);
  }
}

StepReport session_step(Session& s, const StepCommands& commands) {
  StepContext context;
  if (s.pool) context.tasks = s.pool->runner();
  context.clock.now_ms = &steady_ms;
  context.embed_surface = s.embed_surface;
  StepReport report;
  world_step(s.world, s.state, commands, context, &report);
  s.map_ms += report.timings.map_ms;
  return report;
}

void session_embed(Session& s) {
  if (s.state.pbd && !s.embed_surface) world_embed(s.world, s.state, s.pool->runner());
}

uint64_t session_hash(const Session& s) { return world_hash(s.state); }

}  // namespace dvx
