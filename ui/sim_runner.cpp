#include "ui/sim_runner.h"

#include "engine/errors.h"
#include "engine/options.h"
#include "engine/timing.h"
#include "render/normals.h"
#include "sim/state_hash.h"

#include <cstdlib>
#include <string>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>

namespace dvx {
namespace {

// Later commands of the same step win (a newer pose, a newer grab target or a release).
void merge(StepCommands& into, const StepCommands& from) {
  if (from.has_blade) {
    into.has_blade = true;
    into.blade = from.blade;
    into.cutting = from.cutting;
  }
  if (from.grab.kind != GrabCommand::kNone) into.grab = from.grab;
}

// The anchored particles' positions, for the window's pins (status under the runner's lock).
void collect_anchors(const Session& session, SimStatus& status) {
  status.anchors.clear();
  const std::optional<PbdState>& pbd = session.state.pbd;
  for (size_t p = 0; pbd && p < pbd->data.position.size(); ++p) {
    if (pbd->model.refs[p] > 0 && pbd->model.inv_mass[p] == 0.0)
      status.anchors.push_back(pbd->data.position[p].cast<float>());
  }
  ++status.anchors_version;
}

int default_workers() {
  const unsigned n = std::thread::hardware_concurrency();
  return int(std::clamp(n > 1 ? n - 1 : 1u, 1u, 4u));
}

}  // namespace

SimRunner::SimRunner() {
  every_step_ = read_env_options().snapshot_every_step;
  thread_ = std::thread([this] { run(); });
}

SimRunner::~SimRunner() { stop(); }

void SimRunner::stop() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    quit_ = true;
  }
  wake_.notify_all();
  exchange_.close();
  if (thread_.joinable()) thread_.join();
}

void SimRunner::open(const Scene& scene, double dt, const std::string& record_path) {
  std::lock_guard<std::mutex> lock(mutex_);
  open_request_ = std::make_unique<OpenRequest>(OpenRequest{scene, dt, record_path, nullptr});
  status_.loading = true;
  wake_.notify_all();
}

void SimRunner::play(const std::string& recording_path) {
  // Read and typed once (a bad grab or camera is refused here, before anything starts).
  auto playback = std::make_shared<const Playback>(load_playback(recording_path));  // throws InputError
  for (const std::string& w : playback->warnings) std::fprintf(stderr, "divvox: warning: %s\n", w.c_str());
  play(std::move(playback));
}

void SimRunner::play(std::shared_ptr<const Playback> playback) {
  std::lock_guard<std::mutex> lock(mutex_);
  open_request_ = std::make_unique<OpenRequest>(OpenRequest{playback->scene, playback->dt, "", playback});
  status_.loading = true;
  wake_.notify_all();
}

void SimRunner::start_recording(const std::string& path) {
  std::lock_guard<std::mutex> lock(mutex_);
  record_request_ = path;
  wake_.notify_all();
}

void SimRunner::stop_recording() {
  std::lock_guard<std::mutex> lock(mutex_);
  stop_record_request_ = true;
  wake_.notify_all();
}

void SimRunner::push(const StampedCommands& c) {
  std::lock_guard<std::mutex> lock(mutex_);
  // Keep the queue sorted by step (stable for equal stamps).
  auto at = std::upper_bound(queue_.begin(), queue_.end(), c.step,
                             [](uint32_t step, const StampedCommands& q) { return step < q.step; });
  queue_.insert(at, c);
  wake_.notify_all();  // its step may run at once (run)
}

void SimRunner::push_now(const StepCommands& commands) { push({next_step_.load(), commands}); }

void SimRunner::set_paused(bool paused) {
  std::lock_guard<std::mutex> lock(mutex_);
  paused_ = paused;
  status_.paused = paused;
  wake_.notify_all();
}

void SimRunner::step_once() {
  std::lock_guard<std::mutex> lock(mutex_);
  ++single_steps_;
  wake_.notify_all();
}

