#include "engine/replay.h"

#include "engine/errors.h"
#include "engine/output.h"
#include "engine/playback.h"
#include "engine/plot.h"
#include "engine/session.h"
#include "engine/snapshot.h"
#include "engine/stats.h"
#include "engine/timing.h"
#ifdef DIVVOX_HAS_RENDER
#include "engine/headless_render.h"
#endif
#include "sim/cut.h"
#include "sim/pbd.h"
#include "sim/state_hash.h"
#include "sim/surface_metrics.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <sstream>
#include <thread>

namespace dvx {
namespace {

// SIGINT stops a replay cleanly: the step loop ends, outputs cover the steps done.
std::atomic<bool> g_interrupted{false};
void on_sigint(int) { g_interrupted.store(true); }

// What the step loop did.
struct ReplayRun {
  std::vector<StepReport> rows;  // (steps run) one per step
  uint64_t voxels_cut = 0;
  uint32_t steps_done = 0;
  bool interrupted = false;
  HashChecks checks;
  double initial_volume = 0.0;  // of the uncut surface
  double wall_s = 0.0;          // from the first step to the last output written
  int64_t last_mesh = -1;       // step of the last DIR/meshes file written (-1: none)
  // Cutting strokes (runs of steps whose blade cuts): the surface's components after each, so
  // summary.json reports the pieces each stroke took off and the smallest piece (docs/cutting.md).
  struct Stroke {
    uint32_t first_step, last_step;
    uint32_t components;    // after the stroke
    int64_t created;        // components after minus before
    double smallest_volume;  // of the smallest component after the stroke (rest space)
  };
  std::vector<Stroke> strokes;
  bool in_stroke = false;
  uint32_t stroke_first = 0, components = 0;  // components before the stroke under way
};

// Closes the stroke under way (its last step `last`): the components of the surface now.
void end_stroke(const Session& session, uint32_t last, ReplayRun& run) {
  const std::vector<double> volumes = component_volumes(compact_surface(session.state.cut.surface));
  const double smallest = volumes.empty() ? 0.0 : *std::min_element(volumes.begin(), volumes.end());
  run.strokes.push_back({run.stroke_first, last, uint32_t(volumes.size()),
                         int64_t(volumes.size()) - int64_t(run.components), smallest});
  run.components = uint32_t(volumes.size());
  run.in_stroke = false;
}

// --meshes: DIR/meshes/mesh_NNNNN.ply, the deformed surface in world space with its cut faces marked.
void write_step_mesh(const ReplayOptions& options, Session& session, uint32_t step, ReplayRun& run) {
  session_embed(session);
  char name[32];
  std::snprintf(name, sizeof(name), "mesh_%05u.ply", step);
  write_cut_mesh_ply((std::filesystem::path(options.out_dir) / "meshes" / name).string(), session.state.cut.surface,
                     session.state.pbd ? &session.state.pbd->deformed : nullptr);
  run.last_mesh = step;
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
void simulate(const Playback& playback, const ReplayOptions& options, bool check_hashes, Session& session,
              SessionRecorder* recorder, SnapshotExchange* exchange, ReplayRun& run) {
  PlaybackCursor cursor;
  DirtyHistory dirty_history;
  CameraCommand camera;
  bool camera_on = false;
  const uint32_t last = playback.last_step();
  const Clock::time_point start = Clock::now();
  for (uint32_t step = 0; step <= last && !playback.steps.empty(); ++step) {
    if (g_interrupted.load()) {
      run.interrupted = true;
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
    run.voxels_cut += row.cut.voxels_cut;
    run.rows.push_back(row);
    if (row.cutting && !run.in_stroke) {
      run.in_stroke = true;
      run.stroke_first = step;
    } else if (!row.cutting && run.in_stroke) {
      end_stroke(session, step - 1, run);
    }

    // Determinism: compare with the recorded hash; record what was applied.
    if (recorded && check_hashes) check_hash(*recorded, session, run.checks);
    if (recorder) recorder->record(step, commands, camera_set, session);

    // Hand the surface to the render thread (capture frames every frames_every steps).
    if (exchange != nullptr) {
      const bool capture = options.frames_every > 0 && step % options.frames_every == 0;
      exchange->publish(
          [&](Snapshot& slot, uint64_t slot_sequence) {
            fill_snapshot(slot, slot_sequence, session.state.cut.surface, session.state.pbd ? &session.state.pbd->deformed : nullptr,
                          dirty_history, step, row.timings);
            publish_camera(slot, camera_on, camera);
          },
          capture);
      session.state.cut.surface.clear_dirty();
    }
    run.steps_done = step + 1;
    if (options.meshes_every > 0 && (step % options.meshes_every == 0 || step == last)) {
      write_step_mesh(options, session, step, run);
    }
    if (options.progress && step % 200 == 0) std::fprintf(stderr, "\rdivvox: replay step %u / %u", step, last);
  }
  if (run.in_stroke && run.steps_done > 0) end_stroke(session, run.steps_done - 1, run);
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

// Per-step samples of each phase for summary.json: cut, surface and total over the steps whose blade
// sweep crossed lattice edges; deform (with the physics) and step over every step.
struct PhaseSamples {
  std::vector<double> cut, surface, total, deform, step;
};

// timings.csv (one row per step) and the phase samples.
PhaseSamples write_timings_csv(const std::vector<StepReport>& rows, bool physics, const std::filesystem::path& out) {
  std::ostringstream csv;
  csv << "step,cut_ms,surface_ms,deform_ms,total_ms,cut_voxels,edges_hit,edges_cut,voxels_divided,"
         "vertices_changed,triangles_changed,cutting,sim_voxels_cut\n";
  PhaseSamples samples;
  for (const StepReport& r : rows) {
    if (physics) samples.deform.push_back(r.timings.deform_ms);
    samples.step.push_back(r.timings.total_ms);
    csv << r.step << ',' << r.timings.cut_ms << ',' << r.timings.surface_ms << ',' << r.timings.deform_ms << ','
        << r.timings.total_ms << ',' << r.cut.voxels_cut << ',' << r.cut.edges_hit << ',' << r.cut.edges_cut << ','
        << r.cut.voxels_divided << ',' << r.cut.vertices_changed << ',' << r.cut.triangles_changed << ','
        << (r.cutting ? 1 : 0) << ',' << r.sim_voxels_cut << '\n';
    if (r.cut.edges_hit > 0) {
      samples.cut.push_back(r.timings.cut_ms);
      samples.surface.push_back(r.timings.surface_ms);
      samples.total.push_back(r.timings.total_ms);
    }
  }
  write_text_file((out / "timings.csv").string(), csv.str());
  return samples;
}

// timings.svg and timings.png: one panel per phase against the step (the same log time axis in each),
// the cutting steps shaded, each phase's p50 / p99 (over the samples summary.json uses) and the frame
// (33 ms) and haptic (1 ms) budgets as lines. Sent to the gnuplot child started with the replay,
// which draws them while the other outputs are written (PlotProcess::finish waits for it).
void send_timings_plot(const std::string& recording, const std::vector<StepReport>& rows,
                       const std::vector<FrameRow>& frames, bool physics, const std::filesystem::path& out,
                       PlotProcess& plotter) {
  Plot plot;
  plot.title = "divvox replay: time per step, " + std::filesystem::path(recording).filename().string();
  plot.subtitle = std::to_string(rows.size()) + " steps, physics " + (physics ? "on" : "off") + "; " + machine_summary();
  plot.x_label = "step";
  plot.span_name = "steps that cut voxels";
  plot.same_y = true;
  plot.png_scale = 1.0;  // the replay waits for it (plot.h)
  // A panel: the values against x (NaN: not a sample), their p50 / p99 and the two budgets.
  const auto panel = [&](const char* name, const char* colour, const char* over, const std::vector<double>& x,
                         const std::vector<double>& y) {
    PlotSeries s;
    s.name = name;
    s.colour = colour;
    s.markers = false;
    s.x = x;
    s.y = y;
    std::vector<double> sample;
    for (double v : y) {
      if (!std::isnan(v)) sample.push_back(v);
    }
    PlotPanel p{std::string(name) + " ms", true, {s}, {}};
    const nlohmann::json stats = percentiles_json(sample);
    for (const char* q : {"p50", "p99"}) {
      char label[96];
      std::snprintf(label, sizeof label, "%s %.3g ms (%s)", q, stats[q].get<double>(), over);
      const bool p50 = q[1] == '5';  // dotted, its label under the line; p99 dashed, above
      p.lines.push_back({stats[q].get<double>(), label, colour, p50 ? 3 : 2, false, p50});
    }
    p.lines.push_back({33.0, "frame budget 33 ms", "#b03030", 1, true, false});
    p.lines.push_back({1.0, "haptic budget 1 ms", "#b03030", 1, true, false});
    plot.panels.push_back(p);
  };
  std::vector<double> steps, cut, surface, deform, total;
  for (const StepReport& r : rows) {
    const bool cut_edges = r.cut.edges_hit > 0;  // the steps summary.json's cut and surface figures cover
    steps.push_back(r.step);
    cut.push_back(cut_edges ? r.timings.cut_ms : NAN);
    surface.push_back(cut_edges ? r.timings.surface_ms : NAN);
    deform.push_back(r.timings.deform_ms);
    total.push_back(r.timings.total_ms);
  }
  panel("cut", "#1f77b4", "sweeps crossing edges", steps, cut);
  panel("surface", "#ff7f0e", "sweeps crossing edges", steps, surface);
  if (physics) panel("deform", "#2ca02c", "every step", steps, deform);
  panel("total", "#333333", "every step", steps, total);
  if (!frames.empty()) {
    // The render thread's frames, at the step each one drew.
    std::vector<double> frame_steps, render;
    for (const FrameRow& f : frames) {
      frame_steps.push_back(f.step);
      render.push_back(f.upload_ms + f.draw_ms + f.readback_ms);
    }
    panel("render", "#9467bd", "every frame", frame_steps, render);
  }
  // The steps that cut voxels, as shaded runs.
  for (size_t i = 0; i < rows.size(); ++i) {
    if (rows[i].cut.voxels_cut == 0) continue;
    size_t j = i;
    while (j + 1 < rows.size() && rows[j + 1].cut.voxels_cut > 0) ++j;
    plot.spans.push_back({double(rows[i].step) - 0.5, double(rows[j].step) + 0.5});
    i = j;
  }
  plotter.send(plot, {(out / "timings.svg").string(), (out / "timings.png").string()});
}

// Per-frame samples of the render thread: upload + draw + readback, and the interval between frames.
struct FrameSamples {
  std::vector<double> render, interval;
  size_t rendered = 0;
};

// frame_timings.csv (when frames were rendered) and the frame samples.
FrameSamples write_frame_timings(const std::vector<FrameRow>& frames, const std::filesystem::path& out) {
  FrameSamples samples;
  samples.rendered = frames.size();
  if (frames.empty()) return samples;
  std::ostringstream f;
  f << "frame,step,upload_ms,draw_ms,readback_ms,frame_interval_ms,written\n";
  for (const FrameRow& r : frames) {
    f << r.frame << ',' << r.step << ',' << r.upload_ms << ',' << r.draw_ms << ',' << r.readback_ms << ','
      << r.interval_ms << ',' << (r.written ? 1 : 0) << '\n';
    samples.render.push_back(r.upload_ms + r.draw_ms + r.readback_ms);
    if (r.frame > 0) samples.interval.push_back(r.interval_ms);
  }
  write_text_file((out / "frame_timings.csv").string(), f.str());
  return samples;
}

// The final surface's checks on the rest-space surface, and the count of non-finite values in it and
// in the particles (final.ply itself is written from the cut surface, as the --meshes files are).
struct FinalSurface {
  SurfaceStats stats;
  uint64_t nonfinite = 0;
};
FinalSurface final_surface(const Session& session) {
  FinalSurface f;
  const SurfaceMesh rest = compact_surface(session.state.cut.surface);
  f.stats = surface_stats(rest);
  for (const Vec3f& p : rest.positions) f.nonfinite += p.allFinite() ? 0 : 1;
  if (const PbdState* pbd = session.state.pbd ? &*session.state.pbd : nullptr) f.nonfinite += count_nonfinite(*pbd);
  return f;
}

// The task pool's counters since the session opened (README "summary.json": "pool").
nlohmann::json pool_json(const TaskPoolStats& stats) {
  nlohmann::json threads = nlohmann::json::array();
  for (const TaskPoolThreadStats& t : stats.threads) {
    threads.push_back({{"jobs", t.jobs}, {"chunks", t.chunks}, {"stolen", t.stolen}, {"waits", t.waits},
                       {"long_waits", t.long_waits}, {"wait_ms", t.wait_ms}, {"cpu_s", t.cpu_s}});
  }
  return {{"workers", stats.threads.size()}, {"jobs", stats.jobs}, {"wakeups", stats.wakeups}, {"stages", stats.stages},
          {"late_workers", stats.late_workers}, {"threads", threads}};
}

// summary.json (DESIGN §1 contract: the fields that apply without physics).
nlohmann::json summary_json(const ReplayOptions& options, const Playback& playback, const Session& session,
                            const ReplayResult& result, const ReplayRun& run, const PhaseSamples& phases,
                            const FrameSamples& frames, const FinalSurface& final) {
  const CutState& state = session.state.cut;
  const PbdState* pbd = session.state.pbd ? &*session.state.pbd : nullptr;
  nlohmann::json summary = {
      {"recording", options.recording},
      {"scene", scene_to_json(playback.scene)},
      {"physics", bool(pbd)},
      {"workers", pbd ? session.pool->workers() : 1},
      {"steps", result.steps},
      {"dt", playback.dt},
      {"final_hash", result.final_hash},
      {"hash_checks",
       {{"checked", result.hash_checked},
        {"mismatched", result.hash_mismatched},
        {"first_mismatch_step", result.first_mismatch_step}}},
      {"timing_ms",
       {{"cut", percentiles_json(phases.cut)},
        {"surface", percentiles_json(phases.surface)},
        {"deform", percentiles_json(phases.deform)},
        {"total", percentiles_json(phases.total)},
        {"step", percentiles_json(phases.step)},
        {"render", percentiles_json(frames.render)},
        {"frame_interval", percentiles_json(frames.interval)}}},
      {"frames", {{"rendered", frames.rendered}, {"written", result.frames_written}, {"size", {options.width, options.height}}}},
      {"interrupted", result.interrupted},
      {"wall_s", run.wall_s},
      {"timing_note", "cut, surface, total: over steps whose blade sweep crossed lattice edges; deform and step: every step"},
      {"init_ms", session.init_ms},
      {"lattice", {session.world.voxels.lattice.nx, session.world.voxels.lattice.ny, session.world.voxels.lattice.nz}},
      {"cut",
       {{"voxels_cut", run.voxels_cut},
        {"voxels_divided", state.divided.size()},
        {"edges_cut", state.edge_cuts.size()},
        {"sim_voxels_divided", pbd ? sim_voxels_divided(*pbd) : 0},
        {"explicit_bytes", cut_memory_bytes(state)}}},
      {"surface", surface_stats_json(final.stats)},
      {"nonfinite_values", final.nonfinite},
  };
  summary["surface"]["initial_volume"] = run.initial_volume;
  // The pieces: components of the final surface, the smallest one's volume, and what each cutting
  // stroke created (docs/cutting.md).
  {
    const std::vector<double> volumes = component_volumes(compact_surface(state.surface));
    summary["pieces"] = {{"components", volumes.size()},
                         {"smallest_volume", volumes.empty() ? 0.0 : *std::min_element(volumes.begin(), volumes.end())}};
    nlohmann::json strokes = nlohmann::json::array();
    for (const ReplayRun::Stroke& s : run.strokes) {
      strokes.push_back({{"first_step", s.first_step}, {"last_step", s.last_step}, {"components", s.components},
                         {"created", s.created}, {"smallest_volume", s.smallest_volume}});
    }
    summary["strokes"] = strokes;
  }
  if (pbd) {
    summary["mass"] = {{"initial", session.initial_mass}, {"final", total_mass(*pbd)}};
    summary["kinetic_energy"] = kinetic_energy(*pbd);
    summary["particles"] = pbd->position.size() - pbd->free_particles.size();
    summary["shape_constraints"] = live_pieces(*pbd);
    summary["stretch_constraints"] = stretch_count(*pbd);
    summary["pool"] = pool_json(session.pool->stats());
  }
  return summary;
}

}  // namespace

ReplayResult run_replay(const ReplayOptions& options) {
  const Playback playback = load_playback(options.recording);
  for (const std::string& warning : playback.warnings) std::fprintf(stderr, "divvox: warning: %s\n", warning.c_str());

  // The simulation of the recording's scene; the recorder of the replayed session.
  Session session;
  open_session(playback.scene, playback.dt, options.physics, options.workers, session, options.progress);
  // Without frames the surface is read only by the --meshes files and the final outputs: embedded
  // there, not every step.
  session.embed_surface = options.render || options.frames_every > 0;
  ReplayRun run;
  run.initial_volume = surface_stats(compact_surface(session.state.cut.surface)).volume;
  run.components = uint32_t(component_volumes(compact_surface(session.state.cut.surface)).size());
  make_output_dir(options.out_dir);
  if (options.meshes_every > 0) make_output_dir((std::filesystem::path(options.out_dir) / "meshes").string());
  std::unique_ptr<SessionRecorder> recorder;
  if (!options.record_path.empty()) {
    recorder = std::make_unique<SessionRecorder>(options.record_path, playback.scene, playback.dt, options.physics,
                                                 options.hash_every);
  }
  std::string warning;
  const bool check_hashes = hashes_apply(playback, options.physics, warning);
  if (!check_hashes) std::fprintf(stderr, "divvox: warning: %s\n", warning.c_str());

  // The step loop: here, or on a thread while this one renders.
  std::vector<FrameRow> frames;
  const auto simulate_on = [&](SnapshotExchange* exchange) {
    simulate(playback, options, check_hashes, session, recorder.get(), exchange, run);
  };
  // The gnuplot child for timings.svg / .png gets ready while the steps run (without gnuplot: a
  // message at the end, and the replay goes on).
  PlotProcess plotter;
  std::string plot_error;
  plotter.start(plot_error);
  const Clock::time_point start = Clock::now();
  std::signal(SIGINT, on_sigint);
  if (options.render || options.frames_every > 0) {
    simulate_and_render(simulate_on, options, session, frames);
  } else {
    simulate_on(nullptr);
  }
  std::signal(SIGINT, SIG_DFL);
  if (options.progress) std::fprintf(stderr, "\n");
  // An interrupted replay still ends with the mesh of its last step.
  if (options.meshes_every > 0 && run.steps_done > 0 && run.last_mesh != int64_t(run.steps_done) - 1) {
    write_step_mesh(options, session, run.steps_done - 1, run);
  }

  session_embed(session);  // the final surface and summary read it
  ReplayResult result;
  result.steps = run.steps_done;
  result.interrupted = run.interrupted;
  result.hash_checked = run.checks.checked;
  result.hash_mismatched = run.checks.mismatched;
  result.first_mismatch_step = run.checks.first_mismatch_step;
  for (const FrameRow& f : frames) result.frames_written += f.written ? 1 : 0;
  result.final_hash = hash_hex(session_hash(session));
  if (recorder) recorder->finish(session);

  // The outputs: the plot first (gnuplot draws it meanwhile), timings, frame timings, final surface,
  // then the plot waited for, and the summary.
  const std::filesystem::path out(options.out_dir);
  send_timings_plot(options.recording, run.rows, frames, session.state.pbd.has_value(), out, plotter);
  const FinalSurface final = final_surface(session);
  const PhaseSamples phases = write_timings_csv(run.rows, session.state.pbd.has_value(), out);
  const FrameSamples frame_samples = write_frame_timings(frames, out);
  // The same binary PLY as the --meshes files (world space, cut faces marked).
  write_cut_mesh_ply((out / "final.ply").string(), session.state.cut.surface, session.state.pbd ? &session.state.pbd->deformed : nullptr);
  if (!plotter.finish(plot_error)) std::fprintf(stderr, "divvox: timings.svg skipped: %s\n", plot_error.c_str());
  run.wall_s = std::chrono::duration<double>(Clock::now() - start).count();  // the steps and the outputs
  result.summary_path = (out / "summary.json").string();
  write_json_file(result.summary_path, summary_json(options, playback, session, result, run, phases, frame_samples, final));
  return result;
}

}  // namespace dvx
