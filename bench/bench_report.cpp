// `divvox bench report`: REPORT.md and its plots from the JSON results of the other benchmarks
// (and of tools/peers when it ran). Each section appears when its results exist. This file holds the
// report's assembly and its sections 1, 2, 4-6; section 3 (speed against error) is
// bench/report_speed_error.cpp, the shared pieces bench/report_common.h.
#include "bench/bench.h"
#include "bench/bench_contact.h"
#include "bench/report_common.h"
#include "engine/errors.h"
#include "engine/output.h"
#include "engine/stats.h"

#include <algorithm>
#include <cstdio>
#include <ctime>
#include <map>
#include <sstream>

namespace dvx {
namespace {

using namespace report;

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
     << "Per second: the steps of each simulated second over their compute time (× real time), the slowest "
        "second and p1 over the runs' seconds (a second that severs a piece is the slowest).\n\n"
     << "| recording | workers | runs | steps | wall s (median) | × real time (median) | per second min / p1 | step p99 ms | "
        "deform p50 ms | deform p99 ms | barriers / step | waits / step | deterministic |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const json& r : replay["rows"]) {
    std::map<int, std::vector<const json*>> by_workers;
    for (const json& run : r["runs"]) by_workers[run["workers"].get<int>()].push_back(&run);
    for (auto& [workers, runs] : by_workers) {
      std::vector<double> wall, factor, p99, deform50, deform99, stages, waits, second_min, second_p1;
      for (const json* run : runs) {
        if (run->contains("per_second") && !(*run)["per_second"].is_null()) {
          second_min.push_back(get((*run)["per_second"], "min"));
          second_p1.push_back(get((*run)["per_second"], "p1"));
        }
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
         << (*runs[0])["steps"] << " | " << num(quantile(wall, 0.5)) << " | " << num(quantile(factor, 0.5)) << " | "
         << (second_min.empty() ? std::string("–")
                                : num(*std::min_element(second_min.begin(), second_min.end())) + " / " + num(quantile(second_p1, 0.5)))
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
     << "Direction: the cut plane's normal axis (y: the plane the peers clip with; x and z sweep across the other "
        "ways). Step = divide + surface update.\n\n"
     << "| res | direction | occupied voxels | step p50 ms | step p99 ms | surface p99 ms | µs per cut voxel | "
        "µs per newly divided voxel | explicit B per divided voxel |\n|---|---|---|---|---|---|---|---|---|\n";
  for (const json& r : cut["rows"]) {
    md << "| " << r["resolution"] << " | " << r.value("direction", std::string("y")) << " | " << r["occupied_voxels"] << " | "
       << num(get(r["step_ms"], "p50")) << " | " << num(get(r["step_ms"], "p99")) << " | "
       << (r.contains("surface_ms") ? num(get(r["surface_ms"], "p99")) : std::string("–")) << " | "
       << num(get(r, "us_per_cut_voxel")) << " | " << num(get(r, "us_per_newly_divided_voxel")) << " | "
       << num(get(r, "bytes_per_divided_voxel")) << " |\n";
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
