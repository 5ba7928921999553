// One running simulation: the voxel model, the cut state, the PBD model and its worker threads, and
// the blade. The simulation thread owns a Session; nothing else touches it. Inputs arrive as
// StepCommands stamped with the step they apply to — the same for a live session (mouse) and a
// replay (recording), so a replay reproduces a live session bit for bit.
#pragma once

#include "engine/mesh_io.h"
#include "engine/scene.h"
#include "engine/task_pool.h"
#include "engine/timing.h"
#include "sim/cut.h"
#include "sim/pbd.h"
#include "sim/world_to_rest.h"

#include <memory>
#include <string>

namespace dvx {

// The grab tool's command for one step.
struct GrabCommand {
  enum Kind : uint8_t { kNone, kTarget, kRelease } kind = kNone;
  Vec3d target = Vec3d::Zero();  // starts the grab at the nearest particle, or moves it
  double compliance = 1e-4;
};

// Everything that applies at one step.
struct StepCommands {
  bool has_blade = false;  // a new blade pose (else the last one is kept)
  BladePose blade;
  bool cutting = false;    // with has_blade: the sweep into this pose cuts
  GrabCommand grab;
};

// What one step did and how long each phase took.
struct StepReport {
  uint32_t step = 0;
  bool cutting = false;
  StepTimings timings;
  CutStepStats cut;
  uint32_t sim_voxels_cut = 0;
  PbdCutStats pbd;  // what the PBD model update did (with physics)
};

struct Session {
  Scene scene;
  double dt = 1.0 / 60.0;
  LoadedMesh input;
  VoxelModel model;
  CutState cut;
  std::unique_ptr<PbdState> pbd;  // null without physics
  std::unique_ptr<TaskPool> pool;
  double init_ms = 0.0, initial_mass = 0.0;
  // The blade: its last pose in world space, and the sweep mapper carrying its samples' rest points
  // from one cutting step to the next (so a still blade cuts tissue moving into it).
  BladePose blade;
  SweepMapper sweep;
  SweepMapStats sweep_stats;  // accumulated over the session
  double map_ms = 0.0;        // time spent mapping the blade to rest space, accumulated
  bool have_blade = false, cutting = false;
  uint32_t step = 0;  // the next step to run
  // Whether each step embeds the deformed surface (pbd->deformed). A headless replay that draws no
  // frames and writes no meshes turns it off (a quarter of a step's instructions on the default
  // recording) and calls session_embed before it reads the surface.
  bool embed_surface = true;
};

// PBD parameters of a scene at time step dt.
PbdParams pbd_params(const Scene& scene, double dt);

// Loads the scene's mesh, voxelizes it, builds the surface and (with physics) the PBD model.
// Throws InputError for bad input. With `progress`, loading the mesh reports on stderr.
void open_session(const Scene& scene, double dt, bool physics, int workers, Session& session, bool progress = false);

// Runs one step at the fixed dt: the blade's sweep (when cutting), the PBD update, the grab.
StepReport session_step(Session& session, const StepCommands& commands);

// Brings pbd->deformed up to date after steps that skipped the embedding (embed_surface false).
void session_embed(Session& session);

// State hash: the cut surface, and the live particles when the physics runs.
uint64_t session_hash(const Session& session);

}  // namespace dvx
