// Running a recording headlessly: the recording's session stepped through its blade poses and grab
// commands, the state hashes checked, frames rendered on an EGL thread, the --meshes files and the
// --record recording written as the steps go. What `divvox replay` writes from the run afterwards
// (summary.json, timings.csv, the timings plot, final.ply) is harness/replay_outputs.h's.
#pragma once

#include "engine/playback.h"
#include "engine/recording.h"
#include "engine/session.h"
#include "engine/snapshot.h"

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace dvx {

struct ReplayOptions {
  std::string recording;
  std::string out_dir = "out/replay";
  bool physics = true;           // PBD deformation (false: --no-physics, geometry-only cutting)
  int workers = 2;               // threads for the PBD loops (results do not depend on it)
  bool render = false;           // draw every published snapshot offscreen (EGL) on a render thread
  uint32_t frames_every = 0;     // > 0: write DIR/frames/frame_NNNNN.png every N steps (implies render)
  uint32_t meshes_every = 0;     // > 0: write DIR/meshes/mesh_NNNNN.ply every N steps and after the last
  int width = 1280, height = 720;
  bool wireframe = false;
  bool realtime = false;         // pace the simulation at dt per step (default: as fast as possible)
  std::string record_path;       // when set: write the replayed session (poses + hashes) here
  uint32_t hash_every = kHashEvery;  // with record_path: a state hash every N steps
  bool progress = false;
};

// A replay: the recording, the simulation of its scene, the recorder of the replayed session and
// what the step loop did. open_replay fills the first part, run_replay_steps the rest; the outputs
// are written from it afterwards. Holds a Session (threads, unique pointers): built in place, never
// copied.
struct Replay {
  Playback playback;
  Session session;
  std::unique_ptr<SessionRecorder> recorder;  // with --record
  bool check_hashes = true;  // false when the recording's hashes were taken in the other physics mode

  // The step loop's product.
  std::vector<StepReport> rows;  // (steps run) one per step
  std::vector<FrameRow> frames;  // (frames rendered) one per frame of the render thread
  uint64_t voxels_cut = 0;
  uint32_t steps_done = 0;
  bool interrupted = false;      // stopped early by SIGINT (outputs cover the steps done)
  HashChecks checks;
  std::string final_hash;        // after the last step run
  double initial_volume = 0.0;   // of the uncut surface
  int64_t last_mesh = -1;        // step of the last DIR/meshes file written (-1: none)
  // Cutting strokes (runs of steps whose blade cuts): the surface's components after each, so
  // summary.json reports the pieces each stroke took off and the smallest piece (docs/cutting.md).
  struct Stroke {
    uint32_t first_step, last_step;
    uint32_t components;     // after the stroke
    int64_t created;         // components after minus before
    double smallest_volume;  // of the smallest component after the stroke (rest space)
  };
  std::vector<Stroke> strokes;
  bool in_stroke = false;
  uint32_t stroke_first = 0, components = 0;  // components before the stroke under way
};

// Loads the recording (its warnings on stderr), opens the session of its scene, creates the output
// folders and the recorder. Throws InputError for bad input (recording, scene, mesh).
void open_replay(const ReplayOptions& options, Replay& replay);

// Runs every recorded step (here, or on a thread while this one renders the frames; SIGINT stops it
// cleanly), then embeds the final surface, takes the final hash and ends the recorder. Throws
// InputError when rendering was asked for and is impossible.
void run_replay_steps(const ReplayOptions& options, Replay& replay);

}  // namespace dvx
