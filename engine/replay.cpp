#include "engine/replay.h"

#include "engine/errors.h"
#include "engine/mesh_io.h"
#include "engine/output.h"
#include "engine/recording.h"
#include "engine/voxelize_job.h"
#include "sim/cut.h"
#include "sim/state_hash.h"
#include "sim/surface_metrics.h"
#include "sim/voxelize.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <sstream>

namespace dvx {
namespace {

using Clock = std::chrono::steady_clock;

double ms_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

// Per-step timings and counts (one row of timings.csv).
struct StepRow {
  uint32_t step;
  bool cutting;
  double cut_ms, surface_ms, total_ms;
  CutStepStats stats;
};

// {"mean","p50","p95","p99","max"} of a sample (empty: zeros).
nlohmann::json percentiles(std::vector<double> values) {
  if (values.empty()) return {{"mean", 0.0}, {"p50", 0.0}, {"p95", 0.0}, {"p99", 0.0}, {"max", 0.0}, {"count", 0}};
  std::sort(values.begin(), values.end());
  double sum = 0.0;
  for (double v : values) sum += v;
  const auto at = [&](double q) {
    const size_t i = size_t(std::ceil(q * double(values.size()))) - 1;
    return values[std::min(i, values.size() - 1)];
  };
  return {{"mean", sum / double(values.size())},
          {"p50", at(0.50)},
          {"p95", at(0.95)},
          {"p99", at(0.99)},
          {"max", values.back()},
          {"count", values.size()}};
}

bool same_pose(const BladePose& a, const BladePose& b) { return a.a == b.a && a.b == b.b; }

}  // namespace

ReplayResult run_replay(const ReplayOptions& options) {
  if (options.physics) {
    throw_input(options.recording,
                "physics is not part of this build yet; replay with --no-physics (geometry-only cutting)");
  }
  const Recording recording = read_recording(options.recording);
  for (const std::string& warning : recording.warnings) std::fprintf(stderr, "divvox: warning: %s\n", warning.c_str());

  // The voxel model of the recording's scene.
  const Scene& scene = recording.scene;
  const LoadedMesh input = load_mesh(scene.mesh_path);
  check_voxelize_memory(scene.mesh_path, mesh_bounds(input.mesh), input.mesh.triangles.size(), scene.resolution);
  VoxelModel model;
  VoxelizeParams params;
  params.resolution = scene.resolution;
  std::string error;
  if (!voxelize(input.mesh, params, model, error)) throw_input(scene.mesh_path, error);
  CutState state;
  const Clock::time_point init_start = Clock::now();
  init_cut_state(model, state);
  const double init_ms = ms_between(init_start, Clock::now());
  const SurfaceStats initial = surface_stats(compact_surface(state.surface));

  make_output_dir(options.out_dir);
  std::unique_ptr<RecordingWriter> writer;
  if (!options.record_path.empty()) writer = std::make_unique<RecordingWriter>(options.record_path, scene, recording.dt);

  // Step through the recording: a line sets the pose (kept until the next line); the sweep from the
  // previous step's pose to this step's cuts when this step is cutting.
  ReplayResult result;
  std::vector<StepRow> rows;
  BladePose pose;
  bool have_pose = false, cutting = false;
  uint64_t totals_voxels_cut = 0;
  size_t line = 0;
  const uint32_t last = recording.last_step();
  for (uint32_t step = 0; step <= last && !recording.steps.empty(); ++step) {
    const BladePose previous = pose;
    const bool had_pose = have_pose;
    std::string recorded_hash;
    for (; line < recording.steps.size() && recording.steps[line].step == step; ++line) {
      const RecordedStep& r = recording.steps[line];
      if (r.has_blade) {
        pose = r.blade;
        cutting = r.cutting;
        have_pose = true;
      }
      if (r.has_hash) recorded_hash = r.hash;
    }
    StepRow row{step, cutting, 0, 0, 0, {}};
    if (cutting && had_pose && !same_pose(previous, pose)) {
      const Clock::time_point t0 = Clock::now();
      cut_divide(model, state, previous, pose, row.stats);
      const Clock::time_point t1 = Clock::now();
      cut_update_surface(model, state, row.stats);
      const Clock::time_point t2 = Clock::now();
      row.cut_ms = ms_between(t0, t1);
      row.surface_ms = ms_between(t1, t2);
      row.total_ms = ms_between(t0, t2);
      totals_voxels_cut += row.stats.voxels_cut;
    }
    rows.push_back(row);
    if (writer && have_pose) writer->write_blade(step, pose, cutting);

    // Determinism: compare with the recorded hash, write ours.
    const bool want_hash = !recorded_hash.empty() || (writer && options.hash_every > 0 && step % options.hash_every == 0);
    if (want_hash) {
      const std::string hash = hash_hex(cut_state_hash(state));
      if (!recorded_hash.empty()) {
        ++result.hash_checked;
        if (hash != recorded_hash) {
          ++result.hash_mismatched;
          if (result.first_mismatch_step < 0) result.first_mismatch_step = step;
        }
      }
      if (writer && options.hash_every > 0 && step % options.hash_every == 0) writer->write_hash(step, hash);
    }
    if (options.progress && step % 200 == 0) std::fprintf(stderr, "\rdivvox: replay step %u / %u", step, last);
  }
  if (options.progress) std::fprintf(stderr, "\n");
  result.steps = recording.steps.empty() ? 0 : last + 1;
  result.final_hash = hash_hex(cut_state_hash(state));
  if (writer && (options.hash_every == 0 || last % options.hash_every != 0)) writer->write_hash(last, result.final_hash);

  // Final surface and its checks.
  const SurfaceMesh final_surface = compact_surface(state.surface);
  const SurfaceStats stats = surface_stats(final_surface);
  uint64_t nonfinite = 0;
  for (const Vec3f& p : final_surface.positions) nonfinite += p.allFinite() ? 0 : 1;

  // timings.csv
  std::ostringstream csv;
  csv << "step,cut_ms,surface_ms,deform_ms,total_ms,cut_voxels,edges_hit,edges_cut,voxels_divided,"
         "vertices_changed,triangles_changed,cutting\n";
  std::vector<double> cut_ms, surface_ms, total_ms;
  for (const StepRow& r : rows) {
    csv << r.step << ',' << r.cut_ms << ',' << r.surface_ms << ",0," << r.total_ms << ',' << r.stats.voxels_cut << ','
        << r.stats.edges_hit << ',' << r.stats.edges_cut << ',' << r.stats.voxels_divided << ','
        << r.stats.vertices_changed << ',' << r.stats.triangles_changed << ',' << (r.cutting ? 1 : 0) << '\n';
    if (r.stats.edges_hit > 0) {
      cut_ms.push_back(r.cut_ms);
      surface_ms.push_back(r.surface_ms);
      total_ms.push_back(r.total_ms);
    }
  }
  const std::filesystem::path out(options.out_dir);
  write_text_file((out / "timings.csv").string(), csv.str());
  save_ply((out / "final.ply").string(), final_surface);

  // summary.json (DESIGN §1 contract: the fields that apply without physics).
  const nlohmann::json summary = {
      {"recording", options.recording},
      {"scene", scene_to_json(scene)},
      {"physics", false},
      {"steps", result.steps},
      {"dt", recording.dt},
      {"final_hash", result.final_hash},
      {"hash_checks",
       {{"checked", result.hash_checked},
        {"mismatched", result.hash_mismatched},
        {"first_mismatch_step", result.first_mismatch_step}}},
      {"timing_ms",
       {{"cut", percentiles(cut_ms)}, {"surface", percentiles(surface_ms)}, {"total", percentiles(total_ms)}}},
      {"timing_note", "over steps whose blade sweep crossed lattice edges"},
      {"init_ms", init_ms},
      {"lattice", {model.lattice.nx, model.lattice.ny, model.lattice.nz}},
      {"cut",
       {{"voxels_cut", totals_voxels_cut},
        {"voxels_divided", state.divided.size()},
        {"edges_cut", state.edge_cuts.size()},
        {"explicit_bytes", cut_memory_bytes(state)}}},
      {"surface",
       {{"vertices", stats.vertices},
        {"triangles", stats.triangles},
        {"boundary_edges", stats.boundary_edges},
        {"nonmanifold_edges", stats.nonmanifold_edges},
        {"misoriented_edges", stats.misoriented_edges},
        {"components", stats.components},
        {"volume", stats.volume},
        {"initial_volume", initial.volume}}},
      {"nonfinite_values", nonfinite},
  };
  result.summary_path = (out / "summary.json").string();
  write_json_file(result.summary_path, summary);
  return result;
}

}  // namespace dvx
