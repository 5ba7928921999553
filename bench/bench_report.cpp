// `divvox bench report`: REPORT.md and its plots from the JSON results of the other benchmarks
// (and of tools/peers when it ran). Each section appears when its results exist.
#include "bench/bench.h"
#include "bench/bench_contact.h"
#include "engine/errors.h"
#include "engine/output.h"
#include "engine/scene.h"
#include "engine/stats.h"
#include "harness/plot.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>

namespace dvx {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// A number with `digits` significant digits (ms, ratios, errors).
std::string num(double v, int digits = 3) {
  char text[48];
  std::snprintf(text, sizeof text, "%.*g", digits, v);
  return text;
}
std::string pct(double fraction) { return num(100.0 * fraction, 3) + " %"; }
std::string mib(double bytes) { return num(bytes / (1024.0 * 1024.0), 3) + " MiB"; }

// The solver settings the shipped scenes use (assets/scenes/bunny.json, the headless default; the
// window's liver uses the same), against which the speed-against-error front is read; the built-in
// defaults of a scene without a `solver` block when that file is not there.
PbdParams shipped_solver() {
  const fs::path path = fs::path(DIVVOX_SOURCE_DIR_DEFAULT) / "assets/scenes/bunny.json";
  if (fs::exists(path)) {
    try {
      return load_scene(path.string()).pbd;
    } catch (const std::exception&) {
    }
  }
  return Scene().pbd;
}

// A results file as JSON, or null when it does not exist.
json read_results(const fs::path& dir, const std::string& name) {
  const fs::path path = dir / name;
  if (!fs::exists(path)) return nullptr;
  std::ifstream file(path);
  json value = json::parse(file, nullptr, false);
  if (value.is_discarded()) throw_input(path.string(), "not valid JSON");
  return value;
}

double get(const json& j, const char* key, double fallback = 0.0) {
  return j.is_object() && j.contains(key) && j[key].is_number() ? j[key].get<double>() : fallback;
}

// The machine the results were measured on (they record it), else this one (older results).
std::string machine_of(const json& results) {
  return results.is_object() && results.contains("machine") && results["machine"].is_string()
             ? results["machine"].get<std::string>()
             : machine_summary();
}
// The plot's second title line: what ran, on which machine.
std::string measured_on(const json& results, const std::string& what) {
  const std::string machine = machine_of(results);
  return what + (what.empty() ? "" : "; ") + "measured on " + machine;
}

// Draws a plot beside the CSVs (SVG, and PNG for pages that embed it). Returns the SVG's file name, or
// "" with `error` when gnuplot did not draw it.
std::string draw_into(const fs::path& dir, const std::string& name, const Plot& plot, std::string& error) {
  const fs::path svg = dir / name;
  return draw_plot(plot, {svg.string(), fs::path(svg).replace_extension(".png").string()}, error) ? name : "";
}

// The Markdown image line of a drawn plot (or why it is missing).
std::string image_line(const std::string& title, const std::string& link_dir, const std::string& name,
                       const std::string& error) {
  if (name.empty()) {
    std::fprintf(stderr, "divvox: bench report: plot \"%s\" skipped: %s\n", title.c_str(), error.c_str());
    return "(plot \"" + title + "\" skipped: " + error + ")\n";
  }
  return "![" + title + "](" + link_dir + "/" + name + ")\n";
}

// A plot with both axes logarithmic.
Plot log_log_plot(const std::string& title, const std::string& subtitle, const std::string& x_label,
                  const std::string& y_label) {
  Plot plot;
  plot.title = title;
  plot.subtitle = subtitle;
  plot.x_label = x_label;
  plot.y_label = y_label;
  plot.log_x = plot.log_y = true;
  return plot;
}

PlotSeries series(const std::string& name, bool markers, bool lines) {
  PlotSeries s;
  s.name = name;
  s.markers = markers;
  s.lines = lines;
  return s;
}

// The Pareto front of the points (smaller is better on both axes) as a wide grey band under them.
PlotSeries front_series(const std::string& name, const std::vector<double>& x, const std::vector<double>& y) {
  PlotSeries s = series(name, true, true);  // markers: a one-point front shows too
  s.colour = "#cfcfcf";
  s.width = 9.0;
  s.point_size = 2.2;
  for (size_t i : pareto_front(x, y)) {
    s.x.push_back(x[i]);
    s.y.push_back(y[i]);
  }
  return s;
}

// Chosen settings (the defaults) as large open circles.
PlotSeries chosen_series(const std::string& name) {
  PlotSeries s = series(name, true, false);
  s.colour = "#000000";
  s.point_type = 6;
  s.point_size = 2.4;
  return s;
}

// The histogram of an angle_stats_json value as a plot series (fraction of triangles per 5-degree bin).
PlotSeries histogram_series(const std::string& name, const json& stats, const char* key) {
  PlotSeries s = series(name, true, true);
  const double n = std::max(1.0, get(stats, "triangles"));
  for (size_t i = 0; i < stats[key].size(); ++i) {
    s.x.push_back(5.0 * double(i) + 2.5);
    s.y.push_back(stats[key][i].get<double>() / n);
  }
  return s;
}

// Experiment 2: time against cut voxels, both samples and their least-squares lines.
Plot cut_length_plot(const json& r) {
  Plot plot;
  plot.title = "Experiment 2: cutting time against the voxels a step cuts";
  plot.subtitle = measured_on(r, r.value("mesh", std::string()) + " at " + std::to_string(r.value("resolution", 0)) +
                                     ", no physics, medians of " + std::to_string(r.value("repeats", 0)));
  plot.x_label = "voxels cut in the step";
  plot.y_label = "divide + surface time (ms)";
  const struct { const char* key; const char* name; const char* colour; } samples[] = {
      {"single_step", "one step per cut length", "#1f77b4"}, {"progressive", "steps of a progressive cut", "#d62728"}};
  for (const auto& sample : samples) {
    const json& part = r[sample.key];
    PlotSeries s = series(sample.name, true, false);
    s.colour = sample.colour;
    s.point_size = 0.8;
    s.x = part["x_voxels_cut"].get<std::vector<double>>();
    s.y = part["y_ms"].get<std::vector<double>>();
    if (s.x.empty()) continue;
    const json& fit = part["fit"];
    char name[96];
    std::snprintf(name, sizeof name, "fit: %.3g µs per voxel, R² %.4g", get(fit, "us_per_voxel"), get(fit, "r2"));
    PlotSeries line = series(name, false, true);
    line.colour = sample.colour;
    const double hi = *std::max_element(s.x.begin(), s.x.end());
    line.x = {0.0, hi};
    line.y = {get(fit, "intercept_ms"), get(fit, "intercept_ms") + get(fit, "us_per_voxel") * 1e-3 * hi};
    plot.series.push_back(s);
    plot.series.push_back(line);
  }
  return plot;
}

// The solvers of the shipped scenes' budget (substeps x iterations constraint passes per step) at the
// finest simulation level, where the reference lives, so only the solver differs: how the shipped
// setting ranks among the ways of spending its budget (Macklin et al. 2019's small steps against more
// iterations), per scenario.
std::string budget_table(const json& deform, const PbdParams& shipped) {
  int finest = 0;
  for (const json& r : deform["rows"]) finest = std::max(finest, r["sim_resolution"].get<int>());
  const int budget = shipped.substeps * shipped.iterations;
  std::ostringstream md;
  md << "The same budget (" << budget << " constraint passes per step) spent as substeps × iterations at the finest "
     << "level (sim " << finest << "), where only the solver differs from the reference:\n\n"
     << "| scenario | substeps × iterations | step p50 ms | error |\n|---|---|---|---|\n";
  std::string verdict;
  for (const char* scenario : {"anchored", "through_cut"}) {
    std::vector<const json*> rows;
    for (const json& r : deform["rows"]) {
      if (r["scenario"] == scenario && r["sim_resolution"] == finest &&
          r.value("substeps", 1) * r["iterations"].get<int>() == budget) {
        rows.push_back(&r);
      }
    }
    if (rows.empty()) continue;
    std::sort(rows.begin(), rows.end(), [](const json* a, const json* b) { return get(*a, "relative_error") < get(*b, "relative_error"); });
    for (const json* r : rows) {
      md << "| " << scenario << " | " << r->value("substeps", 1) << " × " << (*r)["iterations"].get<int>() << " | "
         << num(get(*r, "step_p50_ms")) << " | " << num(get(*r, "relative_error")) << " |\n";
    }
    const json& best = *rows.front();
    const bool shipped_best = best.value("substeps", 1) == shipped.substeps && best["iterations"] == shipped.iterations;
    verdict += std::string(verdict.empty() ? "" : "; ") + scenario + ": " +
               (shipped_best ? "the shipped " + std::to_string(shipped.substeps) + " × " + std::to_string(shipped.iterations) + " is the most accurate"
                             : "the most accurate is " + std::to_string(best.value("substeps", 1)) + " × " +
                                   std::to_string(best["iterations"].get<int>()));
  }
  if (verdict.empty()) return "";
  md << "\n" << verdict << ".\n\n";
  return md.str();
}

// Physics speed against error: one panel per scenario, a curve per simulation resolution (points
// labelled with their iterations), the Pareto front and the scene's default setting marked.
Plot deform_plot(const json& r) {
  Plot plot;
  plot.title = "PBD: step time against error, by simulation resolution and iterations";
  plot.subtitle = measured_on(r, r.value("mesh", std::string()) + " at " + std::to_string(r.value("resolution", 0)) +
                                     ", " + std::to_string(r.value("workers", 0)) + " workers, labels: iterations");
  plot.x_label = "PBD + embedding step time, p50 (ms)";
  plot.log_x = true;
  const PbdParams defaults = shipped_solver();
  for (const char* scenario : {"anchored", "through_cut"}) {
    PlotPanel panel{std::string(scenario == std::string("anchored") ? "anchored" : "through-cut") + ": relative error",
                    true, {}, {}};
    std::map<int, PlotSeries> by_sim;
    std::vector<double> all_x, all_y;
    PlotSeries chosen = chosen_series("shipped scenes (sim " + std::to_string(defaults.sim_resolution) + ", " +
                                      std::to_string(defaults.substeps) + "x" + std::to_string(defaults.iterations) + ")");
    for (const json& row : r["rows"]) {
      if (row["scenario"] != scenario || get(row, "relative_error") <= 0.0) continue;  // the reference itself
      const int sim = row["sim_resolution"], iterations = row["iterations"];
      // The small-steps sweep (substeps > 1, labels substeps x iterations) in its own series per sim.
      const int substeps = row.value("substeps", 1);
      const int key = substeps > 1 ? -sim : sim;
      const std::string label = "sim " + std::to_string(sim) + (substeps > 1 ? ", substeps x iterations" : "");
      PlotSeries& s = by_sim.try_emplace(key, series(label, true, true)).first->second;
      s.x.push_back(get(row, "step_p50_ms"));
      s.y.push_back(get(row, "relative_error"));
      s.point_labels.push_back(substeps > 1 ? std::to_string(substeps) + "x" + std::to_string(iterations)
                                            : std::to_string(iterations));
      all_x.push_back(s.x.back());
      all_y.push_back(s.y.back());
      if (sim == defaults.sim_resolution && iterations == defaults.iterations && substeps == defaults.substeps) {
        chosen.x.push_back(s.x.back());
        chosen.y.push_back(s.y.back());
      }
    }
    panel.series.push_back(front_series("Pareto front", all_x, all_y));
    for (auto& [sim, s] : by_sim) panel.series.push_back(s);
    if (!chosen.x.empty()) panel.series.push_back(chosen);
    plot.panels.push_back(panel);
  }
  return plot;
}


// bench elastic: per swept case, step time against the error to CalculiX, by model and simulation
// resolution; the Pareto front, the shipped solver and the chosen setting (the cheapest on the front
// within 10 % RMS) marked.
struct ElasticPick {
  const json* shipped = nullptr;  // the shipped solver at the shipped simulation resolution
  const json* chosen = nullptr;   // the cheapest Pareto-optimal row within 10 % RMS error
};
ElasticPick elastic_pick(const json& r, const std::string& name, const std::string& model) {
  ElasticPick pick;
  const json& shipped = r.contains("shipped") ? r["shipped"] : json::object();
  std::vector<const json*> rows;
  for (const json& row : r["rows"]) {
    if (row["case"] != name || row["model"] != model || !(get(row, "rms_error", -1.0) >= 0.0)) continue;
    rows.push_back(&row);
    if (row.value("kind", std::string()) == "defaults" && row["sim_resolution"] == shipped.value("sim_resolution", 16)) {
      pick.shipped = &row;
    }
  }
  for (const json* row : rows) {
    bool dominated = false;
    for (const json* o : rows) {
      dominated = dominated || (get(*o, "step_p50_ms") < get(*row, "step_p50_ms") && get(*o, "rms_error") <= get(*row, "rms_error"));
    }
    if (dominated || get(*row, "rms_error") > 0.1) continue;
    if (!pick.chosen || get(*row, "step_p50_ms") < get(*pick.chosen, "step_p50_ms")) pick.chosen = row;
  }
  return pick;
}

std::string elastic_setting(const json& row) {
  return "sim " + std::to_string(row["sim_resolution"].get<int>()) + ", " + std::to_string(row["substeps"].get<int>()) +
         "x" + std::to_string(row["iterations"].get<int>());
}

Plot elastic_plot(const json& r) {
  Plot plot;
  plot.title = "Elasticity: step time against error to CalculiX";
  plot.subtitle = measured_on(r, std::to_string(r.value("workers", 1)) + " workers, labels: substeps x iterations");
  plot.x_label = "step time (world_step), p50 (ms)";
  plot.log_x = true;
  std::vector<std::string> cases;
  for (const json& row : r["rows"]) {
    const std::string name = row["case"];
    if (row.value("kind", std::string()) == "sweep" && std::find(cases.begin(), cases.end(), name) == cases.end()) cases.push_back(name);
  }
  // Without a sweep: every case's shipped-solver rows.
  for (const json& row : r["rows"]) {
    const std::string name = row["case"];
    if (std::find(cases.begin(), cases.end(), name) == cases.end() && cases.size() < 2 && row.value("kind", std::string()) == "defaults") {
      bool swept = false;
      for (const json& o : r["rows"]) swept = swept || o.value("kind", std::string()) == "sweep";
      if (!swept) cases.push_back(name);
    }
  }
  for (const std::string& name : cases) {
    PlotPanel panel{name + ": relative RMS error", true, {}, {}};
    std::map<std::string, PlotSeries> by_key;
    std::vector<double> all_x, all_y;
    for (const json& row : r["rows"]) {
      if (row["case"] != name || !(get(row, "rms_error") > 0.0)) continue;
      const std::string key = row["model"].get<std::string>() + ", sim " + std::to_string(row["sim_resolution"].get<int>());
      PlotSeries& s = by_key.try_emplace(key, series(key, true, false)).first->second;
      s.x.push_back(get(row, "step_p50_ms"));
      s.y.push_back(get(row, "rms_error"));
      s.point_labels.push_back(std::to_string(row["substeps"].get<int>()) + "x" + std::to_string(row["iterations"].get<int>()));
      all_x.push_back(s.x.back());
      all_y.push_back(s.y.back());
    }
    panel.series.push_back(front_series("Pareto front", all_x, all_y));
    for (auto& [key, s] : by_key) panel.series.push_back(s);
    PlotSeries shipped = chosen_series("shipped solver"), chosen = chosen_series("chosen (cheapest within 10 %)");
    chosen.point_type = 4;
    for (const char* model : {"neo_hookean", "paper"}) {
      const ElasticPick pick = elastic_pick(r, name, model);
      if (pick.shipped) {
        shipped.x.push_back(get(*pick.shipped, "step_p50_ms"));
        shipped.y.push_back(get(*pick.shipped, "rms_error"));
      }
      if (pick.chosen) {
        chosen.x.push_back(get(*pick.chosen, "step_p50_ms"));
        chosen.y.push_back(get(*pick.chosen, "rms_error"));
      }
    }
    if (!shipped.x.empty()) panel.series.push_back(shipped);
    if (!chosen.x.empty()) panel.series.push_back(chosen);
    PlotLine ten;
    ten.y = 0.1;
    ten.label = "10 %";
    panel.lines.push_back(ten);
    plot.panels.push_back(panel);
  }
  return plot;
}

// The results a report reads: each file read once, on first use (null when it does not exist).
struct Results {
  fs::path dir;      // the results folder (plots are drawn into it)
  std::string link;  // the results folder relative to the report (for links and images)
  std::map<std::string, json> files;

