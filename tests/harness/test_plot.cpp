// The plot module: readable log-axis ticks, the Pareto front, gnuplot's SVG, and a missing gnuplot.
#include "harness/plot.h"
#include "support.h"

#include <doctest/doctest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <regex>
#include <sstream>

using namespace dvx;
namespace fs = std::filesystem;

namespace {

using dvx_test::read_text;

// The values of the explicit ticks in a gnuplot `set Xtics ("label" value, ...)` line.
std::vector<std::pair<std::string, double>> explicit_ticks(const std::string& script, const std::string& axis) {
  std::vector<std::pair<std::string, double>> ticks;
  const size_t at = script.find("set " + axis + "tics (");
  if (at == std::string::npos) return ticks;
  const std::string line = script.substr(at, script.find('\n', at) - at);
  const std::regex item("'([^']*)' ([-+0-9.eE]+)");
  for (std::sregex_iterator it(line.begin(), line.end(), item), end; it != end; ++it) {
    ticks.push_back({(*it)[1].str(), std::stod((*it)[2].str())});
  }
  return ticks;
}

}  // namespace

TEST_SUITE("plot") {
  TEST_CASE("log-axis tick labels are short and never in e+NN notation") {
    CHECK(tick_label(20000) == "20k");
    CHECK(tick_label(1e6) == "1M");
    CHECK(tick_label(5000) == "5000");
    CHECK(tick_label(0.05) == "0.05");
    CHECK(tick_label(2e-5) == "2×10⁻⁵");
    CHECK(tick_label(1e-4) == "10⁻⁴");
    for (double v = 1e-7; v < 1e10; v *= 10) {
      for (double m : {1.0, 2.0, 5.0}) {
        CAPTURE(m * v);
        const std::string label = tick_label(m * v);
        CHECK(label.find('e') == std::string::npos);
        CHECK(label.size() <= 12);
      }
    }
  }

  TEST_CASE("a log axis over three decades gets 1-2-5 ticks covering the data") {
    Plot plot;
    plot.log_x = plot.log_y = true;
    plot.series.push_back({"a", {2.32e4, 1.6e5, 2.73e7}, {2.46, 4.33, 23.4}});
    const std::string script = plot_script(plot, {"out.svg"});
    for (const char* axis : {"x", "y"}) {
      CAPTURE(axis);
      const auto ticks = explicit_ticks(script, axis);
      REQUIRE(ticks.size() >= 3);
      for (const auto& tick : ticks) {
        const auto& label = tick.first;  // not a structured binding: clang 14 cannot capture one (CAPTURE)
        const auto value = tick.second;
        CAPTURE(label);
        const double mantissa = value / std::pow(10.0, std::floor(std::log10(value) + 1e-9));
        CHECK((std::abs(mantissa - 1) < 1e-6 || std::abs(mantissa - 2) < 1e-6 || std::abs(mantissa - 5) < 1e-6));
        CHECK(label == tick_label(value));
      }
    }
    const auto x = explicit_ticks(script, "x");
    CHECK(x.front().second <= 2.32e4);
    CHECK(x.back().second >= 2.73e7);
  }

  TEST_CASE("the Pareto front: no front point is beaten, every other point is") {
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    std::vector<double> x(200), y(200);
    for (size_t i = 0; i < x.size(); ++i) x[i] = u(rng), y[i] = u(rng);
    const std::vector<size_t> front = pareto_front(x, y);
    REQUIRE(!front.empty());
    std::vector<bool> on(x.size(), false);
    for (size_t i : front) on[i] = true;
    const auto beats = [&](size_t a, size_t b) { return x[a] <= x[b] && y[a] <= y[b] && (x[a] < x[b] || y[a] < y[b]); };
    for (size_t i = 0; i < x.size(); ++i) {
      bool beaten = false;
      for (size_t j = 0; j < x.size(); ++j) beaten = beaten || beats(j, i);
      CHECK(beaten != on[i]);
    }
    for (size_t k = 1; k < front.size(); ++k) CHECK(x[front[k - 1]] <= x[front[k]]);
  }

  TEST_CASE("gnuplot draws an SVG and a PNG naming every series") {
    std::string error;
    if (find_gnuplot(error).empty()) {
      MESSAGE("skipped: " << error);
      return;
    }
    dvx_test::TempDir dir;
    Plot plot;
    plot.title = "a title with 'quotes' & <angle brackets>";
    plot.x_label = "x";
    plot.panels.push_back({"first_panel ms", true, {{"alpha_1", {1, 2, 3}, {0.5, 2, 8}}}, {{1.0, "budget", "#aa0000"}}});
    plot.panels.push_back({"second", false, {{"beta", {1, 2, 3}, {3, 1, 2}}}, {}});
    plot.spans = {{1.5, 2.5}};
    plot.span_name = "shaded";
    const fs::path svg = dir.path / "p.svg", png = dir.path / "p.png";
    REQUIRE_MESSAGE(draw_plot(plot, {svg.string(), png.string()}, error), error);
    const std::string text = read_text(svg);
    CHECK(text.rfind("<?xml", 0) == 0);
    CHECK(text.find("<svg") != std::string::npos);
    CHECK(text.find("</svg>") != std::string::npos);
    for (const std::string name : {"<text>alpha_1</text>", "<text>beta</text>", "<text>shaded</text>", "budget",
                                   "&amp; &lt;angle brackets>"}) {
      CAPTURE(name);
      CHECK(text.find(name) != std::string::npos);
    }
    CHECK(read_text(png).substr(0, 8) == "\x89PNG\r\n\x1a\n");
  }

  TEST_CASE("without gnuplot: false, a one-line reason, and no stale output left") {
    dvx_test::TempDir dir;
    const dvx_test::ScopedEnv env("DIVVOX_GNUPLOT", (dir.path / "no-such-gnuplot").string());
    const fs::path svg = dir.path / "p.svg";
    std::ofstream(svg) << "stale";
    Plot plot;
    plot.series.push_back({"a", {1, 2}, {1, 2}});
    std::string error;
    CHECK_FALSE(draw_plot(plot, {svg.string()}, error));
    CHECK(error.find("no-such-gnuplot") != std::string::npos);
    CHECK(error.find('\n') == std::string::npos);
    CHECK_FALSE(fs::exists(svg));
  }
}
