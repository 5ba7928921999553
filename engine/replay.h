// `divvox replay`: feeds a recording's blade poses and grab commands through the cutter and the PBD
// model step by step and writes summary.json, timings.csv and final.ply.
#pragma once

#include "engine/recording.h"

#include <cstdint>
#include <string>

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

// What replay found; exit code 0 when hashes matched, 1 when the replay diverged.
struct ReplayResult {
  uint32_t steps = 0;
  bool interrupted = false;      // stopped early by SIGINT (outputs cover the steps done)
  uint32_t frames_written = 0;
  uint32_t hash_checked = 0, hash_mismatched = 0;
  int64_t first_mismatch_step = -1;
  std::string final_hash;
  std::string summary_path;
};

// Throws InputError for bad input (recording, scene, mesh).
ReplayResult run_replay(const ReplayOptions& options);

}  // namespace dvx