  const json& read(const std::string& name) {
    auto it = files.find(name);
    if (it == files.end()) it = files.emplace(name, read_results(dir, name)).first;
    return it->second;
  }
  // Draws `plot` into the results folder and returns its Markdown image line (`title`: the image's
  // name in the text, default the plot's title).
  std::string plot(const std::string& name, const Plot& plot, const std::string& title = "") const {
    std::string error;
    return image_line(title.empty() ? plot.title : title, link, draw_into(dir, name, plot, error), error);
  }
};

// Issue 12's bounds on the cut step with the physics model update (the `cut` column): p99 at 256 and
// 512 against 1 and 2 ms, and per mesh bench scaling's p99 ratio of its highest resolution to 128
// against 2 (flat in resolution).
std::string scaling_flatness(const json& scaling) {
  if (!scaling.contains("cut_p99_flatness")) return "";
  std::ostringstream out;
  for (const json& f : scaling["cut_p99_flatness"]) {
    out << (out.tellp() == 0 ? "\n" : "") << "- " << f["mesh"].get<std::string>()
        << ": cut step with the physics model update, p99 at " << f["to"] << " / p99 at " << f["from"] << " = "
        << num(get(f, "cut_p99_ratio")) << " (issue 12: ≤ 2 from 128 to 512)";
    for (const json& r : scaling["rows"]) {
      const int res = r["resolution"];
      if (r["mesh"] != f["mesh"] || r["status"] != "ok" || (res != 256 && res != 512)) continue;
      out << "; p99 at " << res << ": " << num(get(r["step_ms"]["cut"], "p99")) << " ms (≤ " << (res == 256 ? 1 : 2) << ")";
    }
    if (f.contains("cut_us_per_voxel_to")) {
      out << "; per fine voxel cut: " << num(get(f, "cut_us_per_voxel_from")) << " µs at " << f["from"] << ", "
          << num(get(f, "cut_us_per_voxel_to")) << " µs at " << f["to"];
    }
    out << ".\n";
  }
  return out.str();
}

// Experiment 1 (paper Table 1, Fig. 8): time per cutting step with the physics, memory, plot.
void scaling_section(Results& in, std::ostream& md, std::ostream& head) {
  const json& scaling = in.read("bench_scaling.json");
  if (scaling.is_null()) return;
  md << "## 1. Scaling with resolution (paper Table 1, Fig. 8)\n\n"
     << "The same horizontal cut (scene units) through each mesh, " << scaling["steps"].get<int>()
     << " blade poses, physics on (PBD at the simulation resolution shown, anchored on the lowest 20 %, gravity). "
        "Times are per step whose sweep cut voxels: p50 / p99 in ms. Memory: peak RSS of the process for that "
        "configuration; bytes per occupied voxel counts the voxel model and the explicit cut data. World to rest: "
        "the blade's sweep mapped through the deformed pieces, µs per blade sample (Newton inversions per sample); "
        "per-step counters in `bench_scaling_steps.csv`.\n\n"
     << "| mesh | res | lattice | occupied voxels | cut | surface | deform | total | world to rest | peak RSS | "
        "B/occ. voxel | triangles | status |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  std::map<std::string, PlotSeries> total_series;
  for (const json& r : scaling["rows"]) {
    const std::string mesh = r["mesh"];
    if (r["status"] != "ok") {
      md << "| " << mesh << " | " << r["resolution"] << " | | | | | | | | | | | " << r["status"].get<std::string>()
         << " |\n";
      continue;
    }
    const json& t = r["step_ms"];
    auto cell = [&](const char* k) { return num(get(t[k], "p50")) + " / " + num(get(t[k], "p99")); };
    std::string map_cell;  // world to rest: µs per sample (Newton inversions per sample)
    if (r.contains("world_to_rest")) {
      const json& m = r["world_to_rest"];
      const double samples = get(m, "samples");
      map_cell = num(get(m, "us_per_sample")) + " (" + num(samples > 0 ? get(m, "piece_tests") / samples : 0.0) + ")";
    }
    md << "| " << mesh << " | " << r["resolution"] << " | " << r["lattice"][0] << "×" << r["lattice"][1] << "×"
       << r["lattice"][2] << " | " << r["occupied_voxels"] << " | " << cell("cut") << " | " << cell("surface")
       << " | " << cell("deform") << " | " << cell("total") << " | " << map_cell << " | "
       << mib(get(r, "peak_rss_bytes")) << " | "
       << num(get(r, "bytes_per_occupied_voxel")) << " | " << r["surface_triangles"] << " | ok |\n";
    PlotSeries& s = total_series[mesh];
    s.name = mesh;
    s.x.push_back(get(r, "occupied_voxels"));
    s.y.push_back(get(t["total"], "p50"));
    s.point_labels.push_back(std::to_string(r["resolution"].get<int>()));
    if (mesh.rfind("armadillo", 0) == 0 && r["resolution"] == 256) {
      head << "- **Cutting with physics**, armadillo at 256 (" << r["occupied_voxels"]
           << " occupied voxels): " << cell("total") << " ms per cutting step with the physics (p50 / p99; cutting, including the simulation model's update, + surface "
           << num(get(t["cut"], "p99") + get(t["surface"], "p99")) << " ms p99), "
           << num(get(r, "bytes_per_occupied_voxel")) << " B per occupied voxel.\n";
    }
  }
  md << scaling_flatness(scaling);
  Plot plot = log_log_plot("Experiment 1: time per cutting step (cut + surface + deform, p50) against model size",
                           measured_on(scaling, "points labelled with the resolution, physics on"), "occupied voxels",
                           "ms per cutting step (p50)");
  for (auto& [name, s] : total_series) plot.series.push_back(s);
  plot.lines.push_back({33.0, "frame budget 33 ms", "#b03030", 1, true, false});
  md << "\n" << in.plot("report_scaling.svg", plot) << "\n";
}

// Experiment 2 (paper Fig. 9-10): time against cut voxels, the least-squares fits and their plot.
void cut_length_section(Results& in, std::ostream& md, std::ostream& head) {
  const json& length = in.read("bench_cut_length.json");
  if (length.is_null()) return;
  const json& one = length["single_step"]["fit"];
  const json& prog = length["progressive"]["fit"];
  md << "## 2. Time against cut voxels (paper Fig. 9–10)\n\n"
     << length["mesh"].get<std::string>() << " at " << length["resolution"]
     << ", no physics. *One step per length*: cuts of 1/10 … 10/10 of the path, each made in one step on a "
        "fresh model; *progressive*: each step of a " << length["progressive"]["steps"]
     << "-step cut. Least-squares lines (time = intercept + slope × voxels):\n\n"
     << "| samples | slope (µs per cut voxel) | intercept (ms) | R² |\n|---|---|---|---|\n"
     << "| one step per length | " << num(get(one, "us_per_voxel")) << " | " << num(get(one, "intercept_ms")) << " | "
     << num(get(one, "r2"), 4) << " |\n"
     << "| progressive steps | " << num(get(prog, "us_per_voxel")) << " | " << num(get(prog, "intercept_ms"))
     << " | " << num(get(prog, "r2"), 4) << " |\n\n"
     << in.plot("bench_cut_length.svg", cut_length_plot(length), "Experiment 2")
     << "\n";
  head << "- **Cost is linear in the cut voxels**: " << num(get(one, "us_per_voxel")) << " µs per cut voxel (R² "
       << num(get(one, "r2"), 4) << ") for one-step cuts of growing length on " << length["mesh"].get<std::string>()
       << " at " << length["resolution"] << ".\n";
}

// Section 3's heading, above its surface and physics parts (when either ran).
void speed_error_heading(Results& in, std::ostream& md, std::ostream&) {
  if (!in.read("bench_voxelize.json").is_null() || !in.read("bench_deform.json").is_null()) {
    md << "## 3. Speed against error\n\n";
  }
}

// Section 3, surface: voxelize + dual contouring, time against error (with OpenVDB's points when it ran).
void surface_section(Results& in, std::ostream& md, std::ostream&) {
  const json& voxelize = in.read("bench_voxelize.json");
  const json& vdb = in.read("peers_vdb.json");
  if (voxelize.is_null()) return;
  md << "### Surface: voxelize + dual contouring against resolution\n\n"
     << "Error: two-sided sampled distance between the dual-contoured surface and the input mesh, in voxels "
        "(mean / max), " << voxelize.value("error_samples", 0) << " samples per side. Time: load excluded "
        "(voxelize + contour, median).\n\n"
     << "| mesh | res | voxelize + contour ms | error mean | error max | error mean (scene units) | triangles |\n"
        "|---|---|---|---|---|---|---|\n";
  std::map<std::string, PlotSeries> by_mesh;
  const Scene defaults;
  PlotSeries chosen = chosen_series("scene default (resolution " + std::to_string(defaults.pbd.resolution) + ")");
  for (const json& r : voxelize["rows"]) {
    if (r["status"] != "ok" || !r.contains("error_voxels")) continue;
    const double ms = get(r["time_ms"], "voxelize") + get(r["time_ms"], "contour");
    const double h = get(r, "voxel_size"), mean = get(r["error_voxels"], "mean");
    md << "| " << r["mesh"].get<std::string>() << " | " << r["resolution"] << " | " << num(ms) << " | " << num(mean)
       << " | " << num(get(r["error_voxels"], "max")) << " | " << num(mean * h) << " | " << r["surface_triangles"]
       << " |\n";
    PlotSeries& s = by_mesh.try_emplace(r["mesh"].get<std::string>(), series("divvox " + r["mesh"].get<std::string>(), true, true)).first->second;
    s.x.push_back(ms);
    s.y.push_back(mean / get(r, "resolution"));  // voxels over voxels per longest side
    s.point_labels.push_back(std::to_string(r["resolution"].get<int>()));
    if (r["resolution"] == defaults.pbd.resolution) {
      chosen.x.push_back(ms);
      chosen.y.push_back(s.y.back());
    }
  }
  Plot plot = log_log_plot("Surface extraction: time against error (voxelize + dual contouring)",
                           measured_on(voxelize, "points labelled with the resolution"),
                           "voxelize + contour time, median (ms)", "mean error / longest side of the mesh");
  // The Pareto front of each mesh (with OpenVDB's points on its mesh), under the curves.
  const std::string peer_mesh = vdb.is_object() ? vdb.value("mesh", std::string()) : std::string();
  PlotSeries peer = series("OpenVDB " + peer_mesh, true, true);
  peer.colour = "#555555";
  peer.point_type = 5;
  if (!vdb.is_null() && vdb.value("status", "") == "ok") {
    for (const json& r : vdb["rows"]) {
      peer.x.push_back(get(r, "total_ms"));
      peer.y.push_back(get(r["error"], "mean") / get(r, "resolution"));
      peer.point_labels.push_back(std::to_string(r["resolution"].get<int>()));
    }
  }
  for (auto& [mesh, s] : by_mesh) {
    std::vector<double> x = s.x, y = s.y;
    if (mesh == peer_mesh) {
      x.insert(x.end(), peer.x.begin(), peer.x.end());
      y.insert(y.end(), peer.y.begin(), peer.y.end());
    }
    plot.series.push_back(front_series(plot.series.empty() ? "Pareto front (per mesh)" : "", x, y));
  }
  for (auto& [mesh, s] : by_mesh) plot.series.push_back(s);
  if (!peer.x.empty()) plot.series.push_back(peer);
  if (!chosen.x.empty()) plot.series.push_back(chosen);
  md << "\n" << in.plot("report_surface_pareto.svg", plot) << "\n";
}

// Section 3, physics: the Pareto-optimal simulation resolution x iterations, their plot, the speed target.
void deform_section(Results& in, std::ostream& md, std::ostream&) {
  const json& deform = in.read("bench_deform.json");
  if (deform.is_null()) return;
  md << "### Physics: simulation resolution × iterations\n\n"
     << deform["mesh"].get<std::string>() << " at " << deform["resolution"] << ", anchored on one side under gravity, "
     << num(get(deform, "seconds")) << " s simulated, " << deform["workers"] << " workers. Error: "
     << deform["error"].get<std::string>() << ". The Pareto-optimal settings (no other setting is both faster and "
        "more accurate; the reference run itself, error 0 by definition, left out). PBD's shape matching stiffens with "
        "iterations and with coarser simulation voxels, so at coarse levels the error need not fall with iterations: "
        "it includes the coarse model's own error, not only the solver's. Both sweeps are in it: the iterations "
        "sweep (1 substep) and the small-steps sweep (substeps × iterations at equal cost, Macklin et al. 2019).\n\n"
        "| scenario | sim res | substeps × iterations | step p50 ms | error |\n|---|---|---|---|---|\n";
  const PbdParams defaults = shipped_solver();
  std::string default_on_front;  // the scenarios whose front holds the shipped scenes' setting
  std::string default_rows;      // that setting's own figures per scenario
  for (const char* scenario : {"anchored", "through_cut"}) {
    std::vector<const json*> rows;
    for (const json& r : deform["rows"]) {
      if (r["scenario"] == scenario && get(r, "relative_error") > 0.0) rows.push_back(&r);
    }
    for (const json* r : rows) {
      const int substeps = r->value("substeps", 1), iterations = (*r)["iterations"], sim = (*r)["sim_resolution"];
      const bool shipped = sim == defaults.sim_resolution && iterations == defaults.iterations && substeps == defaults.substeps;
      if (shipped) {
        default_rows += std::string(default_rows.empty() ? "" : "; ") + scenario + " " + num(get(*r, "step_p50_ms")) +
                        " ms, error " + num(get(*r, "relative_error"));
      }
      bool dominated = false;
      for (const json* o : rows) {
        dominated = dominated || (get(*o, "step_p50_ms") < get(*r, "step_p50_ms") &&
                                  get(*o, "relative_error") <= get(*r, "relative_error"));
      }
      if (dominated) continue;
      if (shipped) default_on_front += std::string(default_on_front.empty() ? "" : " and ") + scenario;
      md << "| " << scenario << " | " << sim << " | " << substeps << " × " << iterations << " | "
         << num(get(*r, "step_p50_ms")) << " | " << num(get(*r, "relative_error")) << " |\n";
    }
  }
  md << "\nThe shipped scenes' solver (sim " << defaults.sim_resolution << ", " << defaults.substeps << " × "
     << defaults.iterations << ") is "
     << (default_on_front.empty() ? std::string("on neither front") : "on the " + default_on_front + " front")
     << (default_rows.empty() ? std::string(" (not measured in this run)") : " (" + default_rows + ")")
     << ". With shape stiffness 1 the model's converged limit is rigid (every cluster keeps its rest shape), so "
        "the reference is itself an effort-dependent solution and these errors rank settings against that run, "
        "not against a physical limit; at a coarser level they also hold that level's own model error. The error "
        "against physics (CalculiX, the same geometry and material) is the next section's (`bench elastic`).\n\n"
     << budget_table(deform, defaults)
     << in.plot("bench_deform.svg", deform_plot(deform), "physics speed against error")
     << "\n";
  // The shape-matching kernel before (scalar) and after (blocks, issue 17), measured in the same run.
  const json& kernels = deform.contains("kernels") ? deform["kernels"] : json();
  if (kernels.is_object() && kernels.contains("shape_matching")) {
    const json& r = kernels["shape_matching"];
    md << "Shape-matching kernel before (scalar) and after (vector blocks of " << kShapeLanes
       << " clusters, issue 17; path " << kernels.value("path", std::string("?")) << "), same run, on "
       << "the settled reference state (" << kernels["clusters"] << " clusters): " << num(get(r, "scalar_ns"))
       << " → " << num(get(r, "blocks_ns")) << " ns per cluster solve (" << num(get(r, "speedup")) << "×), "
       << (r["identical"].get<bool>() ? "the same bits" : "**results differ**") << ".\n\n";
  }
  if (kernels.is_object() && kernels.contains("stretch")) {
    const json& r = kernels["stretch"];
    md << "Stretch constraints before (rows one by one) and after (the rows of a colour eight at a time with AVX-512, "
       << "four with AVX2; path " << kernels.value("path", std::string("?")) << "), same run, same state ("
       << kernels["stretch_constraints"] << " constraints, every colour once): " << num(get(r, "rows_ns")) << " → "
       << num(get(r, "vector_ns")) << " ns per constraint ("
       << num(get(r, "speedup")) << "×), " << (r["identical"].get<bool>() ? "the same bits" : "**results differ**")
       << ".\n\n";
  }
  const json& target = deform["target"];
  if (target.is_object()) {
    md << "Speed target: " << target["mesh"].get<std::string>() << " at " << target["resolution"] << " ("
       << target["surface_vertices"] << " surface vertices), simulation " << target["sim_resolution"] << ", "
       << target["iterations"] << " iterations, " << target["workers"] << " workers: PBD + embedding "
       << num(get(target["step_ms"], "p50")) << " ms p50, " << num(get(target["step_ms"], "p99")) << " ms p99 per step.\n\n";
  }
}

// Speed against error, for real (issue 30): the error to CalculiX of each case at the shipped solver,
// the sweep's front, the frequency. Replaces bench deform's self-referenced error as the report.
void elastic_section(Results& in, std::ostream& md, std::ostream& head) {
  const json& r = in.read("bench_elastic.json");
  if (r.is_null()) return;
  const json& shipped = r["shipped"];
  md << "### Elasticity against a finite-element reference (bench elastic)\n\n"
     << "divvox (world_step, settled with damping) against CalculiX on the same geometry, anchors, gravity and "
        "material (C3D8I hexahedra; NLGEOM + Neo-Hookean where the case bends far). Error: "
     << r.value("error", std::string()) << ". Shipped solver: sim " << shipped.value("sim_resolution", 0) << ", "
     << shipped.value("substeps", 0) << " x " << shipped.value("iterations", 0) << ". Command: `divvox bench elastic`.\n\n"
     << "| case | reference | elements | ccx s |\n|---|---|---|---|\n";
  for (const json& c : r["references"]) {
    md << "| " << c["case"].get<std::string>() << " | " << (c.value("nlgeom", false) ? "NLGEOM Neo-Hookean" : "linear")
       << ", E " << num(get(c, "youngs_modulus")) << " Pa, nu " << num(get(c, "poisson_ratio")) << " | "
       << c["elements"] << " | " << (c.value("ok", false) ? num(get(c, "seconds")) : "failed: " + c.value("error", std::string()))
       << " |\n";
  }
  md << "\n| case | model | sim | substeps × iterations | step p50 ms | p99 ms | RMS error | max-disp. error | tip dy mm (ref) |\n"
        "|---|---|---|---|---|---|---|---|---|\n";
  for (const json& row : r["rows"]) {
    if (row.value("kind", std::string()) != "defaults") continue;
    md << "| " << row["case"].get<std::string>() << " | " << row["model"].get<std::string>() << " | "
       << row["sim_resolution"] << " | " << row["substeps"] << " × " << row["iterations"] << " | "
       << num(get(row, "step_p50_ms")) << " | " << num(get(row, "step_p99_ms")) << " | " << pct(get(row, "rms_error"))
       << " | " << pct(get(row, "max_error")) << " | " << num(1e3 * get(row, "tip_dy_m")) << " ("
       << num(1e3 * get(row, "ref_tip_dy_m")) << ") |\n";
  }
  md << "\nPareto-optimal settings of the sweep (no other setting of the same case and model is both faster and "
        "more accurate), the chosen one (cheapest within 10 % RMS) marked:\n\n"
        "| case | model | setting | step p50 ms | RMS error |\n|---|---|---|---|---|\n";
  std::vector<std::string> names;
  for (const json& row : r["rows"]) {
    if (row.value("kind", std::string()) == "sweep" && std::find(names.begin(), names.end(), row["case"].get<std::string>()) == names.end()) {
      names.push_back(row["case"]);
    }
  }
  for (const std::string& name : names) {
    for (const char* model : {"neo_hookean", "paper"}) {
      const ElasticPick pick = elastic_pick(r, name, model);
      std::vector<const json*> rows;
      for (const json& row : r["rows"]) {
        if (row["case"] == name && row["model"] == model && get(row, "rms_error", -1.0) >= 0.0) rows.push_back(&row);
      }
      std::sort(rows.begin(), rows.end(), [](const json* a, const json* b) { return get(*a, "step_p50_ms") < get(*b, "step_p50_ms"); });
      double best = 1e300;
      for (const json* row : rows) {
        if (get(*row, "rms_error") >= best) continue;
        best = get(*row, "rms_error");
        md << "| " << name << " | " << model << " | " << elastic_setting(*row) << (row == pick.chosen ? " **(chosen)**" : "")
           << " | " << num(get(*row, "step_p50_ms")) << " | " << pct(get(*row, "rms_error")) << " |\n";
      }
      if (!pick.chosen && !rows.empty()) {
        md << "| " << name << " | " << model << " | no setting within 10 % RMS | | |\n";
      }
      if (pick.shipped) {
        head << "- Elasticity (" << name << ", " << model << ", shipped solver): " << pct(get(*pick.shipped, "rms_error"))
             << " RMS error to CalculiX at " << num(get(*pick.shipped, "step_p50_ms")) << " ms per step\n";
      }
    }
  }
  md << "\n" << in.plot("bench_elastic.svg", elastic_plot(r), "elasticity speed against error") << "\n";
  if (r.contains("frequency") && !r["frequency"].empty()) {
    md << "First natural frequency of the cantilever (damping off, tip oscillation) against Euler-Bernoulli "
          "(1.875²/2π)·√(EI/ρAL⁴):\n\n| model | sim | measured Hz | analytic Hz |\n|---|---|---|---|\n";
    for (const json& f : r["frequency"]) {
      md << "| " << f["model"].get<std::string>() << " | " << f["sim_resolution"] << " | " << num(get(f, "measured_hz"))
         << " | " << num(get(f, "analytic_hz")) << " |\n";
    }
    md << "\n";
  }
}

// Section 4 (paper Fig. 13): cut-surface angles against CGAL clip (when tools/peers ran), histograms.
void quality_section(Results& in, std::ostream& md, std::ostream& head) {
  const json& quality = in.read("bench_quality.json");
  const json& clip = in.read("peers_clip.json");
  if (quality.is_null()) return;
  md << "## 4. Cut-surface mesh quality (paper Fig. 13)\n\n"
     << quality["mesh"].get<std::string>() << ", cut through by the plane y = "
     << num(quality["plane"]["point"][1].get<double>(), 5) << " (normal +y). divvox: the triangles on the cut faces "
        "after the through-cut; CGAL: `Polygon_mesh_processing::clip` of the input mesh by the same plane, both "
        "sides, with the cap closed (`clip_volume`); its cut surface is the cap plus the input triangles the plane "
        "split.\n\n| method | triangles | min angle | mean min angle | θmin ≤ 10° | θmax ≥ 160° | time ms |\n"
        "|---|---|---|---|---|---|---|\n";
  auto row = [&](const std::string& name, const json& a, const std::string& time) {
    md << "| " << name << " | " << a["triangles"] << " | " << num(get(a, "min_angle_deg")) << "° | "
       << num(get(a, "mean_min_angle_deg")) << "° | " << pct(get(a, "fraction_min_le_10")) << " | "
       << pct(get(a, "fraction_max_ge_160")) << " | " << time << " |\n";
  };
  Plot min_plot, max_plot;
  for (Plot* p : {&min_plot, &max_plot}) {
    const bool min = p == &min_plot;
    p->title = std::string("Cut surface quality: the ") + (min ? "smallest" : "largest") + " angle of each triangle";
    p->subtitle = measured_on(quality, quality["mesh"].get<std::string>() + " cut by a plane; 5-degree bins");
    p->x_label = std::string(min ? "smallest" : "largest") + " angle (degrees)";
    p->y_label = "fraction of the cut triangles";
    p->x_lo = min ? 0.0 : 60.0;  // a triangle's smallest angle is at most 60°, its largest at least 60°
    p->x_hi = min ? 60.0 : 180.0;
  }
  for (const json& r : quality["rows"]) {
    const json& a = r["angles"]["cut_surface"];
    const std::string name = "divvox " + std::to_string(r["resolution"].get<int>());
    row(name, a, num(get(r, "one_step_ms")) + " (one step), " + num(get(r, "progressive_ms")) + " (" +
                     std::to_string(quality["steps"].get<int>()) + " steps)");
    min_plot.series.push_back(histogram_series(name, a, "min_angle_histogram"));
    max_plot.series.push_back(histogram_series(name, a, "max_angle_histogram"));
  }
  if (!clip.is_null() && clip.value("status", "") == "ok") {
    const json& a = clip["angles"];
    row("CGAL clip: cap + split", a["cut_surface"], num(get(clip, "clip_both_ms")) + " (both sides)");
    row("CGAL clip: cap only", a["cap"], "");
    min_plot.series.push_back(histogram_series("CGAL clip", a["cut_surface"], "min_angle_histogram"));
    max_plot.series.push_back(histogram_series("CGAL clip", a["cut_surface"], "max_angle_histogram"));
    // The headline compares CGAL with divvox at the finest resolution measured.
    const json& finest = quality["rows"].back();
    const json& ours = finest["angles"]["cut_surface"];
    head << "- **Cut-surface quality against CGAL clip** (" << quality["mesh"].get<std::string>() << "): "
         << pct(get(ours, "fraction_min_le_10")) << " of divvox's cut triangles have θmin ≤ 10° (at "
         << finest["resolution"] << ") against " << pct(get(a["cut_surface"], "fraction_min_le_10"))
         << " for CGAL; the one-step cut takes " << num(get(finest, "one_step_ms")) << " ms against CGAL's "
         << num(get(clip, "clip_both_ms")) << " ms (" << num(get(clip, "clip_both_ms") / get(finest, "one_step_ms"))
         << "× faster), and divvox's cut is progressive and keeps the simulation's voxels.\n";
  } else {
    md << "| CGAL clip | not measured (build with -DDIVVOX_BENCH_PEERS=ON) | | | | | |\n";
  }
  row("input mesh (all triangles)", quality["input_angles"], "");
  md << "\n" << in.plot("report_quality_min_angle.svg", min_plot)
     << in.plot("report_quality_max_angle.svg", max_plot) << "\n";
}

// Section 5: static surface extraction against OpenVDB (when tools/peers ran).
void vdb_section(Results& in, std::ostream& md, std::ostream& head) {
  const json& vdb = in.read("peers_vdb.json");
  const json& voxelize = in.read("bench_voxelize.json");
  if (vdb.is_null() || vdb.value("status", "") != "ok" || voxelize.is_null()) return;
  md << "## 5. Static surface extraction against OpenVDB\n\n"
     << "Same mesh, same voxel size. divvox: exact ray-parity voxelization + dual contouring (1 thread); OpenVDB "
     << vdb.value("openvdb_version", std::string()) << ": `meshToLevelSet` (half width 3) + `volumeToMesh` "
     << "(adaptivity 0), " << vdb.value("threads", 0) << " thread(s). Error in voxels (two-sided, mean / max).\n\n"
     << "| res | divvox ms | OpenVDB ms | time ratio (OpenVDB / divvox) | divvox error | OpenVDB error | divvox "
        "triangles | OpenVDB triangles |\n|---|---|---|---|---|---|---|---|\n";
  const std::string mesh = vdb.value("mesh", std::string());
  for (const json& v : vdb["rows"]) {
    for (const json& d : voxelize["rows"]) {
      if (d["mesh"] != mesh || d["resolution"] != v["resolution"] || d["status"] != "ok") continue;
      const double ours = get(d["time_ms"], "voxelize") + get(d["time_ms"], "contour");
      md << "| " << v["resolution"] << " | " << num(ours) << " | " << num(get(v, "total_ms")) << " | "
         << num(get(v, "total_ms") / ours) << " | " << num(get(d["error_voxels"], "mean")) << " / "
         << num(get(d["error_voxels"], "max")) << " | " << num(get(v["error"], "mean")) << " / "
         << num(get(v["error"], "max")) << " | " << d["surface_triangles"] << " | " << v["output_triangles"] << " |\n";
      if (v["resolution"] == 256) {
        head << "- **Against OpenVDB** (" << mesh << " at 256): voxelize + contour " << num(ours) << " ms against "
             << num(get(v, "total_ms")) << " ms for meshToLevelSet + volumeToMesh (" << num(get(v, "total_ms") / ours)
             << "×), mean error " << num(get(d["error_voxels"], "mean")) << " against "
             << num(get(v["error"], "mean")) << " voxel.\n";
      }
    }
  }
  md << "\n";
}

// Bullet's soft body on the same PBD model (tools/peers bullet, when it ran): time per step at equal
// iterations, single-threaded, and the sag of each against a converged reference (issue 17).
void bullet_section(Results& in, std::ostream& md, std::ostream& head) {
  const json& b = in.read("peers_bullet.json");
  if (b.is_null() || b.value("status", "") != "ok" || !b.contains("rows") || b["rows"].empty()) return;
  md << "## Deformation against Bullet's soft body\n\n"
     << "`divvox_peers bullet`: the bunny scene's PBD model (" << b.value("particles", 0) << " particles, "
     << b.value("pieces", 0) << " shape-matching pieces, " << b.value("stretch_constraints", 0)
     << " stretch constraints) given to Bullet " << b.value("bullet_version", 0) / 100 << "."
     << b.value("bullet_version", 0) % 100 << "'s `btSoftBody`: the same particles, masses and anchors, a link per stretch constraint plus bending "
        "links for shear, the same iterations, dt, damping and gravity, one substep, no contact; both from rest, "
        "single-threaded, "
     << b.value("time", std::string("time per step")) << " (p50). divvox's PBD time excludes its surface embedding "
        "(timed apart). Sag: mean drop of the free particles; reference: divvox at "
     << b.value("reference_iterations", 0) << " iterations.\n\n"
     << "| iterations | divvox PBD ms | divvox embedding ms | Bullet ms | Bullet / divvox | divvox sag | Bullet sag | "
        "divvox RMS to ref. | Bullet RMS to ref. |\n|---|---|---|---|---|---|---|---|---|\n";
  double worst = 1e30;
  for (const json& r : b["rows"]) {
    const double speedup = get(r, "speedup_pbd");
    worst = std::min(worst, speedup);
    md << "| " << r["iterations"] << " | " << num(get(r, "divvox_pbd_ms_p50")) << " | "
       << num(get(r, "divvox_embed_ms_p50")) << " | " << num(get(r, "bullet_step_ms_p50")) << " | " << num(speedup)
       << "× | " << num(get(r, "divvox_sag")) << " | " << num(get(r, "bullet_sag")) << " | "
       << num(get(r, "divvox_rms_to_reference")) << " | " << num(get(r, "bullet_rms_to_reference")) << " |\n";
  }
  md << "\nReference sag " << num(get(b["rows"][0], "reference_sag"))
     << ". Goal (issue 17): divvox at least 2× faster per step at equal iterations; Bullet's bending links are "
        "stiffer per iteration than one shape-matching pass, so at equal iterations it sags less.\n\n";
  head << "- **Against Bullet's soft body** (same particles and links, equal iterations, one thread): divvox's PBD "
          "step is at least "
       << num(worst) << "× faster.\n";
}

// Section 6: determinism and throughput of headless replay (and the replay's timings plot).
void replay_section(Results& in, std::ostream& md, std::ostream& head) {
  const json& replay = in.read("bench_replay.json");
  if (replay.is_null()) return;
  md << "## 6. Determinism and throughput of headless replay\n\n"
     << "Each shipped recording replayed with physics (no frames) several times with 1 and with 2 workers. "
        "Deterministic: every run's final state hash agrees and every hash recorded in the file matched.\n\n"
     << "Deform: the PBD step's time (p50 and p99 of each run, medians over the runs); barriers: the task "
        "pool's stages per step (a barrier between two), waits: those a thread reached before they opened, per "
        "step and thread (summary.json `pool`).\n\n"
     << "| recording | workers | runs | steps | wall s (median) | × real time (median) | step p99 ms | "
        "deform p50 ms | deform p99 ms | barriers / step | waits / step | deterministic |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const json& r : replay["rows"]) {
    std::map<int, std::vector<const json*>> by_workers;
    for (const json& run : r["runs"]) by_workers[run["workers"].get<int>()].push_back(&run);
    for (auto& [workers, runs] : by_workers) {
      std::vector<double> wall, factor, p99, deform50, deform99, stages, waits;
      for (const json* run : runs) {
        wall.push_back(get(*run, "wall_s"));
        factor.push_back(get(*run, "realtime_factor"));
        p99.push_back(get((*run)["step_ms"], "p99"));
        if (run->contains("deform_ms")) {
          deform50.push_back(get((*run)["deform_ms"], "p50"));
          deform99.push_back(get((*run)["deform_ms"], "p99"));
          stages.push_back(get(*run, "pool_stages_per_step"));
          waits.push_back(get(*run, "pool_waits_per_step") / std::max(1, workers));
        }
      }
      const auto median = [](const std::vector<double>& v) { return v.empty() ? std::string("–") : num(quantile(v, 0.5)); };
      md << "| " << r["recording"].get<std::string>() << " | " << workers << " | " << runs.size() << " | "
         << (*runs[0])["steps"] << " | " << num(quantile(wall, 0.5)) << " | " << num(quantile(factor, 0.5))
         << " | " << num(quantile(p99, 0.5)) << " | " << median(deform50) << " | " << median(deform99) << " | "
         << median(stages) << " | " << median(waits) << " | " << (r["deterministic"].get<bool>() ? "yes" : "**no**")
         << " |\n";
      if (r["recording"] == "bunny_cut.jsonl") {
        head << "- **Replay** of the default recording with " << workers << (workers == 1 ? " worker: " : " workers: ")
             << num(quantile(factor, 0.5)) << "× real time with physics (deform p50 " << median(deform50) << " ms), "
             << (replay["deterministic"].get<bool>() ? "bit-identical" : "NOT identical")
             << " across runs and worker counts.\n";
      }
    }
  }
  md << "\n";
  if (fs::exists(in.dir / "replay_timings.svg")) {
    md << "The default recording replayed as `tools/run.sh` does (frames every 10 steps on the render thread where "
          "EGL works), "
          "its `timings.svg`:\n\n![replay timings](" << in.link << "/replay_timings.svg)\n\n";
  }
}

