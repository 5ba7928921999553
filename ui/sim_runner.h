// The window's simulation thread: one Session stepped at the fixed dt in real time, fed
// StepCommands from a mutex-protected queue (each stamped with the step it applies to), publishing
// a snapshot after every step through a SnapshotExchange (fill_snapshot, as the headless replay
// does). The mouse feeds the queue; a played recording feeds each step its recorded commands through
// the playback module (engine/playback.h: next_commands, check_hash), as headless replay does; the
// thread records the commands it applied (SessionRecorder: a state hash every kHashEvery steps), so
// a recording made here replays bit for bit with `divvox replay`.
#pragma once

#include "engine/playback.h"
#include "engine/session.h"
#include "engine/snapshot.h"

#include <atomic>
#include <condition_variable>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace dvx {

struct StampedCommands {
  uint32_t step = 0;  // the step they apply to (a stamp already past applies at the next step)
  StepCommands commands;
};

// What the panels show; copied out under the runner's lock.
struct SimStatus {
  bool loading = false, ready = false, paused = false;
  uint32_t step = 0;  // the next step to run
  // When the step before `step` finished (SimPace: the simulated time between step boundaries); for
  // a step run ahead of the clock for a command, when it would have finished on the clock (later).
  Clock::time_point step_done = Clock::now();
  double dt = 1.0 / 60.0;
  Scene scene;
  Aabb bounds;            // the input mesh's bounds (framing, blade placement)
  uint64_t generation = 0;  // +1 per (re)built session
  uint32_t occupied_voxels = 0, divided_voxels = 0, sim_voxels_divided = 0, particles = 0;
  std::vector<StepTimings> timings;  // recent steps, oldest first
  std::vector<float> grab_force_n;   // the grab's force (N) of the same steps (StepReport::grab_force_n)
  // The grab now (the last step's report): on, the particles it holds, the candidates an anchor holds.
  bool grab_on = false;
  uint32_t grab_held = 0, grab_anchored = 0;
  // The anchored particles' positions (they do not move; refreshed at open and after cut steps).
  std::vector<Vec3f> anchors;
  uint64_t anchors_version = 0;  // +1 per refresh
  std::string error;                 // the last failed open/record request
  // Recording and playback.
  bool recording = false;
  std::string recording_path;
  bool playing = false, play_done = false;
  std::string play_path;
  std::shared_ptr<const Playback> playback;  // the recording being played (its blade poses are drawn)
  uint32_t play_last = 0, hash_checked = 0, hash_mismatched = 0;
  std::string final_hash;
  // Cutting feedback and undo (see SimRunner::keep_state).
  uint64_t voxels_cut = 0;  // voxels cut since the session opened (sum of the steps' voxels_cut)
  uint32_t undo_levels = 0, redo_levels = 0;
  uint64_t restores = 0;    // +1 per undo or redo carried out
  double restore_ms = 0.0;  // how long the last one took
  std::string undo_note;    // what the last undo / redo did (or why it did not)
  uint64_t undo_notes = 0;  // +1 per note
};

class SimRunner {
 public:
  static constexpr size_t kTimingHistory = 300;

  SimRunner();
  ~SimRunner();  // stops the thread
  SimRunner(const SimRunner&) = delete;
  SimRunner& operator=(const SimRunner&) = delete;

  SnapshotExchange& exchange() { return exchange_; }
  // Render side: the newest snapshot not seen yet, or nullptr (valid until the next take).
  // The simulation thread publishes a step's snapshot only once the renderer is done with the
  // previous one (a snapshot the renderer would skip costs its copy and normals for nothing, on the
  // cores the rasteriser needs); a step that was not published is published then. frame_done: the
  // renderer has drawn the snapshot it took (call it at the end of each frame's drawing): the next
  // one, published now, is as fresh as it can be at the next frame's start.
  // DIVVOX_SNAPSHOT_EVERY_STEP=1 publishes every step (for comparing).
  const Snapshot* take();
  void frame_done();
  // Snapshots carry split vertex normals computed on the simulation thread (the render thread then
  // only uploads them); off: the renderer computes them (GPU passes).
  void set_cpu_normals(bool on) { cpu_normals_.store(on); }
  // Sequence number of the first snapshot of the current session (the renderer uploads it in full).
  uint64_t generation_first_sequence() const { return generation_first_sequence_.load(); }

