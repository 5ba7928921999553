#include "bench/bench_contact.h"

#include "bench/bench_common.h"

#include "engine/errors.h"
#include "engine/output.h"
#include "engine/playback.h"
#include "engine/session.h"
#include "engine/stats.h"
#include "harness/plot.h"
#include "sim/union_find.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <sstream>

namespace dvx {
namespace {

namespace fs = std::filesystem;

// One run of a case: per-step deform and total times, and the contacts solved.
struct ContactRun {
  std::vector<double> deform_ms, step_ms;
  double plane_contacts = 0, piece_contacts = 0;  // summed over the steps
  PieceContacts::Counters counters;
};

// The scene without contact: no planes, no piece contact.
Scene without_contact(Scene scene) {
  scene.pbd.planes.clear();
  scene.pbd.piece_contact = false;
  return scene;
}

// Steps a session with `commands(step)` for `steps` steps, timing each.
template <typename Commands>
ContactRun run_case(const Scene& scene, double dt, int workers, uint32_t steps, Commands&& commands) {
  Session session;
  open_session(scene, dt, true, workers, session);
  ContactRun run;
  for (uint32_t step = 0; step < steps; ++step) {
    const StepReport report = session_step(session, commands(session, step));
    run.deform_ms.push_back(report.timings.deform_ms);
    run.step_ms.push_back(report.timings.total_ms);
    run.plane_contacts += double(session.state.pbd->data.contacts.points.size());
    run.piece_contacts += double(session.state.pbd->data.piece_contacts.set.points.size());
  }
  run.counters = session.state.pbd->data.piece_contacts.counters;
  return run;
}

// The liver's cut: a horizontal blade at 40 % of its height, along z across it, swept along x over
// `cut_steps` steps (a through-cut: the lower part rests on the tray, the upper hangs on it).
StepCommands liver_cut(const Session& session, uint32_t step, int cut_steps, Aabb& box) {
  if (step == 0) {
    box = Aabb{Vec3d::Constant(1e300), Vec3d::Constant(-1e300)};
    for (size_t v = 0; v < session.state.cut.surface.positions.size(); ++v) {
      if (session.state.cut.surface.vertex_piece[v] == CutSurface::kFreeKey) continue;
      box.min = box.min.cwiseMin(session.state.cut.surface.positions[v].cast<double>());
      box.max = box.max.cwiseMax(session.state.cut.surface.positions[v].cast<double>());
    }
  }
  StepCommands c;
  if (int(step) > cut_steps) return c;
  const Vec3d e = box.extent();
  const double m = 0.05 * e.maxCoeff(), x = box.min.x() - m + (e.x() + 2 * m) * step / std::max(1, cut_steps);
  const double y = box.min.y() + 0.4 * e.y();
  c.has_blade = true;
  c.cutting = step > 0;
  c.blade = {Vec3d(x, y, box.min.z() - m), Vec3d(x, y, box.max.z() + m)};
  return c;
}

// The bodies of the live pieces: the connected components of the particle-sharing graph.
uint32_t count_bodies(const PbdState& s, std::vector<uint32_t>& parent) {
  const uint32_t n = uint32_t(s.data.position.size());
  parent.resize(2 * size_t(n));  // parents, then a mark per root
  for (uint32_t p = 0; p < n; ++p) parent[p] = p;
  std::fill(parent.begin() + n, parent.end(), 0u);
  for (const auto& piece : s.model.pieces) {
    if (piece.sim_voxel == kDeadIndex) continue;
    for (int c = 1; c < 8; ++c) uf_unite(parent.data(), piece.particles[0], piece.particles[c]);
  }
  uint32_t bodies = 0;
  for (const auto& piece : s.model.pieces) {
    if (piece.sim_voxel == kDeadIndex) continue;
    uint32_t& mark = parent[n + uf_find(parent.data(), piece.particles[0])];
    bodies += mark == 0;
    mark = 1;
  }
  return bodies;
}

// One sever step: its phases (ms) and where it happened.
struct SeverStep {
  uint32_t stroke = 0, step = 0, bodies_before = 0, bodies_after = 0;
  StepTimings t;
};

// Every step of a sliced run: its phases and the bodies after it.
struct SlicedSteps {
  std::vector<StepTimings> timings;
  std::vector<uint32_t> bodies;
};

// A scene sliced by vertical through-cuts: every step that makes more bodies, with its phases; every
// step in `all`.
std::vector<SeverStep> run_sever(const Scene& scene, int workers, const BenchContactOptions& o, SlicedSteps& all) {
  Session session;
  open_session(scene, scene.pbd.dt, true, workers, session);
  Aabb box{Vec3d::Constant(1e300), Vec3d::Constant(-1e300)};
  const CutSurface& surface = session.state.cut.surface;
  for (size_t v = 0; v < surface.positions.size(); ++v) {
    if (surface.vertex_piece[v] == CutSurface::kFreeKey) continue;
    box.min = box.min.cwiseMin(surface.positions[v].cast<double>());
    box.max = box.max.cwiseMax(surface.positions[v].cast<double>());
  }
  std::vector<SeverStep> out;
  std::vector<uint32_t> parent;
  uint32_t bodies = count_bodies(*session.state.pbd, parent);
  const auto step = [&](uint32_t stroke, const StepCommands& c) {
    const StepReport report = session_step(session, c);
    all.timings.push_back(report.timings);
    const uint32_t now = count_bodies(*session.state.pbd, parent);
    all.bodies.push_back(now);
    if (now > bodies) out.push_back({stroke, report.step, bodies, now, report.timings});
    bodies = now;
  };
  // Slices at 15 %, 30 %, 45 % ... of the width from either end in turn (the anchor holds the middle).
  for (int k = 0; k < o.sever_strokes; ++k) {
    const double at = 0.15 * (1 + k / 2);
    const double height = k % 2 ? 1.0 - at : at;
    for (int j = 0; j <= o.sever_stroke_steps; ++j) {
      StepCommands c;
      c.has_blade = true;
      c.cutting = j > 0;
      c.blade = cut_pose(box, j, o.sever_stroke_steps, height, 0);
      step(uint32_t(k), c);
    }
    StepCommands lift;  // the stroke ends
    lift.has_blade = true;
    lift.cutting = false;
    lift.blade = cut_pose(box, o.sever_stroke_steps, o.sever_stroke_steps, height, 0);
    step(uint32_t(k), lift);
    for (int j = 0; j < o.sever_rest_steps; ++j) step(uint32_t(k), StepCommands());
  }
  return out;
}

}  // namespace

std::string bench_contact(const BenchContactOptions& options) {
  make_output_dir(options.out_dir);
  const fs::path source = DIVVOX_SOURCE_DIR_DEFAULT;
  const std::string recording =
      options.recording.empty() ? (source / "assets/recordings/bunny_cut.jsonl").string() : options.recording;
  const std::string liver = options.liver_scene.empty() ? (source / "assets/scenes/liver.json").string() : options.liver_scene;

  std::ostringstream csv;
  csv << "case,contact,steps,deform_p50_ms,deform_p99_ms,step_p50_ms,step_p99_ms,plane_contacts_per_step,"
         "piece_contacts_per_step,piece_pairs,points,point_pairs,contacts_per_piece_pair,contact_points_built\n";
  nlohmann::json rows = nlohmann::json::array();
  const auto add = [&](const std::string& name, bool contact, const ContactRun& run) {
    const double steps = double(std::max<size_t>(1, run.deform_ms.size()));
    const double p50 = quantile(run.deform_ms, 0.5), p99 = quantile(run.deform_ms, 0.99);
    const double s50 = quantile(run.step_ms, 0.5), s99 = quantile(run.step_ms, 0.99);
    const double per_pair = double(run.counters.contacts) / double(std::max<uint64_t>(1, run.counters.contact_pairs));
    csv << name << ',' << (contact ? "on" : "off") << ',' << run.deform_ms.size() << ',' << p50 << ',' << p99 << ','
        << s50 << ',' << s99 << ',' << run.plane_contacts / steps << ',' << run.piece_contacts / steps << ','
        << run.counters.piece_pairs << ',' << run.counters.points << ',' << run.counters.point_pairs << ',' << per_pair << ','
        << run.counters.reps_built << '\n';
    rows.push_back({{"case", name},
                    {"contact", contact},
                    {"steps", run.deform_ms.size()},
                    {"deform_ms", {{"p50", p50}, {"p99", p99}}},
                    {"step_ms", {{"p50", s50}, {"p99", s99}}},
                    {"plane_contacts_per_step", run.plane_contacts / steps},
                    {"piece_contacts_per_step", run.piece_contacts / steps},
                    {"piece_pairs", run.counters.piece_pairs},
                    {"points", run.counters.points},
                    {"point_pairs", run.counters.point_pairs},
                    {"contacts_per_piece_pair", per_pair},
                    {"contact_points_built", run.counters.reps_built}});
  };

  // The default recording, with its scene as recorded and without contact.
  const Playback playback = load_playback(recording);
  const std::string recording_name = fs::path(recording).filename().string();
  for (const bool contact : {true, false}) {
    if (options.progress) std::fprintf(stderr, "divvox bench contact: %s, contact %s\n", recording_name.c_str(), contact ? "on" : "off");
    PlaybackCursor cursor;
    const ContactRun run = run_case(contact ? playback.scene : without_contact(playback.scene), playback.dt, options.workers,
                                    playback.last_step() + 1, [&](const Session&, uint32_t step) {
                                      const PlaybackStep* recorded = next_commands(playback, cursor, step);
                                      return recorded ? recorded->commands : StepCommands();
                                    });
    add(recording_name, contact, run);
  }

  // The liver scene cut through, then resting.
  if (options.liver_cut_steps + options.liver_rest_steps > 0) {
    Scene scene = load_scene(liver);
    if (options.liver_resolution > 0) scene.pbd.resolution = options.liver_resolution;
    scene.pbd.sim_resolution = std::min(scene.pbd.sim_resolution, scene.pbd.resolution);
    const uint32_t steps = uint32_t(options.liver_cut_steps + options.liver_rest_steps);
    const std::string name = fs::path(liver).filename().string() + " (cut)";
    for (const bool contact : {true, false}) {
      if (options.progress) std::fprintf(stderr, "divvox bench contact: %s, contact %s\n", name.c_str(), contact ? "on" : "off");
      Aabb box;
      const ContactRun run = run_case(contact ? scene : without_contact(scene), scene.pbd.dt, options.workers, steps,
                                      [&](const Session& session, uint32_t step) {
                                        return liver_cut(session, step, options.liver_cut_steps, box);
                                      });
      add(name, contact, run);
    }
  }

  // Sever steps: the sever scene at the sever resolution sliced through (contact on, as the scene says).
  std::ostringstream sever_csv;
  sever_csv << "case,resolution,stroke,step,bodies_before,bodies_after,total_ms,cut_ms,map_ms,surface_ms,model_ms,"
               "deform_ms,contact_ms,solve_ms\n";
  std::ostringstream sliced_csv;  // every step of that run
  sliced_csv << "step,bodies,total_ms,cut_ms,surface_ms,model_ms,deform_ms,contact_ms\n";
  nlohmann::json sever = nullptr;
  if (options.sever_resolution > 0 && options.sever_strokes > 0) {
    const std::string sever_path = options.sever_scene.empty() ? (source / "assets/scenes/bunny.json").string() : options.sever_scene;
    Scene scene = load_scene(sever_path);
    scene.pbd.resolution = options.sever_resolution;
    scene.pbd.sim_resolution = std::min(scene.pbd.sim_resolution, scene.pbd.resolution);
    const std::string name = fs::path(sever_path).filename().string() + " (sliced)";
    if (options.progress) std::fprintf(stderr, "divvox bench contact: %s at %d\n", name.c_str(), options.sever_resolution);
    SlicedSteps all;
    const std::vector<SeverStep> severs = run_sever(scene, options.workers, options, all);
    std::vector<double> all_total, all_contact;
    for (size_t k = 0; k < all.timings.size(); ++k) {
      const StepTimings& t = all.timings[k];
      all_total.push_back(t.total_ms);
      all_contact.push_back(t.contact_ms);
      sliced_csv << k << ',' << all.bodies[k] << ',' << t.total_ms << ',' << t.cut_ms - t.model_ms << ',' << t.surface_ms << ','
                 << t.model_ms << ',' << t.deform_ms << ',' << t.contact_ms << '\n';
    }
    std::vector<double> total, cut, surface, model, contact, solve;
    for (const SeverStep& v : severs) {
      // cut_ms holds the model update; deform_ms the contacts' gathering.
      const double divide = v.t.cut_ms - v.t.model_ms, solver = v.t.deform_ms - v.t.contact_ms;
      sever_csv << name << ',' << options.sever_resolution << ',' << v.stroke << ',' << v.step << ',' << v.bodies_before << ','
                << v.bodies_after << ',' << v.t.total_ms << ',' << divide << ',' << v.t.map_ms << ',' << v.t.surface_ms << ','
                << v.t.model_ms << ',' << v.t.deform_ms << ',' << v.t.contact_ms << ',' << solver << '\n';
      total.push_back(v.t.total_ms);
      cut.push_back(divide);
      surface.push_back(v.t.surface_ms);
      model.push_back(v.t.model_ms);
      contact.push_back(v.t.contact_ms);
      solve.push_back(solver);
    }
    sever = {{"case", name},
             {"resolution", options.sever_resolution},
             {"sim_resolution", scene.pbd.sim_resolution},
             {"strokes", options.sever_strokes},
             {"steps", all.timings.size()},
             {"sever_steps", severs.size()},
             {"step_ms", percentiles_json(total)},
             {"phases_ms", {{"cut", percentiles_json(cut)},
                            {"surface", percentiles_json(surface)},
                            {"model", percentiles_json(model)},
                            {"contact", percentiles_json(contact)},
                            {"solve", percentiles_json(solve)}}},
             {"all_steps_ms", {{"step", percentiles_json(all_total)}, {"contact", percentiles_json(all_contact)}}}};
  }

  const fs::path out(options.out_dir);
  write_text_file((out / "bench_contact.csv").string(), csv.str());
  write_text_file((out / "bench_contact_sever.csv").string(), sever_csv.str());
  write_text_file((out / "bench_contact_sliced.csv").string(), sliced_csv.str());
  write_json_file((out / "bench_contact.json").string(), {{"benchmark", "contact"},
                                                          {"machine", machine_summary()},
                                                          {"workers", options.workers},
                                                          {"liver_cut_steps", options.liver_cut_steps},
                                                          {"liver_rest_steps", options.liver_rest_steps},
                                                          {"rows", rows},
                                                          {"sever", sever}});
  return (out / "bench_contact.csv").string();
}

void report_contact(const nlohmann::json& results, std::ostream& md, std::ostream& head) {
  if (results.is_null()) return;
  const auto fixed = [](double v) {
    char text[32];
    std::snprintf(text, sizeof text, "%.3g", v);
    return std::string(text);
  };
  md << "## Contact: step time with and without it\n\n"
     << "`divvox bench contact`, " << results.value("workers", 0) << " workers: the default recording with its scene "
        "(tray + piece contact) and without contact (no planes, `\"contact\": {\"pieces\": false}`); the liver scene "
        "cut through horizontally in " << results.value("liver_cut_steps", 0) << " steps, then "
     << results.value("liver_rest_steps", 0) << " steps at rest. Deform = the PBD step with contact gathering and "
        "solving; contacts = mean solved per step; per piece pair = contacts per pair of pieces in contact.\n\n"
     << "| case | contact | steps | deform p50 ms | deform p99 ms | step p50 ms | step p99 ms | plane contacts | "
        "piece contacts | per piece pair | p50 ratio |\n|---|---|---|---|---|---|---|---|---|---|---|\n";
  const nlohmann::json& rows = results["rows"];
  for (const nlohmann::json& r : rows) {
    // The ratio of this row's deform p50 to the same case without contact.
    double ratio = 0.0;
    for (const nlohmann::json& o : rows) {
      if (o["case"] == r["case"] && !o["contact"].get<bool>()) ratio = r["deform_ms"]["p50"].get<double>() / std::max(1e-9, o["deform_ms"]["p50"].get<double>());
    }
    md << "| " << r["case"].get<std::string>() << " | " << (r["contact"].get<bool>() ? "on" : "off") << " | " << r["steps"]
       << " | " << fixed(r["deform_ms"]["p50"]) << " | " << fixed(r["deform_ms"]["p99"]) << " | " << fixed(r["step_ms"]["p50"])
       << " | " << fixed(r["step_ms"]["p99"]) << " | " << fixed(r["plane_contacts_per_step"]) << " | "
       << fixed(r["piece_contacts_per_step"]) << " | " << fixed(r.value("contacts_per_piece_pair", 0.0)) << " | "
       << fixed(ratio) << "× |\n";
    if (r["contact"].get<bool>() && r["case"] == rows[0]["case"]) {
      head << "- **Contact** on the default recording: deform p50 " << fixed(ratio) << "× the step without contact.\n";
    }
  }
  md << "\n";
  const nlohmann::json& sever = results.contains("sever") ? results["sever"] : nlohmann::json();
  if (!sever.is_null()) {
    const auto cell = [&](const nlohmann::json& p) {
      return fixed(p.value("p50", 0.0)) + " / " + fixed(p.value("p99", 0.0)) + " / " + fixed(p.value("max", 0.0));
    };
    md << "**Sever steps** (the steps after which the pieces form more bodies): " << sever["case"].get<std::string>() << " at "
       << sever["resolution"] << ", " << sever["strokes"] << " vertical through-cuts, " << sever["sever_steps"]
       << " sever steps in " << sever["steps"] << " steps; p50 / p99 / max in ms:\n\n"
       << "| step | cut | surface | model update | contact gathering | solver + embedding |\n|---|---|---|---|---|---|\n"
       << "| " << cell(sever["step_ms"]) << " | " << cell(sever["phases_ms"]["cut"]) << " | " << cell(sever["phases_ms"]["surface"])
       << " | " << cell(sever["phases_ms"]["model"]) << " | " << cell(sever["phases_ms"]["contact"]) << " | "
       << cell(sever["phases_ms"]["solve"]) << " |\n\n";
    if (sever.contains("all_steps_ms")) {
      md << "All " << sever["steps"] << " steps of that run (strokes, rests, severs), p50 / p99 / max in ms: step "
         << cell(sever["all_steps_ms"]["step"]) << ", contact gathering " << cell(sever["all_steps_ms"]["contact"]) << ".\n\n";
    }
  }
}

}  // namespace dvx
