#include "engine/replay.h"

#include "engine/errors.h"
#include "engine/output.h"
#include "engine/recording.h"
#include "engine/session.h"
#include "engine/snapshot.h"
#include "engine/plot.h"
#ifdef DIVVOX_HAS_RENDER
#include "engine/headless_render.h"
#endif
#include "sim/cut.h"
#include "sim/pbd.h"
#include "sim/state_hash.h"
#include "sim/surface_metrics.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <atomic>
#include <csignal>
#include <memory>
#include <sstream>
#include <thread>

namespace dvx {
namespace {

// SIGINT stops a replay cleanly: the step loop ends, outputs cover the steps done.
std::atomic<bool> g_interrupted{false};
void on_sigint(int) { g_interrupted.store(true); }



// {"mean","p50","p95","p99","max"} of a sample (empty: zeros).
nlohmann::json percentiles(std::vector<double> values) {
  if (values.empty()) return {{"mean", 0.0}, {"p50", 0.0}, {"p95", 0.0}, {"p99", 0.0}, {"max", 0.0}, {"count", 0}};
  std::sort(values.begin(), values.end());
  double sum = 0.0;
  for (double v : values) sum += v;
  const auto at = [&](double q) {
    const size_t i = size_t(std::ceil(q * double(values.size()))) - 1;
    return values[std::min(i, values.size() - 1)];
  };
  return {{"mean", sum / double(values.size())},
          {"p50", at(0.50)},
          {"p95", at(0.95)},
          {"p99", at(0.99)},
          {"max", values.back()},
          {"count", values.size()}};
}


// timings.svg and timings.png: one panel per phase against the step (the same log time axis in each),
// the cutting steps shaded, each phase's p50 / p99 (over the samples summary.json uses) and the frame
// (33 ms) and haptic (1 ms) budgets as lines. Without gnuplot: a message, and the replay goes on.
void write_timings_plot(const std::string& recording, const std::vector<StepReport>& rows,
                        const std::vector<FrameRow>& frames, bool physics, const std::filesystem::path& out) {
  Plot plot;
  plot.title = "divvox replay: time per step, " + std::filesystem::path(recording).filename().string();
  plot.subtitle = std::to_string(rows.size()) + " steps, physics " + (physics ? "on" : "off") + "; " + machine_summary();
  plot.x_label = "step";
  plot.span_name = "steps that cut voxels";
  plot.same_y = true;
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
    const nlohmann::json stats = percentiles(sample);
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
  std::string error;
  if (!draw_plot(plot, {(out / "timings.svg").string(), (out / "timings.png").string()}, error)) {
    std::fprintf(stderr, "divvox: timings.svg skipped: %s\n", error.c_str());
  }
}
}  // namespace

ReplayResult run_replay(const ReplayOptions& options) {
  const Recording recording = read_recording(options.recording);
  for (const std::string& warning : recording.warnings) std::fprintf(stderr, "divvox: warning: %s\n", warning.c_str());

  // The simulation of the recording's scene.
  const Scene& scene = recording.scene;
  Session session;
  open_session(scene, recording.dt, options.physics, options.workers, session, options.progress);
  const SurfaceStats initial = surface_stats(compact_surface(session.cut.surface));

  make_output_dir(options.out_dir);
  std::unique_ptr<RecordingWriter> writer;
  if (!options.record_path.empty()) {
    writer = std::make_unique<RecordingWriter>(options.record_path, scene, recording.dt, options.physics ? 1 : 0);
  }
  // Hashes taken in the other mode cannot match: say so instead of reporting a divergence.
  const bool check_hashes = recording.physics < 0 || recording.physics == (options.physics ? 1 : 0);
  if (!check_hashes) {
    std::fprintf(stderr, "divvox: warning: %s: its state hashes were taken with the physics %s; not checked\n",
                 options.recording.c_str(), recording.physics ? "on" : "off");
  }

  // Step through the recording: a line sets the pose (kept until the next line); the sweep from the
  // previous step's pose to this step's cuts when this step is cutting.
  ReplayResult result;
  std::vector<StepReport> rows;
  uint64_t totals_voxels_cut = 0;
  size_t line = 0;
  const uint32_t last = recording.last_step();
  uint32_t steps_done = 0;
  DirtyHistory dirty_history;
  Snapshot camera;  // only its camera fields: the recording's camera so far
  const Clock::time_point start = Clock::now();
  // Per-step meshes: the deformed surface in world space with its cut faces marked.
  const std::string meshes_dir = (std::filesystem::path(options.out_dir) / "meshes").string();
  if (options.meshes_every > 0) make_output_dir(meshes_dir);
  int64_t last_mesh = -1;
  const auto write_step_mesh = [&](uint32_t step) {
    char name[32];
    std::snprintf(name, sizeof(name), "mesh_%05u.ply", step);
    write_cut_mesh_ply((std::filesystem::path(meshes_dir) / name).string(), session.cut.surface,
                       session.pbd ? &session.pbd->deformed : nullptr);
    last_mesh = step;
  };
  // The simulation loop (on its own thread when a render thread draws its snapshots).
  const auto simulate = [&](SnapshotExchange* exchange) {
  for (uint32_t step = 0; step <= last && !recording.steps.empty(); ++step) {
    if (g_interrupted.load()) {
      result.interrupted = true;
      break;
    }
    // --speed realtime: a step every dt of wall-clock time.
    if (options.realtime) std::this_thread::sleep_until(start + std::chrono::duration<double>(recording.dt * step));
    // The recording's lines for this step become the step's commands.
    StepCommands commands;
    std::string recorded_hash;
    for (; line < recording.steps.size() && recording.steps[line].step == step; ++line) {
      const RecordedStep& r = recording.steps[line];
      if (r.has_blade) {
        commands.has_blade = true;
        commands.blade = r.blade;
        commands.cutting = r.cutting;
      }
      if (r.has_hash && check_hashes) recorded_hash = r.hash;
      if (r.extra.is_object() && r.extra.contains("camera")) {
        // {"target": [x,y,z], "distance": d, "yaw": radians, "pitch": radians}: the frames' camera from here on.
        const nlohmann::json& c = r.extra["camera"];
        const auto number = [&](const char* key) {
          if (!c.is_object() || !c.contains(key) || !c[key].is_number() || !std::isfinite(c[key].get<double>())) {
            throw_input(options.recording, "line " + std::to_string(r.line) +
                                               ": camera must be {\"target\": [x,y,z], \"distance\": d, \"yaw\": a, "
                                               "\"pitch\": b}");
          }
          return float(c[key].get<double>());
        };
        if (!c.is_object() || !c.contains("target") || !c["target"].is_array() || c["target"].size() != 3) number("target");
        for (int a = 0; a < 3; ++a) {
          if (!c["target"][a].is_number()) number("target");
          camera.camera_target[a] = float(c["target"][a].get<double>());
        }
        camera.camera_distance = number("distance");
        camera.camera_yaw = number("yaw");
        camera.camera_pitch = number("pitch");
        camera.has_camera = camera.camera_target.allFinite() && camera.camera_distance > 0.0f;
      }
      if (r.extra.is_object() && r.extra.contains("grab")) {
        commands.grab = parse_grab(r.extra["grab"], options.recording, r.line);
        if (writer) writer->write_line({{"step", step}, {"grab", r.extra["grab"]}});
      }
    }
    const StepReport row = session_step(session, commands);
    totals_voxels_cut += row.cut.voxels_cut;
    rows.push_back(row);
    if (writer && session.have_blade) writer->write_blade(step, session.blade, session.cutting);

    // Determinism: compare with the recorded hash, write ours.
    const bool want_hash = !recorded_hash.empty() || (writer && options.hash_every > 0 && step % options.hash_every == 0);
    if (want_hash) {
      const std::string hash = hash_hex(session_hash(session));
      if (!recorded_hash.empty()) {
        ++result.hash_checked;
        if (hash != recorded_hash) {
          ++result.hash_mismatched;
          if (result.first_mismatch_step < 0) result.first_mismatch_step = step;
        }
      }
      if (writer && options.hash_every > 0 && step % options.hash_every == 0) writer->write_hash(step, hash);
    }
    // Hand the surface to the render thread (capture frames every frames_every steps).
    if (exchange != nullptr) {
      const bool capture = options.frames_every > 0 && step % options.frames_every == 0;
      exchange->publish(
          [&](Snapshot& slot, uint64_t slot_sequence) {
            fill_snapshot(slot, slot_sequence, session.cut.surface, session.pbd ? &session.pbd->deformed : nullptr,
                          dirty_history, step, row.timings);
            slot.has_camera = camera.has_camera;
            slot.camera_target = camera.camera_target;
            slot.camera_distance = camera.camera_distance;
            slot.camera_yaw = camera.camera_yaw;
            slot.camera_pitch = camera.camera_pitch;
          },
          capture);
      session.cut.surface.clear_dirty();
    }
    steps_done = step + 1;
    if (options.meshes_every > 0 && (step % options.meshes_every == 0 || step == last)) write_step_mesh(step);
    if (options.progress && step % 200 == 0) std::fprintf(stderr, "\rdivvox: replay step %u / %u", step, last);
  }
  };

  // Threads: simulation here, or simulation on a thread and rendering here (EGL contexts belong to
  // the thread that made them).
  std::vector<FrameRow> frames;
  const bool render = options.render || options.frames_every > 0;
  const std::string frames_dir = options.frames_every > 0 ? (std::filesystem::path(options.out_dir) / "frames").string() : "";
  std::signal(SIGINT, on_sigint);
  if (render) {
#ifdef DIVVOX_HAS_RENDER
    std::string render_error;
    if (!probe_headless_render(render_error)) throw_input(options.recording, "headless rendering: " + render_error);
    if (!frames_dir.empty()) make_output_dir(frames_dir);
    HeadlessRenderOptions ro;
    ro.width = options.width;
    ro.height = options.height;
    ro.frames_dir = frames_dir;
    ro.wireframe = options.wireframe;
    ro.framing = mesh_bounds(session.input.mesh);
    SnapshotExchange exchange;
    std::thread sim_thread([&] {
      simulate(&exchange);
      exchange.finish();
    });
    const bool rendered = run_headless_render(exchange, ro, frames, render_error);
    sim_thread.join();
    if (!rendered) throw_input(options.recording, "headless rendering: " + render_error);
    for (const FrameRow& f : frames) result.frames_written += f.written ? 1 : 0;
#else
    throw_input(options.recording, "this build has no renderer (configured with -DDIVVOX_GRAPHICS=OFF); drop --frames");
#endif
  } else {
    simulate(nullptr);
  }
  std::signal(SIGINT, SIG_DFL);

  if (options.progress) std::fprintf(stderr, "\n");
  if (options.meshes_every > 0 && steps_done > 0 && last_mesh != int64_t(steps_done) - 1) write_step_mesh(steps_done - 1);
  result.steps = steps_done;
  result.final_hash = hash_hex(session_hash(session));
  const CutState& state = session.cut;
  const PbdState* pbd = session.pbd.get();
  if (writer && steps_done > 0 && (options.hash_every == 0 || (steps_done - 1) % options.hash_every != 0)) {
    writer->write_hash(steps_done - 1, result.final_hash);
  }

  // Final surface and its checks.
  // (The topology checks run on the rest-space surface; final.ply is the deformed one.)
  const SurfaceMesh final_surface = compact_surface(state.surface);
  const SurfaceStats stats = surface_stats(final_surface);
  uint64_t nonfinite = 0;
  for (const Vec3f& p : final_surface.positions) nonfinite += p.allFinite() ? 0 : 1;
  SurfaceMesh deformed_surface = final_surface;
  if (pbd) {
    nonfinite += count_nonfinite(*pbd);
    CutSurface deformed = state.surface;
    for (size_t slot = 0; slot < deformed.positions.size() && slot < pbd->deformed.size(); ++slot) {
      if (deformed.vertex_piece[slot] != CutSurface::kFreeKey) deformed.positions[slot] = pbd->deformed[slot];
    }
    deformed_surface = compact_surface(deformed);
  }

  // timings.csv
  std::ostringstream csv;
  csv << "step,cut_ms,surface_ms,deform_ms,total_ms,cut_voxels,edges_hit,edges_cut,voxels_divided,"
         "vertices_changed,triangles_changed,cutting,sim_voxels_cut\n";
  std::vector<double> cut_ms, surface_ms, total_ms, deform_ms, step_ms;
  for (const StepReport& r : rows) {
    if (pbd) deform_ms.push_back(r.timings.deform_ms);
    step_ms.push_back(r.timings.total_ms);
    csv << r.step << ',' << r.timings.cut_ms << ',' << r.timings.surface_ms << ',' << r.timings.deform_ms << ','
        << r.timings.total_ms << ',' << r.cut.voxels_cut << ','
        << r.cut.edges_hit << ',' << r.cut.edges_cut << ',' << r.cut.voxels_divided << ','
        << r.cut.vertices_changed << ',' << r.cut.triangles_changed << ',' << (r.cutting ? 1 : 0) << ','
        << r.sim_voxels_cut << '\n';
    if (r.cut.edges_hit > 0) {
      cut_ms.push_back(r.timings.cut_ms);
      surface_ms.push_back(r.timings.surface_ms);
      total_ms.push_back(r.timings.total_ms);
    }
  }
  const std::filesystem::path out(options.out_dir);
  write_text_file((out / "timings.csv").string(), csv.str());
  // Per-frame timings of the render thread.
  std::vector<double> render_ms, interval_ms;
  if (!frames.empty()) {
    std::ostringstream f;
    f << "frame,step,upload_ms,draw_ms,readback_ms,frame_interval_ms,written\n";
    for (const FrameRow& r : frames) {
      f << r.frame << ',' << r.step << ',' << r.upload_ms << ',' << r.draw_ms << ',' << r.readback_ms << ','
        << r.interval_ms << ',' << (r.written ? 1 : 0) << '\n';
      render_ms.push_back(r.upload_ms + r.draw_ms + r.readback_ms);
      if (r.frame > 0) interval_ms.push_back(r.interval_ms);
    }
    write_text_file((out / "frame_timings.csv").string(), f.str());
  }
  write_timings_plot(options.recording, rows, frames, pbd != nullptr, out);
  save_ply((out / "final.ply").string(), deformed_surface);

  // summary.json (DESIGN §1 contract: the fields that apply without physics).
  nlohmann::json summary = {
      {"recording", options.recording},
      {"scene", scene_to_json(scene)},
      {"physics", bool(pbd)},
      {"workers", pbd ? session.pool->workers() : 1},
      {"steps", result.steps},
      {"dt", recording.dt},
      {"final_hash", result.final_hash},
      {"hash_checks",
       {{"checked", result.hash_checked},
        {"mismatched", result.hash_mismatched},
        {"first_mismatch_step", result.first_mismatch_step}}},
      {"timing_ms",
       {{"cut", percentiles(cut_ms)},
        {"surface", percentiles(surface_ms)},
        {"deform", percentiles(deform_ms)},
        {"total", percentiles(total_ms)},
        {"step", percentiles(step_ms)},
        {"render", percentiles(render_ms)},
        {"frame_interval", percentiles(interval_ms)}}},
      {"frames", {{"rendered", frames.size()}, {"written", result.frames_written}, {"size", {options.width, options.height}}}},
      {"interrupted", result.interrupted},
      {"wall_s", std::chrono::duration<double>(Clock::now() - start).count()},
      {"timing_note", "cut, surface, total: over steps whose blade sweep crossed lattice edges; deform and step: every step"},
      {"init_ms", session.init_ms},
      {"lattice", {session.model.lattice.nx, session.model.lattice.ny, session.model.lattice.nz}},
      {"cut",
       {{"voxels_cut", totals_voxels_cut},
        {"voxels_divided", state.divided.size()},
        {"edges_cut", state.edge_cuts.size()},
        {"sim_voxels_divided", pbd ? sim_voxels_divided(*pbd) : 0},
        {"explicit_bytes", cut_memory_bytes(state)}}},
      {"surface",
       {{"vertices", stats.vertices},
        {"triangles", stats.triangles},
        {"boundary_edges", stats.boundary_edges},
        {"nonmanifold_edges", stats.nonmanifold_edges},
        {"misoriented_edges", stats.misoriented_edges},
        {"components", stats.components},
        {"volume", stats.volume},
        {"initial_volume", initial.volume}}},
      {"nonfinite_values", nonfinite},
  };
  if (pbd) {
    summary["mass"] = {{"initial", session.initial_mass}, {"final", total_mass(*pbd)}};
    summary["kinetic_energy"] = kinetic_energy(*pbd);
    summary["particles"] = pbd->position.size() - pbd->free_particles.size();
    summary["shape_constraints"] = live_pieces(*pbd);
    summary["stretch_constraints"] = stretch_count(*pbd);
  }
  result.summary_path = (out / "summary.json").string();
  write_json_file(result.summary_path, summary);
  return result;
}

}  // namespace dvx