// Cutting alone (no physics): the step-time targets.
void cut_section(Results& in, std::ostream& md, std::ostream&) {
  const json& cut = in.read("bench_cut.json");
  if (cut.is_null()) return;
  md << "## Cutting alone (no physics)\n\n" << cut["mesh"].get<std::string>() << ", " << cut["steps"]
     << " blade poses, median of " << cut["repeats"] << " repeats per step.\n\n"
     << "| res | occupied voxels | step p50 ms | step p99 ms | µs per cut voxel | µs per newly divided voxel | "
        "explicit B per divided voxel |\n|---|---|---|---|---|---|---|\n";
  for (const json& r : cut["rows"]) {
    md << "| " << r["resolution"] << " | " << r["occupied_voxels"] << " | " << num(get(r["step_ms"], "p50")) << " | "
       << num(get(r["step_ms"], "p99")) << " | " << num(get(r, "us_per_cut_voxel")) << " | "
       << num(get(r, "us_per_newly_divided_voxel")) << " | " << num(get(r, "bytes_per_divided_voxel")) << " |\n";
  }
  md << "\n";
}

// The report's sections in order. Each reads its own results (Results::read) and writes nothing when
// they are absent; a new benchmark's section is one function above and one line here.
using Section = void (*)(Results& in, std::ostream& md, std::ostream& head);

