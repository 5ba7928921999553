#include "harness/plot.h"
#include "engine/options.h"

#include <sys/utsname.h>
#include <csignal>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <numeric>
#include <sstream>

namespace dvx {
namespace {

namespace fs = std::filesystem;

const char* kPalette[] = {"#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf"};
constexpr double kFontPx = 11.0;  // the base font, in SVG pixels

// A value as gnuplot reads it back exactly enough.
std::string g(double v) {
  char text[40];
  std::snprintf(text, sizeof text, "%.9g", v);
  return text;
}

// A gnuplot single-quoted string (only the quote itself needs escaping).
std::string quoted(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("''") : std::string(1, c);
  return out + "'";
}

// A shell single-quoted word.
std::string shell_word(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

// One axis: its range, and (log axes) the ticks this module chose.
struct Axis {
  double lo = 0.0, hi = 1.0;
  bool log = false;
  std::vector<double> ticks;  // empty: gnuplot's own (linear axes: already 1-2-5 steps)
  double at(double v) const { return log ? (std::log10(v) - std::log10(lo)) / (std::log10(hi) - std::log10(lo)) : (v - lo) / (hi - lo); }
};

bool usable(double v, bool log) { return std::isfinite(v) && (!log || v > 0.0); }

// The axis over `values`: log axes snap outwards to 1-2-5 values and label the densest of 1-1.5-2-3-5-7,
// 1-2-5, powers of ten, every other power of ten whose labels stay `min_px` apart over `pixels`;
// linear axes start at zero when every value is non-negative and `from_zero` asks for it.
Axis make_axis(const std::vector<double>& values, bool log, bool from_zero, double pad_lo, double pad_hi, double pixels,
               double min_px) {
  Axis a;
  a.log = log;
  double lo = INFINITY, hi = -INFINITY;
  for (double v : values) {
    if (!usable(v, log)) continue;
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  }
  if (!(lo <= hi)) lo = log ? 1.0 : 0.0, hi = log ? 10.0 : 1.0;
  if (!log) {
    if (from_zero && lo >= 0.0) lo = 0.0, pad_lo = 0.0;
    if (hi - lo < 1e-12 * std::max(1.0, std::fabs(hi))) lo -= 0.5, hi += 0.5;
    a.lo = lo - pad_lo * (hi - lo);
    a.hi = hi + pad_hi * (hi - lo);
    return a;
  }
  if (hi / lo < 1.0001) lo /= 2.0, hi *= 2.0;
  const double span = std::log10(hi / lo);
  lo /= std::pow(10.0, pad_lo * span), hi *= std::pow(10.0, pad_hi * span);
  const auto values_of = [&](const std::vector<double>& mantissas, int every) {
    std::vector<double> out;
    for (int e = int(std::floor(std::log10(lo))) - 2; e <= int(std::ceil(std::log10(hi))) + 2; ++e) {
      if (e % every != 0) continue;
      for (double m : mantissas) out.push_back(m * std::pow(10.0, e));
    }
    return out;
  };
  const double eps = 1e-9;
  const bool narrow = std::log10(hi / lo) <= 1.0;
  const std::vector<double> fine = narrow ? std::vector<double>{1, 1.5, 2, 3, 5, 7} : std::vector<double>{1, 2, 5};
  const std::vector<double> snaps = values_of(fine, 1);
  a.lo = snaps.front(), a.hi = snaps.back();
  for (double c : snaps) {
    if (c <= lo * (1 + eps)) a.lo = c;
  }
  for (auto it = snaps.rbegin(); it != snaps.rend(); ++it) {
    if (*it >= hi * (1 - eps)) a.hi = *it;
  }
  // The labelled ticks: the densest set whose closest pair is at least min_px apart.
  const double px_per_decade = pixels / std::log10(a.hi / a.lo);
  const struct { std::vector<double> mantissas; int every; double gap; } sets[] = {
      {{1, 1.5, 2, 3, 5, 7}, 1, 0.125}, {{1, 2, 5}, 1, 0.301}, {{1}, 1, 1.0}, {{1}, 2, 2.0}, {{1}, 5, 5.0}};
  size_t pick = narrow ? 0 : 1;
  while (pick + 1 < std::size(sets) && sets[pick].gap * px_per_decade < min_px) ++pick;
  for (double c : values_of(sets[pick].mantissas, sets[pick].every)) {
    if (c >= a.lo * (1 - eps) && c <= a.hi * (1 + eps)) a.ticks.push_back(c);
  }
  return a;
}

// The axis commands: range, log scale, ticks (labels off on the panels above the bottom one).
std::string axis_commands(const char* name, const Axis& a, bool labels) {
  std::ostringstream s;
  // (Log ranges open a hair wider: gnuplot drops a tick that falls exactly on a range end such as 10.)
  const double widen = a.log ? 1e-6 : 0.0;
  s << "set " << name << "range [" << g(a.lo * (1 - widen)) << ":" << g(a.hi * (1 + widen)) << "]\n";
  if (a.log) {
    s << "set logscale " << name << "\nset " << name << "tics (";
    for (size_t i = 0; i < a.ticks.size(); ++i) {
      s << (i ? ", " : "") << quoted(labels ? tick_label(a.ticks[i]) : "") << " " << g(a.ticks[i]);
    }
    s << ")\n";
  } else {
    s << "unset logscale " << name << "\nset " << name << "tics\nset format " << name << " " << quoted(labels ? "%g" : "") << "\n";
  }
  return s.str();
}

// Where a panel's legend goes: the corner whose box (the key's estimated size, in the panel's [0,1]²)
// covers the fewest samples of the curves and of the reference lines' labels.
struct Key {
  std::string corner;
  size_t covered = 0;  // samples under the box there
  double height = 0;   // the box's height, as a fraction of the panel's
};

Key place_key(const PlotPanel& panel, const Axis& x, const Axis& y, double width_px, double height_px, int entries) {
  size_t longest = 0;
  for (const PlotSeries& s : panel.series) longest = std::max(longest, s.name.size());
  const double kw = std::min(0.9, (7.2 * double(longest) + 90.0) / width_px);
  const double kh = std::min(0.9, (1.4 * kFontPx * entries + 10.0) / height_px);
  std::vector<std::array<double, 2>> samples;
  for (const PlotSeries& s : panel.series) {
    std::array<double, 2> prev{NAN, NAN};
    for (size_t i = 0; i < s.x.size() && i < s.y.size(); ++i) {
      if (!usable(s.x[i], x.log) || !usable(s.y[i], y.log)) {
        prev = {NAN, NAN};
        continue;
      }
      const std::array<double, 2> p{x.at(s.x[i]), y.at(s.y[i])};
      const int parts = s.lines && std::isfinite(prev[0]) ? 12 : 1;
      for (int k = 1; k <= parts; ++k) {
        const double t = double(k) / parts;
        samples.push_back({prev[0] + t * (p[0] - prev[0]), prev[1] + t * (p[1] - prev[1])});
        if (parts == 1) samples.back() = p;
      }
      if (!s.point_labels.empty()) samples.push_back({p[0] + 0.03, p[1] + 0.04});
      prev = p;
    }
  }
  for (const PlotLine& l : panel.lines) {
    for (int k = 0; k <= 10; ++k) samples.push_back({(l.label_left ? 0.0 : 0.75) + 0.025 * k, y.at(l.y) + (l.label_below ? -0.04 : 0.04)});
  }
  const char* names[] = {"top right", "top left", "bottom right", "bottom left"};
  const double boxes[4][4] = {{1 - kw, 1, 1 - kh, 1}, {0, kw, 1 - kh, 1}, {1 - kw, 1, 0, kh}, {0, kw, 0, kh}};
  Key key{names[0], SIZE_MAX, kh};
  for (int c = 0; c < 4; ++c) {
    size_t count = 0;
    for (const auto& p : samples) {
      count += p[0] >= boxes[c][0] - 0.02 && p[0] <= boxes[c][1] + 0.02 && p[1] >= boxes[c][2] - 0.02 &&
               p[1] <= boxes[c][3] + 0.02;
    }
    if (count < key.covered) key.corner = names[c], key.covered = count;
  }
  return key;
}

// The y axis raised so that the data fill only the panel's lower (1 - fraction): room for the legend.
std::vector<double> with_headroom(std::vector<double> values, const Axis& y, double fraction) {
  double hi = -INFINITY;
  for (double v : values) hi = usable(v, y.log) ? std::max(hi, v) : hi;
  if (!std::isfinite(hi)) return values;
  const double f = std::max(0.3, 1.0 - fraction - 0.04);
  values.push_back(y.log ? y.lo * std::pow(hi / y.lo, 1.0 / f) : y.lo + (hi - y.lo) / f);
  return values;
}

// The legend entries of a panel (the shaded spans' entry is in the first panel).
int key_entries(const Plot& plot, const PlotPanel& panel, size_t index) {
  int entries = index == 0 && !plot.spans.empty() && !plot.span_name.empty() ? 1 : 0;
  for (const PlotSeries& p : panel.series) entries += p.name.empty() ? 0 : 1;
  return entries;
}

// The widest tick label of an axis, in characters (for the left margin).
size_t label_chars(const Axis& a) {
  size_t chars = 0;
  const auto count = [](const std::string& t) {
    size_t n = 0;
    for (unsigned char c : t) n += (c & 0xC0) != 0x80;  // UTF-8 code points
    return n;
  };
  if (a.log) {
    for (double t : a.ticks) chars = std::max(chars, count(tick_label(t)));
    return chars;
  }
  char text[40];
  for (double v : {a.lo, a.hi, (a.hi - a.lo) / 10.0}) {
    std::snprintf(text, sizeof text, "%.2g", v);
    chars = std::max(chars, count(text));
  }
  return chars;
}

// The values of every series (and reference line) of a panel along one axis.
std::vector<double> panel_values(const PlotPanel& p, bool along_x) {
  std::vector<double> v;
  for (const PlotSeries& s : p.series) v.insert(v.end(), (along_x ? s.x : s.y).begin(), (along_x ? s.x : s.y).end());
  if (!along_x) {
    for (const PlotLine& l : p.lines) v.push_back(l.y);
  }
  return v;
}

// One panel: axes, reference lines, legend and the plot command over its datablocks.
void panel_commands(std::ostringstream& s, const Plot& plot, const PlotPanel& panel, size_t index, const Axis& x,
                    const Axis& y, bool bottom, const std::string& corner) {
  s << axis_commands("x", x, bottom) << axis_commands("y", y, true);
  s << "set xlabel " << quoted(bottom ? plot.x_label : "") << "\nset ylabel " << quoted(panel.y_label) << "\n";
  int tag = 10;
  for (const PlotLine& l : panel.lines) {
    if (!usable(l.y, y.log)) continue;
    s << "set arrow " << tag << " from graph 0, first " << g(l.y) << " to graph 1, first " << g(l.y)
      << " nohead front lw 1.2 lc rgb " << quoted(l.colour) << " dt " << l.dash << "\n";
    s << "set label " << tag++ << " " << quoted(l.label) << " at graph " << (l.label_left ? "0.005" : "0.995")
      << ", first " << g(l.y) << (l.label_left ? " left" : " right") << (l.label_below ? " offset 0,-0.6" : " offset 0,0.55") << " front boxed font ',9' tc rgb "
      << quoted(l.colour) << "\n";
  }
  const bool spans = index == 0 && !plot.spans.empty() && !plot.span_name.empty();
  s << "set key inside " << corner << " opaque box lc rgb '#bbbbbb' samplen 2 spacing 1.1 font ',10'\n";
  std::vector<std::string> items;
  if (spans) items.push_back("keyentry with boxes fs solid 1.0 noborder fc rgb '#e6e6e6' title " + quoted(plot.span_name));
  size_t colour = 0;
  for (size_t k = 0; k < panel.series.size(); ++k) {
    const PlotSeries& p = panel.series[k];
    const std::string c = p.colour.empty() ? kPalette[colour++ % 8] : p.colour;
    const char* with = p.lines && p.markers ? "linespoints" : p.lines ? "lines" : "points";
    std::ostringstream item;
    item << "$p" << index << "s" << k << " using 1:2 with " << with << " lw " << g(p.width) << " lc rgb " << quoted(c);
    if (p.markers) item << " pt " << p.point_type << " ps " << g(p.point_size);
    item << " title " << quoted(p.name);
    items.push_back(item.str());
    if (!p.point_labels.empty()) {
      items.push_back("$p" + std::to_string(index) + "s" + std::to_string(k) +
                      "l using 1:2:3 with labels left offset char 0.6,0.6 font ',8' tc rgb " + quoted(c) + " notitle");
    }
  }
  if (items.empty()) items.push_back("keyentry notitle");
  s << "plot ";
  for (size_t i = 0; i < items.size(); ++i) s << (i ? ", \\\n     " : "") << items[i];
  s << "\nunset arrow\nunset label\n";
}

}  // namespace

std::string tick_label(double v) {
  char text[48];
  const double a = std::fabs(v);
  const auto trimmed = [&](double x, const char* suffix) {
    std::snprintf(text, sizeof text, "%.3g%s", x, suffix);
    return std::string(text);
  };
  if (a >= 1e9) return trimmed(v / 1e9, "G");
  if (a >= 1e6) return trimmed(v / 1e6, "M");
  if (a >= 1e4) return trimmed(v / 1e3, "k");
  if (a >= 1e3) return std::to_string(int(std::lround(v)));
  if (a >= 1e-3 || a == 0.0) return trimmed(v, "");
  // Small values: m×10⁻ᵉ with Unicode superscripts (no enhanced-text markup to escape).
  const int e = int(std::floor(std::log10(a) + 1e-9));
  const double m = v / std::pow(10.0, e);
  static const char* digits[] = {"⁰", "¹", "²", "³", "⁴", "⁵", "⁶", "⁷", "⁸", "⁹"};
  std::string power = "10";
  power += e < 0 ? "⁻" : "";
  for (char d : std::to_string(std::abs(e))) power += digits[d - '0'];
  return std::fabs(m - 1.0) < 1e-6 ? power : trimmed(m, "×") + power;
}

std::string machine_summary() {
  std::string cpu = "unknown CPU";
  std::ifstream cpuinfo("/proc/cpuinfo");
  for (std::string line; std::getline(cpuinfo, line);) {
    if (line.rfind("model name", 0) == 0) {
      cpu = line.substr(line.find(':') + 2);
      break;
    }
  }
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
  utsname u{};
  uname(&u);
  char memory[32];
  std::snprintf(memory, sizeof memory, "%.3g GiB", double(pages) * double(page) / (1024.0 * 1024.0 * 1024.0));
  return cpu + ", " + std::to_string(sysconf(_SC_NPROCESSORS_ONLN)) + " cores, " + memory + ", " + u.sysname + " " +
         u.release;
}

std::vector<size_t> pareto_front(const std::vector<double>& x, const std::vector<double>& y) {
  std::vector<size_t> order(std::min(x.size(), y.size()));
  std::iota(order.begin(), order.end(), size_t(0));
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return x[a] < x[b] || (x[a] == x[b] && y[a] < y[b]); });
  std::vector<size_t> front;
  double best = INFINITY;
  for (size_t i : order) {
    if (!std::isfinite(x[i]) || !std::isfinite(y[i]) || y[i] >= best) continue;
    front.push_back(i);
    best = y[i];
  }
  return front;
}

