// One running simulation: the voxel model, the cut state, the PBD model and its worker threads, and
// the blade. The simulation thread owns a Session; nothing else touches it. Inputs arrive as
// StepCommands stamped with the step they apply to — the same for a live session (mouse) and a
// replay (recording), so a replay reproduces a live session bit for bit.
#pragma once

#include "engine/mesh_io.h"
#include "engine/scene.h"
#include "engine/task_pool.h"
#include "engine/timing.h"
#include "sim/world.h"

#include <memory>
#include <string>

namespace dvx {

// A running world: the scene it came from, its model and state (sim/world.h), and the worker
// threads its steps run on. The engine's step (session_step) is world_step with the engine's pool
// and clock.
struct Session {
  Scene scene;
  double dt = 1.0 / 60.0;
  LoadedMesh input;
  WorldModel world;
  WorldState state;
  std::unique_ptr<TaskPool> pool;
  double init_ms = 0.0, initial_mass = 0.0;
  double map_ms = 0.0;  // time spent mapping the blade to rest space, accumulated
  // Whether each step embeds the deformed surface (pbd->data.deformed). A headless replay that draws no
  // frames and writes no meshes turns it off (a quarter of a step's instructions on the default
  // recording) and calls session_embed before it reads the surface.
  bool embed_surface = true;
};

// PBD parameters of a scene at time step dt.
PbdParams pbd_params(const Scene& scene, double dt);

// Loads the scene's mesh, voxelizes it, builds the surface and (with physics) the PBD model.
// Throws InputError for bad input. With `progress`, loading the mesh reports on stderr.
void open_session(const Scene& scene, double dt, bool physics, int workers, Session& session, bool progress = false);

// Runs one step at the fixed dt (world_step on the session's pool, timed by the engine's clock).
StepReport session_step(Session& session, const StepCommands& commands);

// Brings pbd->data.deformed up to date after steps that skipped the embedding (embed_surface false).
void session_embed(Session& session);

// State hash: the cut surface, and the live particles when the physics runs.
uint64_t session_hash(const Session& session);

}  // namespace dvx