// Contact cost (bench/bench_contact.cpp).
void contact_section(Results& in, std::ostream& md, std::ostream& head) { report_contact(in.read("bench_contact.json"), md, head); }
constexpr Section report_sections[] = {
    scaling_section,      // 1. bench_scaling.json
    cut_length_section,   // 2. bench_cut_length.json
    speed_error_heading,  // 3. heading of surface + physics
    surface_section,      //    bench_voxelize.json (+ peers_vdb.json)
    deform_section,       //    bench_deform.json
    elastic_section,      //    bench_elastic.json
    quality_section,      // 4. bench_quality.json (+ peers_clip.json)
    vdb_section,          // 5. peers_vdb.json + bench_voxelize.json
    replay_section,       // 6. bench_replay.json
    cut_section,          //    bench_cut.json
    contact_section,      //    bench_contact.json
    bullet_section,       //    peers_bullet.json
};

}  // namespace

std::string draw_bench_plot(const json& results, const std::string& dir, std::string& error) {
  const std::string benchmark = results.value("benchmark", std::string());
  if (benchmark == "cut_length") return draw_into(dir, "bench_cut_length.svg", cut_length_plot(results), error);
  if (benchmark == "deform") return draw_into(dir, "bench_deform.svg", deform_plot(results), error);
  if (benchmark == "elastic") return draw_into(dir, "bench_elastic.svg", elastic_plot(results), error);
  error = "no plot for benchmark \"" + benchmark + "\"";
  return "";
}

