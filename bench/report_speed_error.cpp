// Section 3 of REPORT.md, speed against error: the surface (voxelize + dual contouring, with
// OpenVDB's points), the physics (bench deform: simulation resolution x iterations, the solver
// budget's table) and the elasticity against CalculiX (bench elastic).
#include "bench/report_common.h"

#include "engine/scene.h"

#include <algorithm>
#include <map>
#include <sstream>

namespace dvx::report {

// Section 3's heading, above its surface and physics parts (when either ran).
void speed_error_heading(Results& in, std::ostream& md, std::ostream&) {
  if (!in.read("bench_voxelize.json").is_null() || !in.read("bench_deform.json").is_null()) {
    md << "## 3. Speed against error\n\n";
  }
}

// Section 3, surface: voxelize + dual contouring, time against error (with OpenVDB's points when it ran).
void surface_section(Results& in, std::ostream& md, std::ostream&) {
  const json& voxelize = in.read("bench_voxelize.json");
  const json& vdb = in.read("peers_vdb.json");
  if (voxelize.is_null()) return;
  md << "### Surface: voxelize + dual contouring against resolution\n\n"
     << "Error: two-sided sampled distance between the dual-contoured surface and the input mesh, in voxels "
        "(mean / max), " << voxelize.value("error_samples", 0) << " samples per side. Time: load excluded "
        "(voxelize + contour, median).\n\n"
     << "| mesh | res | voxelize + contour ms | error mean | error max | error mean (scene units) | triangles |\n"
        "|---|---|---|---|---|---|---|\n";
  std::map<std::string, PlotSeries> by_mesh;
  const Scene defaults;
  PlotSeries chosen = chosen_series("scene default (resolution " + std::to_string(defaults.pbd.resolution) + ")");
  for (const json& r : voxelize["rows"]) {
    if (r["status"] != "ok" || !r.contains("error_voxels")) continue;
    const double ms = get(r["time_ms"], "voxelize") + get(r["time_ms"], "contour");
    const double h = get(r, "voxel_size"), mean = get(r["error_voxels"], "mean");
    md << "| " << r["mesh"].get<std::string>() << " | " << r["resolution"] << " | " << num(ms) << " | " << num(mean)
       << " | " << num(get(r["error_voxels"], "max")) << " | " << num(mean * h) << " | " << r["surface_triangles"]
       << " |\n";
    PlotSeries& s = by_mesh.try_emplace(r["mesh"].get<std::string>(), series("divvox " + r["mesh"].get<std::string>(), true, true)).first->second;
    s.x.push_back(ms);
    s.y.push_back(mean / get(r, "resolution"));  // voxels over voxels per longest side
    s.point_labels.push_back(std::to_string(r["resolution"].get<int>()));
    if (r["resolution"] == defaults.pbd.resolution) {
      chosen.x.push_back(ms);
      chosen.y.push_back(s.y.back());
    }
  }
  Plot plot = log_log_plot("Surface extraction: time against error (voxelize + dual contouring)",
                           measured_on(voxelize, "points labelled with the resolution"),
                           "voxelize + contour time, median (ms)", "mean error / longest side of the mesh");
  // The Pareto front of each mesh (with OpenVDB's points on its mesh), under the curves.
  const std::string peer_mesh = vdb.is_object() ? vdb.value("mesh", std::string()) : std::string();
  PlotSeries peer = series("OpenVDB " + peer_mesh, true, true);
  peer.colour = "#555555";
  peer.point_type = 5;
  if (!vdb.is_null() && vdb.value("status", "") == "ok") {
    for (const json& r : vdb["rows"]) {
      peer.x.push_back(get(r, "total_ms"));
      peer.y.push_back(get(r["error"], "mean") / get(r, "resolution"));
      peer.point_labels.push_back(std::to_string(r["resolution"].get<int>()));
    }
  }
  for (auto& [mesh, s] : by_mesh) {
    std::vector<double> x = s.x, y = s.y;
    if (mesh == peer_mesh) {
      x.insert(x.end(), peer.x.begin(), peer.x.end());
      y.insert(y.end(), peer.y.begin(), peer.y.end());
    }
    plot.series.push_back(front_series(plot.series.empty() ? "Pareto front (per mesh)" : "", x, y));
  }
  for (auto& [mesh, s] : by_mesh) plot.series.push_back(s);
  if (!peer.x.empty()) plot.series.push_back(peer);
  if (!chosen.x.empty()) plot.series.push_back(chosen);
  md << "\n" << in.plot("report_surface_pareto.svg", plot) << "\n";
}

// The solvers of the shipped scenes' budget (substeps x iterations constraint passes per step) at the
// finest simulation level, where the reference lives, so only the solver differs: how the shipped
// setting ranks among the ways of spending its budget (Macklin et al. 2019's small steps against more
// iterations), per scenario.
std::string budget_table(const json& deform, const PbdParams& shipped) {
  int finest = 0;
  for (const json& r : deform["rows"]) finest = std::max(finest, r["sim_resolution"].get<int>());
  const int budget = shipped.substeps * shipped.iterations;
  std::ostringstream md;
  md << "The same budget (" << budget << " constraint passes per step) spent as substeps × iterations at the finest "
     << "level (sim " << finest << "), where only the solver differs from the reference:\n\n"
     << "| scenario | substeps × iterations | step p50 ms | error |\n|---|---|---|---|\n";
  std::string verdict;
  for (const char* scenario : {"anchored", "through_cut"}) {
    std::vector<const json*> rows;
    for (const json& r : deform["rows"]) {
      if (r["scenario"] == scenario && r["sim_resolution"] == finest &&
          r.value("substeps", 1) * r["iterations"].get<int>() == budget) {
        rows.push_back(&r);
      }
    }
    if (rows.empty()) continue;
    std::sort(rows.begin(), rows.end(), [](const json* a, const json* b) { return get(*a, "relative_error") < get(*b, "relative_error"); });
    for (const json* r : rows) {
      md << "| " << scenario << " | " << r->value("substeps", 1) << " × " << (*r)["iterations"].get<int>() << " | "
         << num(get(*r, "step_p50_ms")) << " | " << num(get(*r, "relative_error")) << " |\n";
    }
    const json& best = *rows.front();
    const bool shipped_best = best.value("substeps", 1) == shipped.substeps && best["iterations"] == shipped.iterations;
    verdict += std::string(verdict.empty() ? "" : "; ") + scenario + ": " +
               (shipped_best ? "the shipped " + std::to_string(shipped.substeps) + " × " + std::to_string(shipped.iterations) + " is the most accurate"
                             : "the most accurate is " + std::to_string(best.value("substeps", 1)) + " × " +
                                   std::to_string(best["iterations"].get<int>()));
  }
  if (verdict.empty()) return "";
  md << "\n" << verdict << ".\n\n";
  return md.str();
}

// Section 3, physics: the Pareto-optimal simulation resolution x iterations, their plot, the speed target.
void deform_section(Results& in, std::ostream& md, std::ostream&) {
  const json& deform = in.read("bench_deform.json");
  if (deform.is_null()) return;
  md << "### Physics: simulation resolution × iterations\n\n"
     << deform["mesh"].get<std::string>() << " at " << deform["resolution"] << ", anchored on one side under gravity, "
     << num(get(deform, "seconds")) << " s simulated, " << deform["workers"] << " workers. Error: "
     << deform["error"].get<std::string>() << ". The Pareto-optimal settings (no other setting is both faster and "
        "more accurate; the reference run itself, error 0 by definition, left out). PBD's shape matching stiffens with "
        "iterations and with coarser simulation voxels, so at coarse levels the error need not fall with iterations: "
        "it includes the coarse model's own error, not only the solver's. Both sweeps are in it: the iterations "
        "sweep (1 substep) and the small-steps sweep (substeps × iterations at equal cost, Macklin et al. 2019).\n\n"
        "| scenario | sim res | substeps × iterations | step p50 ms | error |\n|---|---|---|---|---|\n";
  const PbdParams defaults = shipped_solver();
  std::string default_on_front;  // the scenarios whose front holds the shipped scenes' setting
  std::string default_rows;      // that setting's own figures per scenario
  for (const char* scenario : {"anchored", "through_cut"}) {
    std::vector<const json*> rows;
    for (const json& r : deform["rows"]) {
      if (r["scenario"] == scenario && get(r, "relative_error") > 0.0) rows.push_back(&r);
    }
    for (const json* r : rows) {
      const int substeps = r->value("substeps", 1), iterations = (*r)["iterations"], sim = (*r)["sim_resolution"];
      const bool shipped = sim == defaults.sim_resolution && iterations == defaults.iterations && substeps == defaults.substeps;
      if (shipped) {
        default_rows += std::string(default_rows.empty() ? "" : "; ") + scenario + " " + num(get(*r, "step_p50_ms")) +
                        " ms, error " + num(get(*r, "relative_error"));
      }
      bool dominated = false;
      for (const json* o : rows) {
        dominated = dominated || (get(*o, "step_p50_ms") < get(*r, "step_p50_ms") &&
                                  get(*o, "relative_error") <= get(*r, "relative_error"));
      }
      if (dominated) continue;
      if (shipped) default_on_front += std::string(default_on_front.empty() ? "" : " and ") + scenario;
      md << "| " << scenario << " | " << sim << " | " << substeps << " × " << iterations << " | "
         << num(get(*r, "step_p50_ms")) << " | " << num(get(*r, "relative_error")) << " |\n";
    }
  }
  md << "\nThe shipped scenes' solver (sim " << defaults.sim_resolution << ", " << defaults.substeps << " × "
     << defaults.iterations << ") is "
     << (default_on_front.empty() ? std::string("on neither front") : "on the " + default_on_front + " front")
     << (default_rows.empty() ? std::string(" (not measured in this run)") : " (" + default_rows + ")")
     << ". With shape stiffness 1 the model's converged limit is rigid (every cluster keeps its rest shape), so "
        "the reference is itself an effort-dependent solution and these errors rank settings against that run, "
        "not against a physical limit; at a coarser level they also hold that level's own model error. The error "
        "against physics (CalculiX, the same geometry and material) is the next section's (`bench elastic`).\n\n"
     << budget_table(deform, defaults)
     << in.plot("bench_deform.svg", deform_plot(deform), "physics speed against error")
     << "\n";
  // The shape-matching kernel before (scalar) and after (blocks, issue 17), measured in the same run.
  const json& kernels = deform.contains("kernels") ? deform["kernels"] : json();
  if (kernels.is_object() && kernels.contains("shape_matching")) {
    const json& r = kernels["shape_matching"];
    md << "Shape-matching kernel before (scalar) and after (vector blocks of " << kShapeLanes
       << " clusters, issue 17; path " << kernels.value("path", std::string("?")) << "), same run, on "
       << "the settled reference state (" << kernels["clusters"] << " clusters): " << num(get(r, "scalar_ns"))
       << " → " << num(get(r, "blocks_ns")) << " ns per cluster solve (" << num(get(r, "speedup")) << "×), "
       << (r["identical"].get<bool>() ? "the same bits" : "**results differ**") << ".\n\n";
  }
  if (kernels.is_object() && kernels.contains("stretch")) {
    const json& r = kernels["stretch"];
    md << "Stretch constraints before (rows one by one) and after (the rows of a colour eight at a time with AVX-512, "
       << "four with AVX2; path " << kernels.value("path", std::string("?")) << "), same run, same state ("
       << kernels["stretch_constraints"] << " constraints, every colour once): " << num(get(r, "rows_ns")) << " → "
       << num(get(r, "vector_ns")) << " ns per constraint ("
       << num(get(r, "speedup")) << "×), " << (r["identical"].get<bool>() ? "the same bits" : "**results differ**")
       << ".\n\n";
  }
  const json& target = deform["target"];
  if (target.is_object()) {
    md << "Speed target: " << target["mesh"].get<std::string>() << " at " << target["resolution"] << " ("
       << target["surface_vertices"] << " surface vertices), simulation " << target["sim_resolution"] << ", "
       << target["iterations"] << " iterations, " << target["workers"] << " workers: PBD + embedding "
       << num(get(target["step_ms"], "p50")) << " ms p50, " << num(get(target["step_ms"], "p99")) << " ms p99 per step.\n\n";
  }
}

// Speed against error, for real (issue 30): the error to CalculiX of each case at the shipped solver,
// the sweep's front, the frequency. Replaces bench deform's self-referenced error as the report.
void elastic_section(Results& in, std::ostream& md, std::ostream& head) {
  const json& r = in.read("bench_elastic.json");
  if (r.is_null()) return;
  const json& shipped = r["shipped"];
  md << "### Elasticity against a finite-element reference (bench elastic)\n\n"
     << "divvox (world_step, settled with damping) against CalculiX on the same geometry, anchors, gravity and "
        "material (C3D8I hexahedra; NLGEOM + Neo-Hookean where the case bends far). Error: "
     << r.value("error", std::string()) << ". Shipped solver: sim " << shipped.value("sim_resolution", 0) << ", "
     << shipped.value("substeps", 0) << " x " << shipped.value("iterations", 0) << ". Command: `divvox bench elastic`.\n\n"
     << "| case | reference | elements | ccx s |\n|---|---|---|---|\n";
  for (const json& c : r["references"]) {
    md << "| " << c["case"].get<std::string>() << " | " << (c.value("nlgeom", false) ? "NLGEOM Neo-Hookean" : "linear")
       << ", E " << num(get(c, "youngs_modulus")) << " Pa, nu " << num(get(c, "poisson_ratio")) << " | "
       << c["elements"] << " | " << (c.value("ok", false) ? num(get(c, "seconds")) : "failed: " + c.value("error", std::string()))
       << " |\n";
  }
  md << "\n| case | model | sim | substeps × iterations | step p50 ms | p99 ms | RMS error | max-disp. error | tip dy mm (ref) |\n"
        "|---|---|---|---|---|---|---|---|---|\n";
  for (const json& row : r["rows"]) {
    if (row.value("kind", std::string()) != "defaults") continue;
    md << "| " << row["case"].get<std::string>() << " | " << row["model"].get<std::string>() << " | "
       << row["sim_resolution"] << " | " << row["substeps"] << " × " << row["iterations"] << " | "
       << num(get(row, "step_p50_ms")) << " | " << num(get(row, "step_p99_ms")) << " | " << pct(get(row, "rms_error"))
       << " | " << pct(get(row, "max_error")) << " | " << num(1e3 * get(row, "tip_dy_m")) << " ("
       << num(1e3 * get(row, "ref_tip_dy_m")) << ") |\n";
  }
  md << "\nPareto-optimal settings of the sweep (no other setting of the same case and model is both faster and "
        "more accurate), the chosen one marked: the cheapest within 10 % RMS that is converged in the solver (doubling "
        "the iterations moves its largest displacement by at most 1 %; a smaller budget can land near the reference "
        "by luck):\n\n"
        "| case | model | setting | step p50 ms | RMS error |\n|---|---|---|---|---|\n";
  std::vector<std::string> names;
  for (const json& row : r["rows"]) {
    if (row.value("kind", std::string()) == "sweep" && std::find(names.begin(), names.end(), row["case"].get<std::string>()) == names.end()) {
      names.push_back(row["case"]);
    }
  }
  for (const std::string& name : names) {
    for (const char* model : {"neo_hookean", "global", "paper"}) {
      const ElasticPick pick = elastic_pick(r, name, model);
      std::vector<const json*> rows;
      for (const json& row : r["rows"]) {
        if (row["case"] == name && row["model"] == model && get(row, "rms_error", -1.0) >= 0.0) rows.push_back(&row);
      }
      std::sort(rows.begin(), rows.end(), [](const json* a, const json* b) { return get(*a, "step_p50_ms") < get(*b, "step_p50_ms"); });
      double best = 1e300;
      // Whether the shipped and chosen settings have a row of the table yet.
      bool shipped_listed = false, chosen_listed = false;
      const bool shipped_is_chosen = pick.shipped && pick.chosen && elastic_setting(*pick.shipped) == elastic_setting(*pick.chosen);
      for (const json* row : rows) {
        if (get(*row, "rms_error") >= best) continue;
        best = get(*row, "rms_error");
        shipped_listed |= pick.shipped != nullptr && elastic_setting(*row) == elastic_setting(*pick.shipped);
        chosen_listed |= row == pick.chosen;
        md << "| " << name << " | " << model << " | " << elastic_setting(*row) << (row == pick.chosen ? " **(chosen)**" : "")
           << " | " << num(get(*row, "step_p50_ms")) << " | " << pct(get(*row, "rms_error")) << " |\n";
      }
      if (!pick.chosen && !rows.empty()) {
        md << "| " << name << " | " << model << " | no converged setting within 10 % RMS | | |\n";
      }
      // The chosen setting where a cheaper, more accurate but unconverged one hides it from the front.
      if (pick.chosen && !chosen_listed) {
        md << "| " << name << " | " << model << " | " << elastic_setting(*pick.chosen)
           << " **(chosen: converged, off the front)**" << (shipped_is_chosen ? ", shipped" : "") << " | "
           << num(get(*pick.chosen, "step_p50_ms")) << " | " << pct(get(*pick.chosen, "rms_error")) << " |\n";
        shipped_listed |= shipped_is_chosen;
      }
      // The scene's own setting, where it is not on the front (the reader sees how far off it is).
      if (pick.shipped && !shipped_listed) {
        md << "| " << name << " | " << model << " | " << elastic_setting(*pick.shipped) << " (shipped, off the front) | "
           << num(get(*pick.shipped, "step_p50_ms")) << " | " << pct(get(*pick.shipped, "rms_error")) << " |\n";
      }
      if (pick.shipped) {
        head << "- Elasticity (" << name << ", " << model << ", shipped solver): " << pct(get(*pick.shipped, "rms_error"))
             << " RMS error to CalculiX at " << num(get(*pick.shipped, "step_p50_ms")) << " ms per step\n";
      }
    }
  }
  md << "\n" << in.plot("bench_elastic.svg", elastic_plot(r), "elasticity speed against error") << "\n";
  if (r.contains("frequency") && !r["frequency"].empty()) {
    md << "First natural frequency of the cantilever (damping off, tip oscillation) against Euler-Bernoulli "
          "(1.875²/2π)·√(EI/ρAL⁴):\n\n| model | sim | measured Hz | analytic Hz |\n|---|---|---|---|\n";
    for (const json& f : r["frequency"]) {
      md << "| " << f["model"].get<std::string>() << " | " << f["sim_resolution"] << " | " << num(get(f, "measured_hz"))
         << " | " << num(get(f, "analytic_hz")) << " |\n";
    }
    md << "\n";
  }
}

}  // namespace dvx::report
