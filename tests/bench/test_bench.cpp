// The benchmark experiments and the report on the shipped bunny at small resolutions: structure and
// geometric properties of what they write (never their timings).
#include "bench/bench.h"
#include "bench/bench_common.h"
#include "support.h"

#include <nlohmann/json.hpp>

#include <fstream>

using namespace dvx;
using dvx_test::source_path;
using dvx_test::TempDir;

namespace {

nlohmann::json read_json(const std::filesystem::path& path) {
  std::ifstream file(path);
  REQUIRE(file.good());
  return nlohmann::json::parse(file);
}

using dvx_test::read_text;

}  // namespace

TEST_CASE("least-squares line: exact, noisy and degenerate samples") {
  const LineFit exact = fit_line({0, 1, 2, 3}, {1, 3, 5, 7});
  CHECK(exact.slope == doctest::Approx(2.0));
  CHECK(exact.intercept == doctest::Approx(1.0));
  CHECK(exact.r2 == doctest::Approx(1.0));
  const LineFit noisy = fit_line({0, 1, 2, 3, 4}, {0.1, 0.9, 2.2, 2.8, 4.1});
  CHECK(noisy.slope == doctest::Approx(1.0).epsilon(0.05));
  CHECK(noisy.r2 > 0.98);
  CHECK(noisy.r2 < 1.0);
  const LineFit flat_x = fit_line({2, 2, 2}, {1, 2, 3});
  CHECK(flat_x.slope == 0.0);
  CHECK(flat_x.r2 == 0.0);
  CHECK(fit_line({1}, {1}).samples == 1);
  CHECK(quantile({}, 0.5) == 0.0);
  CHECK(quantile({3, 1, 2}, 0.5) == 2.0);
  CHECK(quantile({3, 1, 2}, 1.0) == 3.0);
  CHECK(quantile({3, 1, 2}, 0.0) == 1.0);
}

TEST_CASE("bench cut-length: cut voxels grow with the cut length, fits are well formed") {
  TempDir dir;
  BenchCutLengthOptions o;
  o.mesh = source_path("assets/meshes/bunny_npm.obj");
  o.resolution = 32;
  o.lengths = 6;
  o.steps = 20;
  o.repeats = 1;
  o.out_dir = dir.path.string();
  bench_cut_length(o);
  const nlohmann::json j = read_json(dir.path / "bench_cut_length.json");
  const auto x = j["single_step"]["x_voxels_cut"].get<std::vector<double>>();
  REQUIRE(x.size() == 6);
  for (size_t i = 1; i < x.size(); ++i) CHECK(x[i] >= x[i - 1]);
  CHECK(x.back() > x.front());
  // The progressive cut's steps together cut at least the one-step full cut's voxels.
  double sum = 0;
  for (double v : j["progressive"]["x_voxels_cut"].get<std::vector<double>>()) sum += v;
  CHECK(sum >= x.back());
  for (const char* kind : {"single_step", "progressive"}) {
    const double r2 = j[kind]["fit"]["r2"];
    CHECK(r2 >= 0.0);
    CHECK(r2 <= 1.0);
  }
  CHECK(std::filesystem::file_size(dir.path / "bench_cut_length.svg") > 500);
}

TEST_CASE("bench quality: the through-cut gives two closed pieces with well-shaped cut faces") {
  TempDir dir;
  BenchQualityOptions o;
  o.mesh = source_path("assets/meshes/bunny_npm.obj");
  o.resolutions = {32};
  o.steps = 15;
  o.repeats = 1;
  o.out_dir = dir.path.string();
  bench_quality(o);
  const nlohmann::json j = read_json(dir.path / "bench_quality.json");
  const nlohmann::json& row = j["rows"][0];
  CHECK(row["components"] == 2);
  CHECK(row["boundary_edges"] == 0);
  const nlohmann::json& cut = row["angles"]["cut_surface"];
  CHECK(cut["triangles"].get<uint64_t>() > 100);
  // Dual contouring on a plane through the lattice: mostly right-angled quads split in two.
  CHECK(cut["mean_min_angle_deg"].get<double>() > 30.0);
  CHECK(cut["fraction_min_le_10"].get<double>() < 0.05);
  uint64_t total = 0;
  for (uint64_t c : cut["min_angle_histogram"].get<std::vector<uint64_t>>()) total += c;
  CHECK(total == cut["triangles"].get<uint64_t>());
  CHECK(j["plane"]["normal"][1] == 1);
}

