// The simulation step: the one way a step happens. The window, the headless replay, every test that
// checks a cut step and every benchmark call world_step (DESIGN §3 "Decisions of turn 3").
//
// Like MuJoCo's mj_step(const mjModel*, mjData*): an immutable WorldModel (the voxel model built once
// from the mesh, the parameters) and a mutable WorldState (the cut record and its surface, the
// simulation topology and dynamic state, the blade and the sweep it carries) passed apart. Undo is a
// copy of the WorldState. sim/ reads no clock: a caller that wants phase timings passes a StepClock.
#pragma once

#include "sim/blade_sweep.h"
#include "sim/cut.h"
#include "sim/pbd.h"
#include "sim/step_timings.h"
#include "sim/voxel_model.h"
#include "sim/world_to_rest.h"

#include <cstdint>
#include <optional>
#include <string>

namespace dvx {

// What never changes while the world runs: the fine lattice voxelized from the mesh, the parameters.
struct WorldModel {
  VoxelModel voxels;
  PbdParams params;      // resolution, simulation level, material, solver budget, dt
  bool physics = true;   // false: cutting only (the surface stays at rest)
};

// The grab tool's command for one step. kTarget starts a grab at `target` (the surface point under
// the cursor) or moves the target of the grab under way; kRelease lets go. Two kinds of grab:
// - stiffness > 0: the region grab (sim/pbd.h "Grab"): the particles of the point's embedding piece
//   and those within `radius` held at their offsets from the target, `stiffness` N/m in all, the
//   force clamped at `force_limit` N (0: no limit);
// - stiffness 0: the single-particle grab of the recordings written before it (the live particle
//   nearest the target on a spring of `compliance`), kept bit for bit.
struct GrabCommand {
  enum Kind : uint8_t { kNone, kTarget, kRelease } kind = kNone;
  Vec3d target = Vec3d::Zero();  // starts the grab at the point, or moves its target
  double compliance = 1e-4;      // the single-particle grab's (stiffness 0)
  double stiffness = 0.0;        // N/m, the region grab's total
  double radius = 0.0;           // m (scene lengths), the region's radius around the point
  double force_limit = 0.0;      // N, 0: none
};

// Everything that applies at one step (the same for a live session and a replay).
struct StepCommands {
  bool has_blade = false;  // a new blade pose (else the last one is kept)
  BladePose blade;
  bool cutting = false;    // with has_blade: the sweep into this pose cuts
  GrabCommand grab;
};

// Everything a step changes. Copyable: undo keeps copies of it.
struct WorldState {
  CutState cut;                 // the cut record and its dual-contoured surface
  std::optional<PbdState> pbd;  // simulation topology and dynamic state; empty without physics
  // The blade: its last pose in world space, and the sweep mapper carrying its samples' rest points
  // from one cutting step to the next (so a still blade cuts tissue moving into it).
  BladePose blade;
  bool have_blade = false, cutting = false;
  bool stroke_cutting = false;  // the last step cut (a stroke is under way: its end closes its seams)
  // The voxels the stroke under way refreshed (with physics; repeats dropped as they pile up), for
  // cut_close_seams at its end. Emptied when a stroke ends.
  std::vector<uint32_t> stroke_voxels;
  size_t stroke_voxels_unique = 0;  // its size when last made unique
  SweepMapper sweep;
  SweepMapStats sweep_stats;  // accumulated over the run
  uint32_t step = 0;          // the next step to run
};

// What one step did.
struct StepReport {
  uint32_t step = 0;
  bool cutting = false;
  StepTimings timings;
  CutStepStats cut;
  uint32_t sim_voxels_cut = 0;
  PbdCutStats pbd;  // what the PBD model update did (with physics)
  // The grab (with physics): the force it applies to the tissue, |sum of its multipliers| / h^2 of
  // the step's last substep (N with lengths in metres), the particles it holds and the candidates
  // it left out because an anchor holds them (held 0, anchored > 0: "held by an anchor").
  double grab_force_n = 0.0;
  uint32_t grab_held = 0, grab_anchored = 0;
};

// StepClock (sim/step_timings.h): the clock the caller lends the step for its report.

// How the caller runs a step: its workers, its clock, and whether the deformed surface is embedded
// every step (a headless replay that draws nothing turns it off and calls world_embed before reading).
struct StepContext {
  TaskRunner tasks;
  StepClock clock;
  bool embed_surface = true;
  // Called in a step that cut, after the cut and the model's update and before the dynamics: an
  // observer (the tests measure the new cut faces at the deformation they were cut in). It may read
  // the state and embed the surface (world_embed); it must change nothing else.
  void (*after_cut)(const WorldModel& model, WorldState& state, void* user) = nullptr;
  void* after_cut_user = nullptr;
};

// Builds the uncut state (and, with physics, the PBD model) of `model`. Returns false with a reason
// when the parameters do not fit the lattice (sim_resolution not dividing it into 2^l blocks). The
// surface is built over `tasks` (the same bits for any worker count).
bool world_init(const WorldModel& model, WorldState& state, std::string& error, const TaskRunner& tasks = {});

// One step at the fixed dt: the grab, the blade's sweep mapped to rest space and cut (when cutting),
// the surface update, the PBD model update, then the PBD step. Fills `report` when given.
void world_step(const WorldModel& model, WorldState& state, const StepCommands& commands, const StepContext& context,
                StepReport* report = nullptr);

// Brings pbd->data.deformed up to date after steps that skipped the embedding (embed_surface false).
void world_embed(const WorldModel& model, WorldState& state, const TaskRunner& tasks = {});

// State hash: the cut surface, and the live particles when the physics runs.
uint64_t world_hash(const WorldState& state);

}  // namespace dvx
