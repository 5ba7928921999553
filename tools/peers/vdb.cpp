// divvox_peers vdb: OpenVDB's static surface extraction at divvox's voxel size. Per resolution:
// meshToLevelSet (narrow band of 3 voxels) then volumeToMesh (iso 0, no adaptivity), medians over
// repeats; the last repeat's surface is measured against the input like divvox's report.json.
#include "tools/peers/peers.h"

#include "engine/errors.h"
#include "engine/output.h"
#include "sim/lattice.h"
#include "sim/mesh_distance.h"
#include "sim/surface_metrics.h"
#include "sim/voxelize.h"

#include <openvdb/openvdb.h>
#include <openvdb/tools/MeshToVolume.h>
#include <openvdb/tools/VolumeToMesh.h>
#include <tbb/global_control.h>

#include <nlohmann/json.hpp>

#include <filesystem>
#include <memory>
#include <utility>

namespace dvx::peers {
namespace {

// OpenVDB's output (triangles + quads, world space) as a TriMesh: each quad (a,b,c,d) becomes
// (a,b,c) + (a,c,d), which keeps the winding of the triangles OpenVDB returns.
TriMesh vdb_to_trimesh(const std::vector<openvdb::Vec3s>& points, const std::vector<openvdb::Vec3I>& triangles,
                       const std::vector<openvdb::Vec4I>& quads) {
  TriMesh out;
  out.positions.reserve(points.size());
  for (const openvdb::Vec3s& p : points) out.positions.emplace_back(p.x(), p.y(), p.z());
  out.triangles.reserve(triangles.size() + 2 * quads.size());
  for (const openvdb::Vec3I& t : triangles) out.triangles.push_back({t[0], t[1], t[2]});
  for (const openvdb::Vec4I& q : quads) {
    out.triangles.push_back({q[0], q[1], q[2]});
    out.triangles.push_back({q[0], q[2], q[3]});
  }
  return out;
}

}  // namespace

std::string run_vdb(const VdbOptions& options) {
  // Input, converted once to OpenVDB's single-precision arrays (not timed: divvox's voxelize
  // timing starts from its own loaded TriMesh too).
  const TriMesh input = load_input(options.mesh);
  make_output_dir(options.out_dir);
  const Aabb box = mesh_bounds(input);
  std::vector<openvdb::Vec3s> input_points;
  std::vector<openvdb::Vec3I> input_triangles;
  input_points.reserve(input.positions.size());
  for (const Vec3d& p : input.positions) input_points.emplace_back(float(p.x()), float(p.y()), float(p.z()));
  input_triangles.reserve(input.triangles.size());
  for (const Tri& t : input.triangles) input_triangles.emplace_back(t[0], t[1], t[2]);

  // OpenVDB and TBB: divvox's voxelizer is single-threaded, so one thread unless asked.
  openvdb::initialize();
  std::unique_ptr<tbb::global_control> thread_limit;
  if (options.threads > 0) {
    thread_limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                         size_t(options.threads));
  }