namespace {

// Where everything goes, in screen coordinates (0..1) of a W x H pixel figure, and the axes.
struct Layout {
  double W = 900, H = 500;
  double top = 1, bottom = 0, gap = 0, panel_h = 1, left = 0, right = 1;
  Axis x;
  std::vector<Axis> ys;
  std::vector<Key> keys;
};

Layout lay_out(const Plot& plot, const std::vector<PlotPanel>& panels) {
  Layout L;
  const size_t n = panels.size();
  L.W = plot.width;
  L.H = plot.height > 0 ? plot.height : n == 1 ? 500.0 : 120.0 + 240.0 * double(n);
  // Bands: titles on top, the x axis at the bottom, the panels between.
  L.top = 1.0 - ((plot.title.empty() ? 10.0 : 34.0) + (plot.subtitle.empty() ? 0.0 : 18.0)) / L.H;
  L.bottom = 52.0 / L.H, L.gap = 10.0 / L.H;
  L.panel_h = (L.top - L.bottom - L.gap * double(n - 1)) / double(n);
  const double panel_px = L.panel_h * L.H;
  // y axes per panel (or one range for all), then the left margin their labels need.
  std::vector<std::vector<double>> values;
  std::vector<double> all_y;
  for (const PlotPanel& p : panels) {
    values.push_back(panel_values(p, false));
    all_y.insert(all_y.end(), values.back().begin(), values.back().end());
  }
  if (plot.same_y) values.assign(n, all_y);
  for (size_t i = 0; i < n; ++i) L.ys.push_back(make_axis(values[i], panels[i].log_y, true, 0.03, 0.05, panel_px, 22.0));
  size_t chars = 0;
  for (const Axis& y : L.ys) chars = std::max(chars, label_chars(y));
  L.left = (46.0 + 7.0 * double(chars)) / L.W, L.right = 1.0 - 30.0 / L.W;
  const double width_px = (L.right - L.left) * L.W;
  // The x axis, shared (spans included); padded on both sides when points sit at its ends.
  std::vector<double> xs;
  bool points = false;
  for (const PlotPanel& p : panels) {
    const std::vector<double> v = panel_values(p, true);
    xs.insert(xs.end(), v.begin(), v.end());
    for (const PlotSeries& series : p.series) points = points || series.markers;
  }
  for (const PlotSpan& span : plot.spans) xs.push_back(span.x0), xs.push_back(span.x1);
  const double x_pad = points ? 0.02 : 0.0;
  L.x = std::isfinite(plot.x_lo) && std::isfinite(plot.x_hi)
            ? make_axis({plot.x_lo, plot.x_hi}, plot.log_x, false, 0.0, 0.0, width_px, 55.0)
            : make_axis(xs, plot.log_x, false, x_pad, x_pad, width_px, 55.0);
  // The legends: where they cover the least; where every corner is taken, the y axis rises to make room.
  for (size_t i = 0; i < n; ++i) {
    L.keys.push_back(place_key(panels[i], L.x, L.ys[i], width_px, panel_px, key_entries(plot, panels[i], i)));
  }
  double room = 0.0;
  for (const Key& k : L.keys) room = k.covered > 0 ? std::max(room, k.height) : room;
  for (size_t i = 0; i < n; ++i) {
    if (!(plot.same_y ? room > 0.0 : L.keys[i].covered > 0)) continue;
    const double fraction = plot.same_y ? room : L.keys[i].height;
    L.ys[i] = make_axis(with_headroom(values[i], L.ys[i], fraction), panels[i].log_y, true, 0.03, 0.0, panel_px, 22.0);
    L.keys[i] = place_key(panels[i], L.x, L.ys[i], width_px, panel_px, key_entries(plot, panels[i], i));
  }
  return L;
}

// The data as datablocks, once for every output ($pIsK: panel I, series K; $pIsKl: its point labels).
void data_blocks(std::ostringstream& s, const std::vector<PlotPanel>& panels, const Layout& L) {
  for (size_t i = 0; i < panels.size(); ++i) {
    const auto usable_point = [&](const PlotSeries& p, size_t j) { return usable(p.x[j], L.x.log) && usable(p.y[j], L.ys[i].log); };
    for (size_t k = 0; k < panels[i].series.size(); ++k) {
      const PlotSeries& p = panels[i].series[k];
      s << "$p" << i << "s" << k << " << EOD\n";
      bool gap = false;  // a blank line breaks the curve where a value is missing
      for (size_t j = 0; j < p.x.size() && j < p.y.size(); ++j) {
        if (usable_point(p, j)) {
          s << g(p.x[j]) << " " << g(p.y[j]) << "\n";
          gap = false;
        } else if (!gap) {
          s << "\n";
          gap = true;
        }
      }
      s << "EOD\n";
      if (p.point_labels.empty()) continue;
      s << "$p" << i << "s" << k << "l << EOD\n";
      for (size_t j = 0; j < p.x.size() && j < p.y.size() && j < p.point_labels.size(); ++j) {
        std::string label = p.point_labels[j];
        std::replace(label.begin(), label.end(), '"', '\'');
        if (usable_point(p, j)) s << g(p.x[j]) << " " << g(p.y[j]) << " \"" << label << "\"\n";
      }
      s << "EOD\n";
    }
  }
}

// One output file: terminal (by extension), style, titles, shaded spans, then every panel.
void figure_commands(std::ostringstream& s, const Plot& plot, const std::vector<PlotPanel>& panels, const Layout& L,
                     const std::string& out) {
  s << "reset\n";
  if (fs::path(out).extension() == ".png") {
    const double k = plot.png_scale;
    s << "set terminal pngcairo size " << int(L.W * k) << "," << int(L.H * k) << " font 'DejaVu Sans,10' fontscale "
      << g(k) << " linewidth " << g(k) << " background rgb 'white'\n";
  } else {
    s << "set terminal svg size " << int(L.W) << "," << int(L.H) << " font 'DejaVu Sans," << kFontPx
      << "' background rgb 'white'\n";
  }
  s << "set output " << quoted(out) << "\nset termoption noenhanced\nset multiplot\n";
  s << "set border lc rgb '#444444'\nset grid back lt 1 lc rgb '#e2e2e2' lw 1\nset tics out nomirror\n";
  s << "set style textbox opaque noborder margins 1,0\n";  // line labels stay readable over the curves
  s << "set lmargin at screen " << g(L.left) << "\nset rmargin at screen " << g(L.right) << "\n";
  for (size_t k = 0; k < plot.spans.size(); ++k) {
    s << "set object " << k + 1 << " rect from " << g(plot.spans[k].x0) << ", graph 0 to " << g(plot.spans[k].x1)
      << ", graph 1 back fs solid 1.0 noborder fc rgb '#e6e6e6'\n";
  }
  // The titles are labels of the first panel (drawn once); a long subtitle gets a smaller font rather
  // than running off the edges (~6 px per character at 10).
  s << "set label 1 " << quoted(plot.title) << " at screen 0.5, screen " << g(1.0 - 20.0 / L.H) << " center font ',14'\n";
  if (!plot.subtitle.empty()) {
    size_t chars = 0;
    for (unsigned char c : plot.subtitle) chars += (c & 0xC0) != 0x80;
    const double font = std::clamp(10.0 * (L.W - 40.0) / (6.0 * double(chars)), 7.0, 10.0);
    s << "set label 2 " << quoted(plot.subtitle) << " at screen 0.5, screen " << g(1.0 - 40.0 / L.H)
      << " center font '," << g(std::round(font * 2.0) / 2.0) << "' tc rgb '#555555'\n";
  }
  for (size_t i = 0; i < panels.size(); ++i) {
    const double t = L.top - double(i) * (L.panel_h + L.gap);
    s << "set tmargin at screen " << g(t) << "\nset bmargin at screen " << g(t - L.panel_h) << "\n";
    panel_commands(s, plot, panels[i], i, L.x, L.ys[i], i + 1 == panels.size(), L.keys[i].corner);
  }
  s << "unset multiplot\nunset output\n";
}

}  // namespace

