#include "engine/svg_plot.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

namespace dvx {
namespace {

constexpr double kWidth = 800, kHeight = 500, kLeft = 80, kRight = 200, kTop = 40, kBottom = 60;
const char* kColours[] = {"#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf"};

std::string number(double v) {
  char text[32];
  std::snprintf(text, sizeof text, "%.3g", v);
  return text;
}

// Escapes text for XML.
std::string xml(const std::string& s) {
  std::string out;
  for (char c : s) {
    if (c == '<') out += "&lt;";
    else if (c == '>') out += "&gt;";
    else if (c == '&') out += "&amp;";
    else out += c;
  }
  return out;
}

}  // namespace

std::string plot_svg(const Plot& plot) {
  // Data range (log axes use positive values only).
  const auto tx = [&](double v) { return plot.log_x ? std::log10(v) : v; };
  const auto ty = [&](double v) { return plot.log_y ? std::log10(v) : v; };
  const auto usable = [&](double x, double y) {
    return std::isfinite(x) && std::isfinite(y) && (!plot.log_x || x > 0) && (!plot.log_y || y > 0);
  };
  double x0 = std::numeric_limits<double>::infinity(), x1 = -x0, y0 = x0, y1 = -x0;
  for (const PlotSeries& s : plot.series) {
    for (size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
      if (!usable(s.x[i], s.y[i])) continue;
      x0 = std::min(x0, tx(s.x[i]));
      x1 = std::max(x1, tx(s.x[i]));
      y0 = std::min(y0, ty(s.y[i]));
      y1 = std::max(y1, ty(s.y[i]));
    }
  }
  if (!(x0 <= x1)) x0 = 0, x1 = 1;
  if (!(y0 <= y1)) y0 = 0, y1 = 1;
  if (x1 - x0 < 1e-12) x0 -= 0.5, x1 += 0.5;
  if (y1 - y0 < 1e-12) y0 -= 0.5, y1 += 0.5;
  if (!plot.log_y && y0 > 0) y0 = 0;  // linear y axes start at zero
  const double pw = kWidth - kLeft - kRight, ph = kHeight - kTop - kBottom;
  const auto px = [&](double v) { return kLeft + (tx(v) - x0) / (x1 - x0) * pw; };
  const auto py = [&](double v) { return kTop + ph - (ty(v) - y0) / (y1 - y0) * ph; };

  std::ostringstream svg;
  svg << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << kWidth << "\" height=\"" << kHeight
      << "\" font-family=\"sans-serif\" font-size=\"12\">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  svg << "<text x=\"" << kWidth / 2 - 60 << "\" y=\"22\" font-size=\"15\">" << xml(plot.title) << "</text>\n";
  svg << "<rect x=\"" << kLeft << "\" y=\"" << kTop << "\" width=\"" << pw << "\" height=\"" << ph
      << "\" fill=\"none\" stroke=\"#444\"/>\n";
  // Ticks: 5 per axis (powers of ten on log axes).
  for (int i = 0; i <= 5; ++i) {
    const double fx = x0 + (x1 - x0) * i / 5, fy = y0 + (y1 - y0) * i / 5;
    const double vx = plot.log_x ? std::pow(10.0, fx) : fx, vy = plot.log_y ? std::pow(10.0, fy) : fy;
    const double sx = kLeft + pw * i / 5, sy = kTop + ph - ph * i / 5;
    svg << "<line x1=\"" << sx << "\" y1=\"" << kTop << "\" x2=\"" << sx << "\" y2=\"" << kTop + ph
        << "\" stroke=\"#eee\"/>\n<text x=\"" << sx - 12 << "\" y=\"" << kTop + ph + 16 << "\">" << number(vx)
        << "</text>\n";
    svg << "<line x1=\"" << kLeft << "\" y1=\"" << sy << "\" x2=\"" << kLeft + pw << "\" y2=\"" << sy
        << "\" stroke=\"#eee\"/>\n<text x=\"" << 8 << "\" y=\"" << sy + 4 << "\">" << number(vy) << "</text>\n";
  }
  svg << "<text x=\"" << kLeft + pw / 2 - 40 << "\" y=\"" << kHeight - 15 << "\">" << xml(plot.x_label)
      << (plot.log_x ? " (log)" : "") << "</text>\n";
  svg << "<text transform=\"translate(18," << kTop + ph / 2 + 40 << ") rotate(-90)\">" << xml(plot.y_label)
      << (plot.log_y ? " (log)" : "") << "</text>\n";
  // Series.
  for (size_t k = 0; k < plot.series.size(); ++k) {
    const PlotSeries& s = plot.series[k];
    const char* colour = kColours[k % 8];
    std::ostringstream points;
    for (size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
      if (!usable(s.x[i], s.y[i])) continue;
      points << px(s.x[i]) << ',' << py(s.y[i]) << ' ';
      if (s.markers) {
        svg << "<circle cx=\"" << px(s.x[i]) << "\" cy=\"" << py(s.y[i]) << "\" r=\"3\" fill=\"" << colour << "\"/>\n";
      }
    }
    if (s.lines) {
      svg << "<polyline fill=\"none\" stroke=\"" << colour << "\" stroke-width=\"1.5\" points=\"" << points.str()
          << "\"/>\n";
    }
    const double ly = kTop + 14 + 18.0 * double(k);
    svg << "<rect x=\"" << kWidth - kRight + 12 << "\" y=\"" << ly - 9 << "\" width=\"12\" height=\"12\" fill=\""
        << colour << "\"/>\n<text x=\"" << kWidth - kRight + 30 << "\" y=\"" << ly + 1 << "\">" << xml(s.name)
        << "</text>\n";
  }
  svg << "</svg>\n";
  return svg.str();
}

}  // namespace dvx