void SimRunner::set_solver(double dt, int iterations, const Vec3d& gravity) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (status_.recording || status_.playing) {
    status_.error = "solver edits are off while recording or playing (a recording holds one scene)";
    return;
  }
  solver_request_ = true;
  req_dt_ = dt;
  req_iterations_ = iterations;
  req_gravity_ = gravity;
  wake_.notify_all();
}

SimStatus SimRunner::status() {
  std::lock_guard<std::mutex> lock(mutex_);
  return status_;
}

const Snapshot* SimRunner::take() {
  const Snapshot* s = exchange_.take();
  if (s) in_hand_ = s->sequence;
  return s;
}

void SimRunner::frame_done() {
  if (in_hand_ <= taken_.load()) return;
  taken_.store(in_hand_);
  wake_.notify_all();  // a held-back step can go out now
}

void SimRunner::publish(const StepTimings& timings, bool force) {
  // Held back while the renderer has not taken the last one; the surface's dirty ranges keep
  // growing until the next publish, so that one carries every change.
  if (!force && !every_step_ && taken_.load() < published_) {
    unpublished_ = true;
    unpublished_timings_ = timings;
    return;
  }
  unpublished_ = false;
  Session& s = *session_;
  const uint32_t step = s.state.step == 0 ? 0 : s.state.step - 1;
  const bool normals = cpu_normals_.load();
  session_embed(s);  // the deformed surface of this state (the steps held back skipped it)
  exchange_.publish(
      [&](Snapshot& slot, uint64_t slot_sequence) {
        fill_snapshot(slot, slot_sequence, s.state.cut.surface, s.state.pbd ? &s.state.pbd->data.deformed : nullptr,
                      history_, step, timings);
        const Clock::time_point t0 = Clock::now();
        if (normals) {
          split_vertex_normals(slot.positions, slot.triangles, slot.triangle_flags, slot.normals, slot.cut_normals);
        } else {
          slot.normals.clear();
          slot.cut_normals.clear();
        }
        slot.normals_ms = ms_between(t0, Clock::now());
      },
      false);
  ++published_;
  s.state.cut.surface.clear_dirty();
}

void SimRunner::do_open(OpenRequest& request) {
  auto session = std::make_unique<Session>();
  std::string error;
  std::unique_ptr<SessionRecorder> recorder;
  try {
    open_session(request.scene, request.dt, true, default_workers(), *session);
    // The surface is embedded when a snapshot goes out (publish), not every step: the renderer takes
    // one every frame or two.
    session->embed_surface = false;
    if (!request.record_path.empty()) {
      recorder = std::make_unique<SessionRecorder>(request.record_path, request.scene, request.dt, true);
    }
  } catch (const InputError& e) {
    error = e.what();
  } catch (const std::bad_alloc&) {
    error = "out of memory opening the scene";
  } catch (const std::exception& e) {
    error = std::string("internal error: ") + e.what();
  }
  std::unique_lock<std::mutex> lock(mutex_);
  status_.loading = false;
  if (!error.empty()) {
    status_.error = error;
    std::fprintf(stderr, "divvox: error: %s\n", error.c_str());
    return;
  }
  // The new session replaces the old one; the queue starts empty, a played recording at its start.
  session_ = std::move(session);
  recorder_ = std::move(recorder);
  playing_ = request.play;
  play_cursor_ = PlaybackCursor();
  play_done_.store(false);
  queue_.clear();
  // The window always runs the physics: hashes taken without it are not compared.
  std::string warning;
  check_hashes_ = !playing_ || hashes_apply(*playing_, true, warning);
  if (!check_hashes_) std::fprintf(stderr, "divvox: warning: %s\n", warning.c_str());
  status_.error.clear();
  status_.ready = true;
  status_.scene = session_->scene;
  status_.dt = session_->dt;
  status_.bounds = mesh_bounds(session_->input.mesh);
  ++status_.generation;
  status_.step = 0;
  status_.step_done = Clock::now();
  status_.timings.clear();
  status_.grab_force_n.clear();
  status_.grab_on = false;
  status_.grab_held = status_.grab_anchored = 0;
  collect_anchors(*session_, status_);
  status_.recording = recorder_ != nullptr;
  status_.recording_path = request.record_path;
  status_.playing = playing_ != nullptr;
  status_.play_done = false;
  status_.play_path = playing_ ? playing_->file : "";
  status_.playback = playing_;
  status_.play_last = playing_ ? playing_->last_step() : 0;
  status_.hash_checked = status_.hash_mismatched = 0;
  status_.final_hash.clear();
  status_.occupied_voxels = session_->world.voxels.occupied_voxels;
  status_.divided_voxels = 0;
  status_.voxels_cut = 0;
  undo_stack_.clear();
  redo_stack_.clear();
  status_.undo_levels = status_.redo_levels = 0;
  status_.undo_note.clear();
  keep_request_ = false;
  undo_request_ = 0;
  next_step_.store(0);
  lock.unlock();
  // The first snapshot of this session: the renderer uploads it in full.
  history_ = DirtyHistory();
  history_.first_sequence = published_ + 1;
  generation_first_sequence_.store(published_ + 1);
  publish(StepTimings(), true);
}