std::string plot_script(const Plot& plot, const std::vector<std::string>& outputs) {
  std::vector<PlotPanel> panels = plot.panels;
  if (panels.empty()) panels.push_back({plot.y_label, plot.log_y, plot.series, plot.lines});
  const Layout layout = lay_out(plot, panels);
  std::ostringstream s;
  s << "# divvox plot: " << plot.title << "\nset encoding utf8\n";
  data_blocks(s, panels, layout);
  for (const std::string& out : outputs) figure_commands(s, plot, panels, layout, out);
  return s.str();
}

// The gnuplot executable: $DIVVOX_GNUPLOT (a path or a name), else `gnuplot`, looked up on PATH.
std::string find_gnuplot(std::string& error) {
  const std::string configured = read_env_options().gnuplot;
  const std::string exe = configured.empty() ? "gnuplot" : configured;
  if (exe.find('/') != std::string::npos) {
    if (access(exe.c_str(), X_OK) == 0) return exe;
    error = "DIVVOX_GNUPLOT=" + exe + " is not an executable";
    return "";
  }
  const char* path = std::getenv("PATH");
  std::istringstream dirs(path != nullptr ? path : "");
  for (std::string dir; std::getline(dirs, dir, ':');) {
    const std::string candidate = (dir.empty() ? std::string(".") : dir) + "/" + exe;
    if (access(candidate.c_str(), X_OK) == 0) return candidate;
  }
  error = exe + " not found on PATH (install gnuplot-nox, or set DIVVOX_GNUPLOT)";
  return "";
}