  const std::string name = std::filesystem::path(options.mesh).filename().string();
  nlohmann::json rows = nlohmann::json::array();
  std::vector<CsvRow> csv_rows;
  for (const int resolution : options.resolutions) {
    // divvox's lattice for this resolution; OpenVDB's voxel centres are put on its nodes.
    Lattice lattice;
    if (!make_lattice(box, resolution, VoxelizeParams{}.padding, lattice)) {
      throw_input("--resolutions", "no lattice at resolution " + std::to_string(resolution));
    }
    const double h = lattice.voxel_size;
    const openvdb::math::Transform::Ptr transform = openvdb::math::Transform::createLinearTransform(h);
    transform->postTranslate(openvdb::Vec3d(lattice.origin.x(), lattice.origin.y(), lattice.origin.z()));

    // Timed repeats: mesh -> narrow-band level set, level set -> mesh.
    std::vector<double> to_volume_ms, to_mesh_ms, total_ms;
    openvdb::FloatGrid::Ptr grid;
    std::vector<openvdb::Vec3s> points;
    std::vector<openvdb::Vec3I> triangles;
    std::vector<openvdb::Vec4I> quads;
    for (int r = 0; r < options.repeats; ++r) {
      points.clear();
      triangles.clear();
      quads.clear();
      const auto start = std::chrono::steady_clock::now();
      grid = openvdb::tools::meshToLevelSet<openvdb::FloatGrid>(*transform, input_points, input_triangles, 3.0f);
      to_volume_ms.push_back(ms_since(start));
      const auto mesh_start = std::chrono::steady_clock::now();
      openvdb::tools::volumeToMesh(*grid, points, triangles, quads, 0.0 /*iso*/, 0.0 /*adaptivity*/);
      to_mesh_ms.push_back(ms_since(mesh_start));
      total_ms.push_back(ms_since(start));
    }

    // The last repeat's surface, wound outward like divvox's (OpenVDB's may come out inward).
    TriMesh surface = vdb_to_trimesh(points, triangles, quads);
    const bool flipped = signed_volume(surface) < 0.0;
    if (flipped) {
      for (Tri& t : surface.triangles) std::swap(t[1], t[2]);
    }
    const SurfaceStats stats = surface_stats(surface);

    // Two-sided error in voxels (the measure of divvox's report.json error_to_input).
    nlohmann::json error = nullptr;
    ErrorStats e;
    if (options.error_samples > 0 && !surface.triangles.empty()) {
      e = two_sided_error(surface, input, options.error_samples, 1);
      error = {{"max", e.max / h}, {"mean", e.mean / h}, {"rms", e.rms / h}, {"samples", e.samples}};
    }

    // One row per resolution.
    rows.push_back({{"resolution", resolution},
                    {"voxel_size", h},
                    {"lattice", {lattice.nx, lattice.ny, lattice.nz}},
                    {"mesh_to_volume_ms", median(to_volume_ms)},
                    {"volume_to_mesh_ms", median(to_mesh_ms)},
                    {"total_ms", median(total_ms)},
                    {"triangles", triangles.size()},
                    {"quads", quads.size()},
                    {"output_triangles", surface.triangles.size()},
                    {"output_vertices", stats.vertices},
                    {"error", error},
                    {"grid_bytes", grid->memUsage()},
                    {"active_voxels", grid->activeVoxelCount()},
                    {"boundary_edges", stats.boundary_edges},
                    {"nonmanifold_edges", stats.nonmanifold_edges},
                    {"components", stats.components},
                    {"volume", stats.volume},
                    {"flipped", flipped}});
    CsvRow row;
    row.add("mesh", name);
    row.add("threads", uint64_t(options.threads));
    row.add("resolution", uint64_t(resolution));
    row.add("voxel_size", h);
    row.add("nx", uint64_t(lattice.nx));
    row.add("ny", uint64_t(lattice.ny));
    row.add("nz", uint64_t(lattice.nz));
    row.add("mesh_to_volume_ms", median(to_volume_ms));
    row.add("volume_to_mesh_ms", median(to_mesh_ms));
    row.add("total_ms", median(total_ms));
    row.add("triangles", uint64_t(triangles.size()));
    row.add("quads", uint64_t(quads.size()));
    row.add("output_triangles", uint64_t(surface.triangles.size()));
    row.add("error_max", error.is_null() ? std::string() : std::to_string(e.max / h));
    row.add("error_mean", error.is_null() ? std::string() : std::to_string(e.mean / h));
    row.add("error_rms", error.is_null() ? std::string() : std::to_string(e.rms / h));
    row.add("grid_bytes", uint64_t(grid->memUsage()));
    row.add("active_voxels", uint64_t(grid->activeVoxelCount()));
    row.add("boundary_edges", uint64_t(stats.boundary_edges));
    row.add("nonmanifold_edges", uint64_t(stats.nonmanifold_edges));
    row.add("components", uint64_t(stats.components));
    row.add("flipped", flipped);
    csv_rows.push_back(std::move(row));
  }

  // The report: JSON plus one CSV row per resolution.
  const nlohmann::json report = {{"tool", "openvdb"},
                                 {"openvdb_version", OPENVDB_LIBRARY_VERSION_STRING},
                                 {"mesh", name},
                                 {"threads", options.threads},
                                 {"repeats", options.repeats},
                                 {"error_samples", options.error_samples},
                                 {"half_width_voxels", 3.0},
                                 {"input_triangles", input.triangles.size()},
                                 {"input_volume", signed_volume(input)},
                                 {"rows", rows},
                                 {"status", "ok"}};
  const std::filesystem::path out(options.out_dir);
  write_json_file((out / "peers_vdb.json").string(), report);
  write_text_file((out / "peers_vdb.csv").string(), csv_text(csv_rows));
  return (out / "peers_vdb.json").string();
}

}  // namespace dvx::peers