TEST_CASE("bench scaling: rows per resolution, an impossible resolution is a refused row, not a crash") {
  TempDir dir;
  BenchScalingOptions o;
  o.meshes = {source_path("assets/meshes/bunny_npm.obj")};
  o.resolutions = {32, 64, 1024};  // at 16-20 the lattice cannot hold the bunny's ear tips: they come apart
  o.sim_resolution = 8;
  o.steps = 10;
  o.workers = 1;
  o.out_dir = dir.path.string();
  ::setenv("DIVVOX_MEMORY_LIMIT", "200000000", 1);  // 200 MB: resolution 1024 cannot fit
  bench_scaling(o);
  ::unsetenv("DIVVOX_MEMORY_LIMIT");
  const nlohmann::json j = read_json(dir.path / "bench_scaling.json");
  REQUIRE(j["rows"].size() == 3);
  for (int i : {0, 1}) {
    const nlohmann::json& ok = j["rows"][i];
    CHECK(ok["status"] == "ok");
    CHECK(ok["components"] == 2);
    CHECK(ok["boundary_edges"] == 0);
    CHECK(ok["cutting_steps"].get<int>() > 0);
    CHECK(ok["peak_rss_bytes"].get<uint64_t>() > 0);
  }
  // The flatness entry spans the two resolutions that ran (the refused one is left out); its time per
  // fine voxel cut is every cutting step's cut time over the voxels cut, from the rows' own figures.
  REQUIRE(j["cut_p99_flatness"].size() == 1);
  const nlohmann::json& flat = j["cut_p99_flatness"][0];
  CHECK(flat["from"] == 32);
  CHECK(flat["to"] == 64);
  const nlohmann::json& top = j["rows"][1];
  const double top_cut_ms = top["step_ms"]["cut"]["mean"].get<double>() * top["step_ms"]["cut"]["count"].get<double>();
  CHECK(flat["cut_us_per_voxel_to"].get<double>() ==
        doctest::Approx(1000.0 * top_cut_ms / top["voxels_cut"].get<double>()));
  CHECK(flat["cut_us_per_voxel_from"].get<double>() > 0.0);
  CHECK(flat["cut_p99_ratio"].get<double>() ==
        doctest::Approx(top["step_ms"]["cut"]["p99"].get<double>() / j["rows"][0]["step_ms"]["cut"]["p99"].get<double>()));
  const std::string refused = j["rows"][2]["status"];
  CHECK(refused.rfind("skipped:", 0) == 0);
  CHECK(refused.find("needs about") != std::string::npos);  // the estimate is in the message
  CHECK(read_text(dir.path / "bench_scaling.csv").find("skipped:") != std::string::npos);
}

TEST_CASE("bench report: sections for the results present, plots written, links that resolve") {
  TempDir dir;
  const std::filesystem::path results = dir.path / "results";
  BenchQualityOptions q;
  q.mesh = source_path("assets/meshes/bunny_npm.obj");
  q.resolutions = {24};
  q.steps = 10;
  q.repeats = 1;
  q.out_dir = results.string();
  bench_quality(q);
  BenchCutLengthOptions c;
  c.mesh = q.mesh;
  c.resolution = 24;
  c.lengths = 4;
  c.steps = 10;
  c.repeats = 1;
  c.out_dir = results.string();
  bench_cut_length(c);

  BenchReportOptions r;
  r.results_dir = results.string();
  r.report_path = (dir.path / "REPORT.md").string();
  bench_report(r);
  const std::string md = read_text(r.report_path);
  CHECK(md.find("## 2. Time against cut voxels") != std::string::npos);
  CHECK(md.find("## 4. Cut-surface mesh quality") != std::string::npos);
  CHECK(md.find("CGAL clip | not measured") != std::string::npos);  // no peers results here
  CHECK(md.find("## 1. Scaling") == std::string::npos);            // no scaling results here
  // Every link into the results points at a file that exists.
  std::ofstream(results / "MACHINE.md") << "test machine\n";
  size_t at = 0, images = 0;
  while ((at = md.find("](results/", at)) != std::string::npos) {
    const size_t end = md.find(')', at);
    const std::string link = md.substr(at + 2, end - at - 2);
    CHECK_MESSAGE(std::filesystem::exists(dir.path / link), link);
    at = end;
    ++images;
  }
  CHECK(images >= 3);
  // A missing results folder is an input error.
  r.results_dir = (dir.path / "nothing").string();
  CHECK_THROWS(bench_report(r));
}