namespace {

// Whether every output exists and is not empty.
bool outputs_written(const std::vector<std::string>& outputs) {
  bool written = true;
  for (const std::string& out : outputs) written = written && fs::exists(out) && fs::file_size(out) > 0;
  return written;
}

// The error of a failed gnuplot run: the first line of its complaint (an error rather than a
// warning when there is one).
std::string plot_failure(const std::string& exe, const std::string& messages) {
  std::string first;
  std::istringstream lines(messages);
  for (std::string line; std::getline(lines, line);) {
    if (line.find_first_not_of(" \t^") == std::string::npos) continue;
    if (first.empty() || first.find("warning:") != std::string::npos) first = line;
    if (line.find("warning:") == std::string::npos) break;
  }
  return exe + " failed" + (first.empty() ? std::string() : ": " + first);
}

// A temporary file's name (the file is created empty); "" when none can be made.
std::string temporary_file() {
  std::string name = (fs::temp_directory_path() / "divvox_plot_XXXXXX").string();
  const int fd = mkstemp(name.data());
  if (fd < 0) return "";
  close(fd);
  return name;
}

// Writes text to a child's stdin; a child that is gone makes it fail (SIGPIPE ignored meanwhile).
void write_to_child(FILE* pipe, const std::string& text) {
  struct sigaction ignore = {}, previous = {};
  ignore.sa_handler = SIG_IGN;
  sigaction(SIGPIPE, &ignore, &previous);
  std::fwrite(text.data(), 1, text.size(), pipe);
  std::fflush(pipe);
  sigaction(SIGPIPE, &previous, nullptr);
}

}  // namespace

