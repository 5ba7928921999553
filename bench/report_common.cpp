// The report's shared pieces: reading results, formatting numbers, plot helpers.
#include "bench/report_common.h"

#include "engine/errors.h"
#include "engine/scene.h"

#include <algorithm>
#include <cstdio>
#include <fstream>

namespace dvx::report {

// A number with `digits` significant digits (ms, ratios, errors).
std::string num(double v, int digits) {
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

double get(const json& j, const char* key, double fallback) {
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

// bench elastic: per swept case, step time against the error to CalculiX, by model and simulation
// resolution; the Pareto front, the shipped solver and the chosen setting marked. Chosen: the cheapest
// row within 10 % RMS that is converged in the solver: the sweep's row with the same resolution and
// substeps and the fewest iterations at least twice its own moves the largest displacement by at most
// 1 % (issue 30). A budget too small to converge can land near the reference by luck (its softness
// cancelling the hexahedra's stiffness: the liver at 1 x 5 read 9.1 %, 1 x 10 10.7 %); a row with no
// such twin in the sweep is not chosen.
const json* doubled_twin(const std::vector<const json*>& rows, const json& row) {
  const json* twin = nullptr;
  for (const json* o : rows) {
    if ((*o)["sim_resolution"] != row["sim_resolution"] || (*o)["substeps"] != row["substeps"]) continue;
    const int it = (*o)["iterations"].get<int>();
    if (it < 2 * row["iterations"].get<int>()) continue;
    if (!twin || it < (*twin)["iterations"].get<int>()) twin = o;
  }
  return twin;
}

bool converged_in_solver(const std::vector<const json*>& rows, const json& row) {
  const json* twin = doubled_twin(rows, row);
  const double d = get(row, "max_displacement_m");
  return twin && d > 0.0 && std::abs(get(*twin, "max_displacement_m") / d - 1.0) <= 0.01;
}

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
    if (get(*row, "rms_error") > 0.1 || !converged_in_solver(rows, *row)) continue;
    if (!pick.chosen || get(*row, "step_p50_ms") < get(*pick.chosen, "step_p50_ms")) pick.chosen = row;
  }
  return pick;
}

std::string elastic_setting(const json& row) {
  return "sim " + std::to_string(row["sim_resolution"].get<int>()) + ", " + std::to_string(row["substeps"].get<int>()) +
         "x" + std::to_string(row["iterations"].get<int>());
}

const json& Results::read(const std::string& name) {
  auto it = files.find(name);
  if (it == files.end()) it = files.emplace(name, read_results(dir, name)).first;
  return it->second;
}

std::string Results::plot(const std::string& name, const Plot& plot, const std::string& title) const {
  std::string error;
  return image_line(title.empty() ? plot.title : title, link, draw_into(dir, name, plot, error), error);
}

}  // namespace dvx::report