void SimRunner::do_step(std::unique_lock<std::mutex>& lock, Clock::duration early) {
  Session& s = *session_;
  const uint32_t step = s.state.step;
  // This step's commands: the played recording's, then every queued entry stamped up to it (later win).
  StepCommands commands;
  const PlaybackStep* recorded = playing_ ? next_commands(*playing_, play_cursor_, step) : nullptr;
  if (recorded != nullptr) commands = recorded->commands;
  while (!queue_.empty() && queue_.front().step <= step) {
    merge(commands, queue_.front().commands);
    queue_.pop_front();
  }
  lock.unlock();

  const StepReport report = session_step(s, commands);
  const Clock::time_point step_done = Clock::now();
  // Record what was applied, at the step it was applied to.
  if (recorder_) {
    try {
      recorder_->record(step, commands, nullptr, s);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "divvox: error: recording: %s\n", e.what());
      recorder_.reset();
    }
  }
  // Playback: the recording's hashes are checked; its last step prints the final hash.
  HashChecks checks;
  if (recorded != nullptr && check_hashes_ && !check_hash(*recorded, s, checks)) {
    std::fprintf(stderr, "divvox: warning: %s: state hash differs from the recording at step %u\n",
                 playing_->file.c_str(), step);
  }
  const bool done = playing_ && !play_done_.load() && step >= playing_->last_step();
  std::string final_hash;
  if (done) {
    final_hash = hash_hex(session_hash(s));
    std::printf("final hash %s (played %s to step %u)\n", final_hash.c_str(), playing_->file.c_str(), step);
    std::fflush(stdout);
  }
  publish(report.timings, false);

  lock.lock();
  next_step_.store(s.state.step);
  status_.step = s.state.step;
  status_.step_done = step_done + early;  // when it would have finished on the clock
  status_.timings.push_back(report.timings);
  if (status_.timings.size() > kTimingHistory) status_.timings.erase(status_.timings.begin());
  status_.grab_force_n.push_back(float(report.grab_force_n));
  if (status_.grab_force_n.size() > kTimingHistory) status_.grab_force_n.erase(status_.grab_force_n.begin());
  status_.grab_on = s.state.pbd && grab_active(s.state.pbd->data);
  status_.grab_held = report.grab_held;
  status_.grab_anchored = report.grab_anchored;
  if (report.sim_voxels_cut > 0) collect_anchors(s, status_);
  status_.divided_voxels = uint32_t(s.state.cut.divided.size());
  status_.voxels_cut += report.cut.voxels_cut;
  if (s.state.pbd) {
    status_.sim_voxels_divided = uint32_t(sim_voxels_divided(s.state.pbd->model));
    status_.particles = uint32_t(s.state.pbd->data.position.size() - s.state.pbd->model.free_particles.size());
  }
  status_.recording = recorder_ != nullptr;
  status_.hash_checked += checks.checked;
  status_.hash_mismatched += checks.mismatched;
  if (done) {
    status_.play_done = true;
    status_.final_hash = final_hash;
    play_done_.store(true);
  }
}