bool draw_plot(const Plot& plot, const std::vector<std::string>& outputs, std::string& error) {
  std::error_code ignored;
  for (const std::string& out : outputs) fs::remove(out, ignored);
  const std::string exe = find_gnuplot(error);
  if (exe.empty()) return false;
  // The script goes through a temporary file; gnuplot's messages come back through the pipe.
  const std::string script = temporary_file();
  if (script.empty()) {
    error = "cannot create a temporary file for the gnuplot script";
    return false;
  }
  std::ofstream(script, std::ios::binary) << plot_script(plot, outputs);
  FILE* pipe = popen((shell_word(exe) + " " + shell_word(script) + " 2>&1").c_str(), "r");
  std::string messages;
  int status = -1;
  if (pipe != nullptr) {
    char buffer[512];
    while (std::fgets(buffer, sizeof buffer, pipe) != nullptr) messages += buffer;
    status = pclose(pipe);
  }
  fs::remove(script, ignored);
  if (status == 0 && outputs_written(outputs)) return true;
  for (const std::string& out : outputs) fs::remove(out, ignored);
  error = plot_failure(exe, messages);
  return false;
}

PlotProcess::~PlotProcess() {
  if (pipe_ != nullptr) pclose(pipe_);  // gnuplot reads the end of its input and exits
  std::error_code ignored;
  if (!messages_.empty()) fs::remove(messages_, ignored);
}

