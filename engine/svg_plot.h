// Minimal SVG line/scatter plots for benchmark and timing outputs (no plotting library ships for
// C++ in Debian; these plots only need axes, ticks, polylines, markers and a legend).
#pragma once

#include <string>
#include <vector>

namespace dvx {

struct PlotSeries {
  std::string name;
  std::vector<double> x, y;
  bool markers = true;  // draw points
  bool lines = true;    // join points in order
};

struct Plot {
  std::string title, x_label, y_label;
  bool log_x = false, log_y = false;
  std::vector<PlotSeries> series;
};

// The plot as an SVG document (800 x 500).
std::string plot_svg(const Plot& plot);

}  // namespace dvx
