#include "engine/replay.h"

#include "engine/errors.h"
#include "engine/output.h"
#include "engine/timing.h"
#ifdef DIVVOX_HAS_RENDER
#include "engine/headless_render.h"
#endif
#include "sim/cut.h"
#include "sim/state_hash.h"
#include "sim/surface_metrics.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <thread>

namespace dvx {
namespace {

// SIGINT stops a replay cleanly: the step loop ends, outputs cover the steps done.
std::atomic<bool> g_interrupted{false};
void on_sigint(int) { g_interrupted.store(true); }

// Closes the stroke under way (its last step `last`): the components of the surface now.
void end_stroke(uint32_t last, Replay& replay) {
  const std::vector<double> volumes = component_volumes(compact_surface(replay.session.state.cut.surface));
  const double smallest = volumes.empty() ? 0.0 : *std::min_element(volumes.begin(), volumes.end());
  replay.strokes.push_back({replay.stroke_first, last, uint32_t(volumes.size()),
                         int64_t(volumes.size()) - int64_t(replay.components), smallest});
  replay.components = uint32_t(volumes.size());
  replay.in_stroke = false;
}

// --meshes: DIR/meshes/mesh_NNNNN.ply, the deformed surface in world space with its cut faces marked.
void write_step_mesh(const ReplayOptions& options, uint32_t step, Replay& replay) {
  Session& session = replay.session;
  session_embed(session);
  char name[32];
  std::snprintf(name, sizeof(name), "mesh_%05u.ply", step);
  write_cut_mesh_ply((std::filesystem::path(options.out_dir) / "meshes" / name).string(), session.state.cut.surface,
                     session.state.pbd ? &session.state.pbd->data.deformed : nullptr);
  replay.last_mesh = step;
}

// The recording's camera for frames from this step on: usable only with a finite target and a
// positive distance (otherwise the default framing).
void publish_camera(Snapshot& slot, bool on, const CameraCommand& c) {
  slot.has_camera = on;
  slot.camera_target = c.target;
  slot.camera_distance = c.distance;
  slot.camera_yaw = c.yaw;
  slot.camera_pitch = c.pitch;
}

// Steps the session through the playback: each step's recorded commands, then the hash check and the
// recorder; with `exchange`, every step's surface goes to the render thread.
void simulate(const ReplayOptions& options, SnapshotExchange* exchange, Replay& replay) {
  const Playback& playback = replay.playback;
  Session& session = replay.session;
  PlaybackCursor cursor;
  DirtyHistory dirty_history;
  CameraCommand camera;
  bool camera_on = false;
  const uint32_t last = playback.last_step();
  const Clock::time_point start = Clock::now();
  for (uint32_t step = 0; step <= last && !playback.steps.empty(); ++step) {
    if (g_interrupted.load()) {
      replay.interrupted = true;
      break;
    }
    // --speed realtime: a step every dt of wall-clock time.
    if (options.realtime) std::this_thread::sleep_until(start + std::chrono::duration<double>(playback.dt * step));
    // The recorded commands of this step (none: the blade keeps its pose).
    const PlaybackStep* recorded = next_commands(playback, cursor, step);
    const StepCommands commands = recorded ? recorded->commands : StepCommands();
    const CameraCommand* camera_set = recorded && recorded->has_camera ? &recorded->camera : nullptr;
    if (camera_set != nullptr) {
      camera = *camera_set;
      camera_on = camera.target.allFinite() && camera.distance > 0.0f;
    }
    const StepReport row = session_step(session, commands);
    replay.voxels_cut += row.cut.voxels_cut;
    replay.rows.push_back(row);
    if (row.cutting && !replay.in_stroke) {
      replay.in_stroke = true;
      replay.stroke_first = step;
    } else if (!row.cutting && replay.in_stroke) {
      end_stroke(step - 1, replay);
    }

    // Determinism: compare with the recorded hash; record what was applied.
    if (recorded && replay.check_hashes) check_hash(*recorded, session, replay.checks);
    if (replay.recorder) replay.recorder->record(step, commands, camera_set, session);

    // Hand the surface to the render thread (capture frames every frames_every steps).
    if (exchange != nullptr) {
      const bool capture = options.frames_every > 0 && step % options.frames_every == 0;
      exchange->publish(
          [&](Snapshot& slot, uint64_t slot_sequence) {
            fill_snapshot(slot, slot_sequence, session.state.cut.surface,
                          session.state.pbd ? &session.state.pbd->data.deformed : nullptr, dirty_history, step,
                          row.timings);
            publish_camera(slot, camera_on, camera);
          },
          capture);
      session.state.cut.surface.clear_dirty();
    }
    replay.steps_done = step + 1;
    if (options.meshes_every > 0 && (step % options.meshes_every == 0 || step == last)) {
      write_step_mesh(options, step, replay);
    }
    if (options.progress && step % 200 == 0) std::fprintf(stderr, "\rdivvox: replay step %u / %u", step, last);
  }
  if (replay.in_stroke && replay.steps_done > 0) end_stroke(replay.steps_done - 1, replay);
}

// The simulation on its own thread and the EGL render thread here (EGL contexts belong to the thread
// that made them). Throws InputError when rendering is impossible.
void simulate_and_render(const std::function<void(SnapshotExchange*)>& simulate_on, const ReplayOptions& options,
                         const Session& session, std::vector<FrameRow>& frames) {
#ifdef DIVVOX_HAS_RENDER
  std::string error;
  if (!probe_headless_render(error)) throw_input(options.recording, "headless rendering: " + error);
  HeadlessRenderOptions ro;
  ro.width = options.width;
  ro.height = options.height;
  ro.frames_dir = options.frames_every > 0 ? (std::filesystem::path(options.out_dir) / "frames").string() : "";
  ro.wireframe = options.wireframe;
  ro.framing = mesh_bounds(session.input.mesh);
  ro.planes = session.scene.pbd.planes;
  if (!ro.frames_dir.empty()) make_output_dir(ro.frames_dir);
  SnapshotExchange exchange;
  std::thread sim_thread([&] {
    simulate_on(&exchange);
    exchange.finish();
  });
  const bool rendered = run_headless_render(exchange, ro, frames, error);
  sim_thread.join();
  if (!rendered) throw_input(options.recording, "headless rendering: " + error);
#else
  (void)simulate_on;
  (void)session;
  (void)frames;
  throw_input(options.recording, "this build has no renderer (configured with -DDIVVOX_GRAPHICS=OFF); drop --frames");
#endif
}

}  // namespace

void open_replay(const ReplayOptions& options, Replay& replay) {
  replay.playback = load_playback(options.recording);
  const Playback& playback = replay.playback;
  for (const std::string& warning : playback.warnings) std::fprintf(stderr, "divvox: warning: %s\n", warning.c_str());

  // The simulation of the recording's scene; the recorder of the replayed session.
  Session& session = replay.session;
  open_session(playback.scene, playback.dt, options.physics, options.workers, session, options.progress);
  // Without frames the surface is read only by the --meshes files and the final outputs: embedded
  // there, not every step.
  session.embed_surface = options.render || options.frames_every > 0;
  replay.initial_volume = surface_stats(compact_surface(session.state.cut.surface)).volume;
  replay.components = uint32_t(component_volumes(compact_surface(session.state.cut.surface)).size());
  make_output_dir(options.out_dir);
  if (options.meshes_every > 0) make_output_dir((std::filesystem::path(options.out_dir) / "meshes").string());
  if (!options.record_path.empty()) {
    replay.recorder = std::make_unique<SessionRecorder>(options.record_path, playback.scene, playback.dt, options.physics,
                                                        options.hash_every);
  }
  std::string warning;
  replay.check_hashes = hashes_apply(playback, options.physics, warning);
  if (!replay.check_hashes) std::fprintf(stderr, "divvox: warning: %s\n", warning.c_str());
}

void run_replay_steps(const ReplayOptions& options, Replay& replay) {
  // The step loop: here, or on a thread while this one renders.
  const auto simulate_on = [&](SnapshotExchange* exchange) { simulate(options, exchange, replay); };
  std::signal(SIGINT, on_sigint);
  if (options.render || options.frames_every > 0) {
    simulate_and_render(simulate_on, options, replay.session, replay.frames);
  } else {
    simulate_on(nullptr);
  }
  std::signal(SIGINT, SIG_DFL);
  if (options.progress) std::fprintf(stderr, "\n");
  // An interrupted replay still ends with the mesh of its last step.
  if (options.meshes_every > 0 && replay.steps_done > 0 && replay.last_mesh != int64_t(replay.steps_done) - 1) {
    write_step_mesh(options, replay.steps_done - 1, replay);
  }

  session_embed(replay.session);  // the final surface and summary read it
  replay.final_hash = hash_hex(session_hash(replay.session));
  if (replay.recorder) replay.recorder->finish(replay.session);
}

}  // namespace dvx