bool PlotProcess::start(std::string& error) {
  exe_ = find_gnuplot(error_);
  if (exe_.empty()) {
    error = error_;
    return false;
  }
  // Commands come through the pipe; gnuplot's messages go to a temporary file.
  messages_ = temporary_file();
  if (messages_.empty()) {
    error = error_ = "cannot create a temporary file for gnuplot's messages";
    return false;
  }
  pipe_ = popen((shell_word(exe_) + " > " + shell_word(messages_) + " 2>&1").c_str(), "w");
  if (pipe_ == nullptr) {
    error = error_ = "cannot start " + exe_;
    return false;
  }
  // The throwaway PNG: gnuplot's test page (its terminal and fonts stay loaded; a `plot` here would
  // leave state behind: the SVG's element titles changed), then a clean state for the plot.
  write_to_child(pipe_, "set terminal pngcairo font 'DejaVu Sans,10'\nset output '/dev/null'\ntest\nunset output\nreset\n");
  return true;
}

void PlotProcess::send(const Plot& plot, const std::vector<std::string>& outputs) {
  std::error_code ignored;
  for (const std::string& out : outputs) fs::remove(out, ignored);
  outputs_ = outputs;
  if (pipe_ != nullptr) write_to_child(pipe_, plot_script(plot, outputs) + "\nexit\n");
}

bool PlotProcess::finish(std::string& error) {
  std::error_code ignored;
  if (pipe_ == nullptr) {
    error = error_.empty() ? "gnuplot was not started" : error_;
    for (const std::string& out : outputs_) fs::remove(out, ignored);
    return false;
  }
  const int status = pclose(pipe_);
  pipe_ = nullptr;
  std::ifstream file(messages_, std::ios::binary);
  const std::string messages((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());
  if (status == 0 && outputs_written(outputs_)) return true;
  for (const std::string& out : outputs_) fs::remove(out, ignored);
  error = plot_failure(exe_, messages);
  return false;
}

}  // namespace dvx