void SimRunner::finish_recording() {
  // The state after the last step ends the recording (unless the periodic hash already did).
  if (recorder_ && session_) {
    try {
      recorder_->finish(*session_);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "divvox: error: recording: %s\n", e.what());
    }
  }
  recorder_.reset();
}

// ---- Undo ------------------------------------------------------------------------------------

void SimRunner::keep_state() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (status_.recording || status_.playing) return;
  keep_request_ = true;
  wake_.notify_all();
}

void SimRunner::undo() {
  std::lock_guard<std::mutex> lock(mutex_);
  ++undo_request_;
  wake_.notify_all();
}

void SimRunner::redo() {
  std::lock_guard<std::mutex> lock(mutex_);
  --undo_request_;
  wake_.notify_all();
}

SimRunner::KeptState SimRunner::kept_of_session() const {
  KeptState k;
  k.state = session_->state;
  k.hash = session_hash(*session_);
  return k;
}

// Carries out one undo (or redo) request with the lock held on entry and exit: swaps the session's
// state with the newest kept one, publishes it in full, drops the queued commands (they were meant
// for steps that are now undone).
void SimRunner::do_restore(bool redo, std::unique_lock<std::mutex>& lock) {
  undo_request_ += redo ? 1 : -1;
  std::vector<KeptState>& from = redo ? redo_stack_ : undo_stack_;
  std::vector<KeptState>& to = redo ? undo_stack_ : redo_stack_;
  const char* what = redo ? "redo" : "undo";
  if (status_.recording || status_.playing) {
    status_.undo_note = std::string(what) + " is off while recording or playing";
    ++status_.undo_notes;
    return;
  }
  if (from.empty()) {
    status_.undo_note = std::string("nothing to ") + what;
    ++status_.undo_notes;
    return;
  }
  KeptState kept = std::move(from.back());
  from.pop_back();
  queue_.clear();
  lock.unlock();
  const Clock::time_point t0 = Clock::now();
  Session& s = *session_;
  // The current state goes on the other stack: moved out, not copied (it is replaced at once).
  KeptState now;
  now.hash = session_hash(s);
  now.state = std::move(s.state);
  s.state = std::move(kept.state);
  const uint64_t hash = session_hash(s);
  // A full upload of the restored surface (the renderer's slots no longer match).
  history_ = DirtyHistory();
  history_.first_sequence = published_ + 1;
  generation_first_sequence_.store(published_ + 1);
  publish(StepTimings(), true);
  const double ms = ms_between(t0, Clock::now());
  std::printf("%s: back to step %u (hash %s, kept %s) in %.1f ms\n", what, s.state.step, hash_hex(hash).c_str(),
              hash_hex(kept.hash).c_str(), ms);
  std::fflush(stdout);
  lock.lock();
  if (to.size() == kUndoLevels) to.erase(to.begin());
  to.push_back(std::move(now));
  next_step_.store(s.state.step);
  status_.step = s.state.step;
  status_.step_done = Clock::now();
  status_.divided_voxels = uint32_t(s.state.cut.divided.size());
  status_.undo_levels = uint32_t(undo_stack_.size());
  status_.redo_levels = uint32_t(redo_stack_.size());
  ++status_.restores;
  collect_anchors(*session_, status_);
  status_.restore_ms = ms;
  char note[96];
  std::snprintf(note, sizeof note, "%s: back to step %u (%.0f ms)", what, s.state.step, ms);
  status_.undo_note = note;
  ++status_.undo_notes;
}

