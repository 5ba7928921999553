// The pieces `divvox bench report` is made of (bench/bench_report.cpp assembles them): reading the
// results, number formatting, plot helpers, the figures drawn from a benchmark's JSON
// (bench/report_figures.cpp) and the sections of REPORT.md (the speed-against-error ones in
// bench/report_speed_error.cpp). Internal to bench/: nothing outside it includes this file.
#pragma once

#include "harness/plot.h"
#include "sim/pbd.h"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <map>
#include <ostream>
#include <string>
#include <vector>

namespace dvx::report {

namespace fs = std::filesystem;
using nlohmann::json;

// A number with `digits` significant digits (ms, ratios, errors).
std::string num(double v, int digits = 3);
std::string pct(double fraction);
std::string mib(double bytes);

// The solver settings the shipped scenes use (assets/scenes/bunny.json, the headless default; the
// window's liver uses the same), against which the speed-against-error front is read; the built-in
// defaults of a scene without a `solver` block when that file is not there.
PbdParams shipped_solver();

// A results file as JSON, or null when it does not exist.
json read_results(const fs::path& dir, const std::string& name);
// A number of `j` by key (`fallback` when it is not there or not a number).
double get(const json& j, const char* key, double fallback = 0.0);

// The machine the results were measured on (they record it), else this one (older results).
std::string machine_of(const json& results);
// The plot's second title line: what ran, on which machine.
std::string measured_on(const json& results, const std::string& what);

// Draws a plot beside the CSVs (SVG, and PNG for pages that embed it). Returns the SVG's file name, or
// "" with `error` when gnuplot did not draw it.
std::string draw_into(const fs::path& dir, const std::string& name, const Plot& plot, std::string& error);
// The Markdown image line of a drawn plot (or why it is missing).
std::string image_line(const std::string& title, const std::string& link_dir, const std::string& name,
                       const std::string& error);

// A plot with both axes logarithmic.
Plot log_log_plot(const std::string& title, const std::string& subtitle, const std::string& x_label,
                  const std::string& y_label);
PlotSeries series(const std::string& name, bool markers, bool lines);
// The Pareto front of the points (smaller is better on both axes) as a wide grey band under them.
PlotSeries front_series(const std::string& name, const std::vector<double>& x, const std::vector<double>& y);
// Chosen settings (the defaults) as large open circles.
PlotSeries chosen_series(const std::string& name);
// The histogram of an angle_stats_json value as a plot series (fraction of triangles per 5-degree bin).
PlotSeries histogram_series(const std::string& name, const json& stats, const char* key);

// bench elastic: per swept case and model, the shipped solver's row and the chosen setting (the
// cheapest on the front within 10 % RMS); pointers into the results.
struct ElasticPick {
  const json* shipped = nullptr;  // the shipped solver at the shipped simulation resolution
  const json* chosen = nullptr;   // the cheapest row within 10 % RMS error converged in the solver
};
ElasticPick elastic_pick(const json& r, const std::string& name, const std::string& model);
// "sim N, SxI" of a bench elastic row.
std::string elastic_setting(const json& row);

// The figures drawn from a benchmark's results (bench/report_figures.cpp): the benchmark draws them
// when it runs (draw_bench_plot), the report redraws them from the JSON.
Plot cut_length_plot(const json& r);  // Experiment 2: time against cut voxels, samples and fits
Plot deform_plot(const json& r);      // PBD step time against error, by simulation resolution
Plot elastic_plot(const json& r);     // step time against the error to CalculiX

// The results a report reads: each file read once, on first use (null when it does not exist), and
// where its plots go. One per report run; the sections share it.
struct Results {
  fs::path dir;      // the results folder (plots are drawn into it)
  std::string link;  // the results folder relative to the report (for links and images)
  std::map<std::string, json> files;

  const json& read(const std::string& name);
  // Draws `plot` into the results folder and returns its Markdown image line (`title`: the image's
  // name in the text, default the plot's title).
  std::string plot(const std::string& name, const Plot& plot, const std::string& title = "") const;
};

// Section 3, speed against error (bench/report_speed_error.cpp): its heading, the surface, the
// physics (bench deform) and the elasticity against CalculiX (bench elastic). Each writes nothing
// when its results are absent; headline lines go to `head`.
void speed_error_heading(Results& in, std::ostream& md, std::ostream& head);
void surface_section(Results& in, std::ostream& md, std::ostream& head);
void deform_section(Results& in, std::ostream& md, std::ostream& head);
void elastic_section(Results& in, std::ostream& md, std::ostream& head);

}  // namespace dvx::report
