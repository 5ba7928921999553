// The figures drawn from a benchmark's JSON results: by the benchmark when it runs
// (draw_bench_plot) and again by `divvox bench report`.
#include "bench/bench.h"
#include "bench/report_common.h"

#include <algorithm>
#include <cstdio>
#include <map>

namespace dvx {
namespace report {

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
    PlotSeries shipped = chosen_series("shipped solver"), chosen = chosen_series("chosen (cheapest converged within 10 %)");
    chosen.point_type = 4;
    for (const char* model : {"neo_hookean", "global", "paper"}) {
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

}  // namespace report

std::string draw_bench_plot(const nlohmann::json& results, const std::string& dir, std::string& error) {
  const std::string benchmark = results.value("benchmark", std::string());
  if (benchmark == "cut_length") return report::draw_into(dir, "bench_cut_length.svg", report::cut_length_plot(results), error);
  if (benchmark == "deform") return report::draw_into(dir, "bench_deform.svg", report::deform_plot(results), error);
  if (benchmark == "elastic") return report::draw_into(dir, "bench_elastic.svg", report::elastic_plot(results), error);
  error = "no plot for benchmark \"" + benchmark + "\"";
  return "";
}

}  // namespace dvx