  // Requests, from any thread; the simulation thread carries them out between steps.
  // (Re)builds the session from `scene` (stops recording and playback). `record_path`: record it
  // from step 0. On failure the previous session stays and status().error says why.
  void open(const Scene& scene, double dt, const std::string& record_path = "");
  // Plays a recording: rebuilds its scene and feeds its commands at their steps; checks its hashes
  // (when taken with the physics on: the window always runs it); prints "final hash X" on stdout after
  // its last step. The path form reads it (throws InputError for a bad recording).
  void play(const std::string& recording_path);
  void play(std::shared_ptr<const Playback> playback);
  void start_recording(const std::string& path);  // restarts the current scene and records from step 0
  void stop_recording();
  void push(const StampedCommands& commands);
  void push_now(const StepCommands& commands);  // stamped with the next step
  void set_paused(bool paused);
  void step_once();
  // Live edits of the running session (refused while recording or playing: a recording holds
  // one scene). Apply to the PBD parameters at the next step.
  void set_solver(double dt, int iterations, const Vec3d& gravity);
  void stop();

  // Undo / redo (off while recording or playing: a recording is one unbroken session). keep_state
  // keeps a copy of the state before the next step (call it with an action's first command: the
  // press of a cut or a grab); undo restores the newest kept state (the current one goes on the redo
  // stack), redo the reverse. Sessions are deterministic, so a restored state continues exactly as it
  // did the first time. The copy excludes the immutable voxel model and the mesh.
  void keep_state();
  void undo();
  void redo();

  SimStatus status();
  uint32_t next_step() const { return next_step_.load(); }
  bool play_done() const { return play_done_.load(); }

 private:
  struct OpenRequest {
    Scene scene;
    double dt;
    std::string record_path;
    std::shared_ptr<const Playback> play;
  };
  void run();
  void do_open(OpenRequest& request);
  void do_step(std::unique_lock<std::mutex>& lock, Clock::duration early);
  // force: publish even if the renderer has not taken the previous snapshot (a new session, a restore).
  void publish(const StepTimings& timings, bool force);
  void finish_recording();
  // Undo (sim_runner.cpp, the section "Undo").
  // A kept state is a copy of the world's state (sim/world.h) and its hash.
  struct KeptState {
    WorldState state;
    uint64_t hash = 0;
  };
  static constexpr size_t kUndoLevels = 8;
  KeptState kept_of_session() const;
  void do_restore(bool redo, std::unique_lock<std::mutex>& lock);

  SnapshotExchange exchange_;
  std::thread thread_;
  std::mutex mutex_;
  std::condition_variable wake_;
  // Shared under mutex_.
  bool quit_ = false, paused_ = false;
  int single_steps_ = 0;
  std::deque<StampedCommands> queue_;
  std::unique_ptr<OpenRequest> open_request_;
  bool stop_record_request_ = false;
  std::string record_request_;
  bool solver_request_ = false;
  double req_dt_ = 0;
  int req_iterations_ = 0;
  Vec3d req_gravity_;
  bool keep_request_ = false;
  int undo_request_ = 0;  // > 0: undo, < 0: redo
  SimStatus status_;
  // Simulation-thread only.
  std::unique_ptr<Session> session_;
  std::unique_ptr<SessionRecorder> recorder_;
  std::shared_ptr<const Playback> playing_;
  PlaybackCursor play_cursor_;
  bool check_hashes_ = true;  // the played recording's hashes were taken with the physics on
  DirtyHistory history_;
  std::vector<KeptState> undo_stack_, redo_stack_;
  uint64_t published_ = 0;
  bool unpublished_ = false;  // a step ran whose snapshot was held back (the renderer was behind)
  bool every_step_ = false;   // DIVVOX_SNAPSHOT_EVERY_STEP=1
  StepTimings unpublished_timings_;
  std::atomic<uint64_t> taken_{0};  // sequence of the snapshot the renderer is done with
  uint64_t in_hand_ = 0;            // render thread: the sequence taken, not yet done
  std::atomic<bool> cpu_normals_{false};
  std::atomic<uint64_t> generation_first_sequence_{1};
  std::atomic<uint32_t> next_step_{0};
  std::atomic<bool> play_done_{false};
};

}  // namespace dvx
