// Playback and recording of sessions: the one place that knows what a recording's step lines mean.
// A recording (engine/recording.h reads and writes its lines) is parsed once into typed step commands
// — blade, cutting, grab, camera, hash — and driven step by step through `next_commands`; the state
// hashes are checked in one way (`check_hash`, with the physics-mode rule of `hashes_apply`) and a
// session is written in one way (`SessionRecorder`). Headless replay (engine/replay.cpp), the window
// (ui/sim_runner.cpp) and the tests all use this module, so they agree on what a recording does.
#pragma once

#include "engine/recording.h"
#include "engine/session.h"

#include <nlohmann/json_fwd.hpp>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace dvx {

// The camera a recording sets for frames from its step on ("camera" in step lines):
// {"target": [x,y,z], "distance": d, "yaw": radians, "pitch": radians}.
struct CameraCommand {
  Vec3f target = Vec3f::Zero();
  float distance = 1.0f, yaw = 0.0f, pitch = 0.0f;
};

// Everything a recording says about one step. Lines of the same step are merged (a pose and a hash
// may share a step).
struct PlaybackStep {
  uint32_t step = 0;
  StepCommands commands;  // what the session applies: blade pose, cutting, grab
  bool has_camera = false;
  CameraCommand camera;
  bool has_hash = false;
  std::string hash;       // lower-case hex state hash after this step
  uint32_t line = 0;      // first line of this step in the file (1-based)
};

// A recording parsed once: its scene, time step, physics mode and typed steps.
struct Playback {
  std::string file;
  Scene scene;
  double dt = 1.0 / 60.0;
  int physics = -1;                   // the mode its hashes were taken in: 1 / 0, -1 unknown
  std::vector<PlaybackStep> steps;    // one per step that has a line, increasing step
  std::vector<std::string> warnings;  // e.g. the truncated last line
  uint32_t last_step() const { return steps.empty() ? 0 : steps.back().step; }
};

// Reads a recording and types every step line. Throws InputError ("FILE: line N: problem") for a bad
// recording (read_recording's rules) and for a bad "grab" or "camera" value, before anything runs.
Playback load_playback(const std::string& path);
// The same from a recording already read.
Playback playback_of(const Recording& recording);

// Where a playback stands: the index of the next PlaybackStep not handed out yet.
struct PlaybackCursor {
  size_t next = 0;
};
// The recorded step `step` (nullptr when the recording has no line for it). Ask for increasing steps:
// recorded steps before `step` that were never asked for are skipped.
const PlaybackStep* next_commands(const Playback& playback, PlaybackCursor& cursor, uint32_t step);

// Whether a playback's hashes can be compared with a run with / without the physics: hashes taken in
// the other mode never match. False with `warning` saying so.
bool hashes_apply(const Playback& playback, bool physics, std::string& warning);

// Hash checks of a run against its recording.
struct HashChecks {
  uint32_t checked = 0, mismatched = 0;
  int64_t first_mismatch_step = -1;
};
// After `recorded.step`: compares the session's state hash with the recorded one (when it has one).
// Returns false on a mismatch.
bool check_hash(const PlaybackStep& recorded, const Session& session, HashChecks& checks);

// A grab command from a recording's "grab" value: {"target": [x,y,z], "stiffness": N/m, "radius": r,
// "force_limit": N} (the region grab), {"target": [x,y,z], "compliance": c} (the single-particle grab
// of older recordings) or "release".
// Throws InputError naming `file` and `line` otherwise.
GrabCommand parse_grab(const nlohmann::json& grab, const std::string& file, uint32_t line);
nlohmann::json grab_to_json(const GrabCommand& grab);

// The one writer of a session: each step's commands as applied (one line per step that had any), a
// state hash every `hash_every` steps from step 0, and the state after the last step. A recording
// written here replays bit for bit (`divvox replay`, the window's --play).
class SessionRecorder {
 public:
  // Creates `path` with the header (scene, dt, physics mode). Throws InputError when it cannot.
  SessionRecorder(const std::string& path, const Scene& scene, double dt, bool physics,
                  uint32_t hash_every = kHashEvery);
  // After session_step(session, commands) ran `step`: its commands (and the camera set at it, if any)
  // and, every hash_every steps, the session's state hash.
  void record(uint32_t step, const StepCommands& commands, const CameraCommand* camera, const Session& session);
  // Ends the recording with the state after the session's last step (unless the periodic hash of that
  // step was just written). Idempotent.
  void finish(const Session& session);
  const std::string& path() const { return path_; }

 private:
  RecordingWriter writer_;
  std::string path_;
  uint32_t hash_every_;
  int64_t last_hash_step_ = -1;
  bool finished_ = false;
};

}  // namespace dvx