void SimRunner::run() {
  // The simulation thread (and the workers it starts, which inherit it) yields to the render and
  // rasteriser threads when the cores are short: on a software rasteriser they share the same cores,
  // and a frame that waits behind a step shows as a stutter, while a step that waits a little only
  // slows the simulated time. DIVVOX_SIM_NICE=N sets the niceness (default 4; 0: none).
  const int nice_value = read_env_options().sim_nice;
  if (nice_value > 0) setpriority(PRIO_PROCESS, id_t(syscall(SYS_gettid)), nice_value);
  std::unique_lock<std::mutex> lock(mutex_);
  Clock::time_point next_time = Clock::now();
  while (!quit_) {
    if (open_request_) {
      std::unique_ptr<OpenRequest> request = std::move(open_request_);
      finish_recording();  // a recording ends with its session
      lock.unlock();
      do_open(*request);
      lock.lock();
      next_time = Clock::now();
      continue;
    }
    if (!record_request_.empty() && session_) {
      // Recording starts from step 0 of the current scene, so it replays.
      open_request_ = std::make_unique<OpenRequest>(OpenRequest{session_->scene, session_->dt, record_request_, nullptr});
      record_request_.clear();
      status_.loading = true;
      continue;
    }
    if (stop_record_request_) {
      stop_record_request_ = false;
      finish_recording();
      status_.recording = false;
    }
    if (solver_request_ && session_) {
      solver_request_ = false;
      Session& s = *session_;
      s.dt = req_dt_;
      s.scene.pbd.dt = req_dt_;
      s.scene.pbd.iterations = req_iterations_;
      s.scene.pbd.gravity = req_gravity_;
      s.world.params = pbd_params(s.scene, req_dt_);
      if (s.state.pbd) {
        s.state.pbd->model.params.dt = req_dt_;
        s.state.pbd->model.params.iterations = req_iterations_;
        s.state.pbd->model.params.gravity = req_gravity_;
      }
      status_.dt = req_dt_;
      status_.scene = s.scene;
    }
    if (undo_request_ != 0 && session_) {
      do_restore(undo_request_ < 0, lock);
      continue;
    }
    if (keep_request_ && session_) {
      keep_request_ = false;
      if (undo_stack_.size() == kUndoLevels) undo_stack_.erase(undo_stack_.begin());
      lock.unlock();
      KeptState kept = kept_of_session();
      std::printf("undo: kept step %u (hash %s)\n", kept.state.step, hash_hex(kept.hash).c_str());
      std::fflush(stdout);
      lock.lock();
      undo_stack_.push_back(std::move(kept));
      redo_stack_.clear();
      status_.undo_levels = uint32_t(undo_stack_.size());
      status_.redo_levels = 0;
    }
    // A held-back snapshot goes out as soon as the renderer has taken the previous one.
    if (session_ && unpublished_ && taken_.load() >= published_) {
      lock.unlock();
      publish(unpublished_timings_, false);
      lock.lock();
      continue;
    }
    if (!session_ || (paused_ && single_steps_ == 0)) {
      wake_.wait_for(lock, std::chrono::milliseconds(50));
      next_time = Clock::now();
      continue;
    }
    Clock::duration early = Clock::duration::zero();  // how far ahead of the clock this step runs
    if (single_steps_ > 0 && paused_) {
      --single_steps_;
    } else {
      // Real time: one step per dt; a simulation that falls behind drops the lost time. A command
      // queued for the next step (the blade, a grab) runs it at once, up to one step ahead of the
      // clock: on the clock alone it waited up to a dt for its step, a frame's worth of the input-to-
      // cut latency (issue 31). The steps keep their times on the clock (next_time), so the pace is
      // the same; the step's finish is reported at its time on the clock (status_.step_done).
      const Clock::time_point now = Clock::now();
      const auto dt = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(session_->dt));
      const bool command_waits = !queue_.empty() && queue_.front().step <= session_->state.step;
      if (now < next_time && !(command_waits && now + dt >= next_time)) {
        wake_.wait_until(lock, next_time);
        continue;
      }
      early = now < next_time ? next_time - now : Clock::duration::zero();
      next_time += dt;
      if (now > next_time + 5 * dt) next_time = now;
    }
    do_step(lock, early);
  }
  finish_recording();
  lock.unlock();
  exchange_.finish();
}

}  // namespace dvx