std::string bench_report(const BenchReportOptions& options) {
  const fs::path report(options.report_path);
  Results in;
  in.dir = options.results_dir;
  if (!fs::is_directory(in.dir)) throw_input(in.dir.string(), "no such results folder (run the benchmarks first)");
  const fs::path report_dir = report.parent_path().empty() ? fs::path(".") : report.parent_path();
  make_output_dir(report_dir.string());
  in.link = fs::relative(fs::absolute(in.dir), fs::absolute(report_dir)).generic_string();

  std::ostringstream md, head;
  for (Section section : report_sections) section(in, md, head);

  const std::time_t now = std::time(nullptr);
  char date[32];
  std::strftime(date, sizeof date, "%Y-%m-%d %H:%M", std::localtime(&now));
  const json& scaling = in.read("bench_scaling.json");
  std::ostringstream doc;
  doc << "# divvox benchmark report\n\n"
      << "Generated " << date << " by `tools/bench_report.sh" << (options.mode == "quick" ? " --quick" : "")
      << "` (" << options.mode << " mode) on: " << machine_of(scaling.is_object() ? scaling : in.read("bench_voxelize.json"))
      << ". All figures in one table come from one run on this machine; compare ratios, not absolute times"
      << (fs::exists(in.dir / "MACHINE.md") ? " (see [MACHINE.md](" + in.link + "/MACHINE.md))" : std::string())
      << ". The CSV and JSON files beside the plots in `" << in.link << "/` hold every number.\n\n## Headline\n\n"
      << (head.str().empty() ? "- (no results found)\n" : head.str()) << "\n"
      << md.str();
  write_text_file(report.string(), doc.str());
  return report.string();
}

}  // namespace dvx
