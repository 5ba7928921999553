#include "harness/replay_outputs.h"

#include "engine/output.h"
#include "engine/stats.h"
#include "engine/timing.h"
#include "harness/plot.h"
#include "sim/cut.h"
#include "sim/pbd.h"
#include "sim/surface_metrics.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <sstream>

namespace dvx {
namespace {

// Per-step samples of each phase for summary.json: cut, surface and total over the steps whose blade
// sweep crossed lattice edges; deform (with the physics) and step over every step.
struct PhaseSamples {
  std::vector<double> cut, surface, total, deform, step;
};

// timings.csv (one row per step) and the phase samples.
PhaseSamples write_timings_csv(const std::vector<StepReport>& rows, bool physics, const std::filesystem::path& out) {
  std::ostringstream csv;
  csv << "step,cut_ms,surface_ms,deform_ms,total_ms,cut_voxels,edges_hit,edges_cut,voxels_divided,"
         "vertices_changed,triangles_changed,cutting,sim_voxels_cut,grab_force_n\n";
  PhaseSamples samples;
  for (const StepReport& r : rows) {
    if (physics) samples.deform.push_back(r.timings.deform_ms);
    samples.step.push_back(r.timings.total_ms);
    csv << r.step << ',' << r.timings.cut_ms << ',' << r.timings.surface_ms << ',' << r.timings.deform_ms << ','
        << r.timings.total_ms << ',' << r.cut.voxels_cut << ',' << r.cut.edges_hit << ',' << r.cut.edges_cut << ','
        << r.cut.voxels_divided << ',' << r.cut.vertices_changed << ',' << r.cut.triangles_changed << ','
        << (r.cutting ? 1 : 0) << ',' << r.sim_voxels_cut << ',' << r.grab_force_n << '\n';
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
  if (const PbdState* pbd = session.state.pbd ? &*session.state.pbd : nullptr)
    f.nonfinite += count_nonfinite(pbd->model, pbd->data);
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

// The simulation's pace in each simulated second of the run: the steps of each second (round(1 / dt)
// steps; a last, shorter one left out unless it is the only one) over the compute time of their steps,
// as x real time: min, p1, p50 and how many seconds (null without steps).
nlohmann::json pace_per_second_json(const std::vector<double>& step_ms, double dt) {
  const size_t per_second = size_t(std::max(1.0, std::round(1.0 / dt)));
  std::vector<double> pace;
  for (size_t begin = 0; begin < step_ms.size(); begin += per_second) {
    const size_t end = std::min(step_ms.size(), begin + per_second);
    if (end - begin < per_second && !pace.empty()) break;
    double ms = 0.0;
    for (size_t i = begin; i < end; ++i) ms += step_ms[i];
    pace.push_back(ms > 0.0 ? double(end - begin) * dt / (ms / 1000.0) : 0.0);
  }
  if (pace.empty()) return nullptr;
  return {{"min", *std::min_element(pace.begin(), pace.end())},
          {"p1", quantile(pace, 0.01)},
          {"p50", quantile(pace, 0.5)},
          {"seconds", pace.size()}};
}

// summary.json (DESIGN §1 contract: the fields that apply without physics).
nlohmann::json summary_json(const ReplayOptions& options, const Replay& replay, const ReplayResult& result, double wall_s,
                            const PhaseSamples& phases, const FrameSamples& frames, const FinalSurface& final) {
  const Playback& playback = replay.playback;
  const Session& session = replay.session;
  const CutState& state = session.state.cut;
  const PbdState* pbd = session.state.pbd ? &*session.state.pbd : nullptr;
  nlohmann::json summary = {
      {"recording", options.recording},
      {"scene", scene_to_json(playback.scene)},
      {"physics", bool(pbd)},
      {"workers", session.pool->workers()},
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
      {"pace_per_second", pace_per_second_json(phases.step, playback.dt)},
      {"frames", {{"rendered", frames.rendered}, {"written", result.frames_written}, {"size", {options.width, options.height}}}},
      {"interrupted", result.interrupted},
      {"wall_s", wall_s},
      {"timing_note", "cut, surface, total: over steps whose blade sweep crossed lattice edges; deform and step: every step"},
      {"init_ms", session.init_ms},
      {"lattice", {session.world.voxels.lattice.nx, session.world.voxels.lattice.ny, session.world.voxels.lattice.nz}},
      {"cut",
       {{"voxels_cut", replay.voxels_cut},
        {"voxels_divided", state.divided.size()},
        {"edges_cut", state.edge_cuts.size()},
        {"sim_voxels_divided", pbd ? sim_voxels_divided(pbd->model) : 0},
        {"explicit_bytes", cut_memory_bytes(state)}}},
      {"surface", surface_stats_json(final.stats)},
      {"nonfinite_values", final.nonfinite},
  };
  summary["surface"]["initial_volume"] = replay.initial_volume;
  // The pieces: components of the final surface, the smallest one's volume, and what each cutting
  // stroke created (docs/cutting.md).
  {
    const std::vector<double> volumes = component_volumes(compact_surface(state.surface));
    summary["pieces"] = {{"components", volumes.size()},
                         {"smallest_volume", volumes.empty() ? 0.0 : *std::min_element(volumes.begin(), volumes.end())}};
    nlohmann::json strokes = nlohmann::json::array();
    for (const Replay::Stroke& s : replay.strokes) {
      strokes.push_back({{"first_step", s.first_step}, {"last_step", s.last_step}, {"components", s.components},
                         {"created", s.created}, {"smallest_volume", s.smallest_volume}});
    }
    summary["strokes"] = strokes;
  }
  if (pbd) {
    summary["mass"] = {{"initial", session.initial_mass}, {"final", total_mass(pbd->model)}};
    summary["kinetic_energy"] = kinetic_energy(pbd->model, pbd->data);
    summary["particles"] = pbd->data.position.size() - pbd->model.free_particles.size();
    summary["shape_constraints"] = live_pieces(pbd->model);
    summary["stretch_constraints"] = stretch_count(pbd->model);
    summary["pool"] = pool_json(session.pool->stats());
  }
  return summary;
}

}  // namespace

ReplayResult run_replay(const ReplayOptions& options) {
  // The recording's session, its output folders and recorder.
  Replay replay;
  open_replay(options, replay);
  // The gnuplot child for timings.svg / .png gets ready while the steps run (without gnuplot: a
  // message at the end, and the replay goes on).
  PlotProcess plotter;
  std::string plot_error;
  plotter.start(plot_error);
  const Clock::time_point start = Clock::now();
  run_replay_steps(options, replay);

  ReplayResult result;
  result.steps = replay.steps_done;
  result.interrupted = replay.interrupted;
  result.hash_checked = replay.checks.checked;
  result.hash_mismatched = replay.checks.mismatched;
  result.first_mismatch_step = replay.checks.first_mismatch_step;
  for (const FrameRow& f : replay.frames) result.frames_written += f.written ? 1 : 0;
  result.final_hash = replay.final_hash;

  // The outputs: the plot first (gnuplot draws it meanwhile), timings, frame timings, final surface,
  // then the plot waited for, and the summary.
  const Session& session = replay.session;
  const std::filesystem::path out(options.out_dir);
  send_timings_plot(options.recording, replay.rows, replay.frames, session.state.pbd.has_value(), out, plotter);
  const FinalSurface final = final_surface(session);
  const PhaseSamples phases = write_timings_csv(replay.rows, session.state.pbd.has_value(), out);
  const FrameSamples frame_samples = write_frame_timings(replay.frames, out);
  // The same binary PLY as the --meshes files (world space, cut faces marked).
  write_cut_mesh_ply((out / "final.ply").string(), session.state.cut.surface,
                     session.state.pbd ? &session.state.pbd->data.deformed : nullptr);
  if (!plotter.finish(plot_error)) std::fprintf(stderr, "divvox: timings.svg skipped: %s\n", plot_error.c_str());
  const double wall_s = std::chrono::duration<double>(Clock::now() - start).count();  // the steps and the outputs
  result.summary_path = (out / "summary.json").string();
  write_json_file(result.summary_path, summary_json(options, replay, result, wall_s, phases, frame_samples, final));
  return result;
}

}  // namespace dvx
