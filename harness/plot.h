// Plots of timings and benchmark results, drawn by gnuplot (Debian gnuplot-nox) through a pipe: the
// caller fills plain structs, this module writes a gnuplot script with the data inline and runs it.
// gnuplot does the layout (ticks, legends, fonts); this module chooses log-axis ticks (1-2-5 steps,
// readable labels such as 20k, 1M, 0.05), the legend's corner and the panels' margins.
#pragma once

#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

namespace dvx {

// One curve or point set.
struct PlotSeries {
  std::string name;  // the legend entry ("" : no entry)
  std::vector<double> x, y;  // a y that is NaN (or not positive on a log axis) breaks the line there
  bool markers = true;  // draw points
  bool lines = true;    // join points in order
  std::string colour;   // "#rrggbb"; "" : the next colour of the palette
  double width = 1.5;   // line width
  int point_type = 7;   // gnuplot point type (7 filled circle, 6 open circle, 5 filled square, ...)
  double point_size = 0.6;
  std::vector<std::string> point_labels;  // when not empty: a small label beside each point (e.g. its setting)
};

// A horizontal reference line across the panel, labelled at one end (a budget, a percentile).
struct PlotLine {
  double y = 0.0;
  std::string label;
  std::string colour = "#555555";
  int dash = 2;             // gnuplot dash type: 1 solid, 2 dashed, 3 dotted, 4 dash-dot
  bool label_left = false;  // the label at the left end (default: right)
  bool label_below = false; // the label under the line (default: above)
};

// A shaded range of x (in every panel), e.g. the steps that cut.
struct PlotSpan {
  double x0 = 0.0, x1 = 0.0;
};

// One panel of a stacked plot: its own y axis, series and reference lines.
struct PlotPanel {
  std::string y_label;
  bool log_y = false;
  std::vector<PlotSeries> series;
  std::vector<PlotLine> lines;
};

struct Plot {
  std::string title, x_label, y_label;
  bool log_x = false, log_y = false;
  std::vector<PlotSeries> series;   // a single-panel plot: these, y_label, log_y and `lines`
  std::vector<PlotLine> lines;
  std::vector<PlotPanel> panels;    // when not empty: stacked panels sharing the x axis (the above ignored)
  std::string subtitle;             // second title line (what ran, on which machine)
  std::vector<PlotSpan> spans;
  std::string span_name;            // legend entry of the shaded spans (first panel)
  bool same_y = false;              // every panel gets the same y range
  double x_lo = NAN, x_hi = NAN;    // a fixed x range (default: the data's)
  int width = 900, height = 0;      // pixels; height 0: 500, or 200 per panel + title and axis
  // PNG pixels per SVG pixel (fonts and lines scaled with them): 1.5 is crisper where the PNG is shown
  // scaled down (the report), 1 draws in about half the time (the replay's timings plot, which the
  // replay waits for: ~95 against ~175 ms for the default recording's).
  double png_scale = 1.5;
};

// Draws `plot` with gnuplot into each output file (.svg or .png, by extension). gnuplot is the
// executable named by $DIVVOX_GNUPLOT, else `gnuplot` on PATH. False with `error` (one line) when it is
// missing or fails; the outputs are then removed, never left stale. Never throws for a missing tool.
bool draw_plot(const Plot& plot, const std::vector<std::string>& outputs, std::string& error);

// A gnuplot child started ahead of its plot: while the caller works (a replay's steps), it starts up
// and draws a throwaway PNG (loading its cairo terminal and fonts, most of a small plot's time);
// then it is sent the plot and drawn in the background while the caller writes its other outputs,
// and finally waited for. The same files and messages as draw_plot. Ends (and reaps) the child when
// destroyed unfinished.
class PlotProcess {
 public:
  PlotProcess() = default;
  PlotProcess(const PlotProcess&) = delete;
  PlotProcess& operator=(const PlotProcess&) = delete;
  ~PlotProcess();
  // Starts gnuplot (as draw_plot finds it). False with `error` when it cannot: then finish() reports it.
  bool start(std::string& error);
  // Sends `plot` for `outputs` (the outputs are removed first, as draw_plot does).
  void send(const Plot& plot, const std::vector<std::string>& outputs);
  // Waits for gnuplot: true when every output of send() was written, else false with `error` (one
  // line; the outputs are removed).
  bool finish(std::string& error);

 private:
  FILE* pipe_ = nullptr;
  std::string exe_, messages_, error_;
  std::vector<std::string> outputs_;
};

// The gnuplot draw_plot would run ("" with `error` when there is none).
std::string find_gnuplot(std::string& error);

// The gnuplot script draw_plot runs (data inline).
std::string plot_script(const Plot& plot, const std::vector<std::string>& outputs);

// A readable label of a log-axis tick value: 20k, 1.5M, 0.05, 2×10⁻⁵.
std::string tick_label(double value);

// One line describing this machine (CPU, cores, memory, kernel), for plot subtitles and reports.
std::string machine_summary();

// Indices of the points no other point beats in both x and y (smaller is better), sorted by x.
std::vector<size_t> pareto_front(const std::vector<double>& x, const std::vector<double>& y);

}  // namespace dvx
