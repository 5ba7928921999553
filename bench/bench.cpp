#include "bench/bench.h"

#include "bench/child_process.h"
#include "engine/errors.h"
#include "engine/output.h"
#include "engine/resources.h"
#include "engine/stats.h"
#include "engine/voxelize_job.h"
#include "harness/plot.h"

#include <nlohmann/json.hpp>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <sstream>

namespace dvx {
namespace {

// One benchmark row: medians over the repeats of one (mesh, resolution).
struct VoxelizeRow {
  double load_ms = 0, voxelize_ms = 0, contour_ms = 0, total_ms = 0;
  uint32_t nx = 0, ny = 0, nz = 0;
  double voxel_size = 0;
  uint64_t occupied_voxels = 0, crossing_edges = 0, model_bytes = 0, peak_rss = 0, surface_triangles = 0;
  uint64_t boundary_edges = 0, components = 0;
  double error_max = 0, error_mean = 0, error_rms = 0;  // two-sided distance to the input, voxel units
};

// Runs the repeats in this (child) process and returns the row.
VoxelizeRow measure(const std::string& mesh, int resolution, int repeats, uint64_t error_samples) {
  std::vector<double> load, vox, contour, total;
  VoxelizeRow row;
  for (int r = 0; r < repeats; ++r) {
    VoxelizeJobOptions options;
    options.mesh_path = mesh;
    options.resolution = resolution;
    options.error_samples = 0;
    const VoxelizeJobResult result = run_voxelize(options);
    load.push_back(result.ms.load);
    vox.push_back(result.ms.voxelize);
    contour.push_back(result.ms.contour);
    total.push_back(result.ms.load + result.ms.voxelize + result.ms.contour);
    row.voxel_size = result.model.lattice.voxel_size;
    row.nx = uint32_t(result.model.lattice.nx);
    row.ny = uint32_t(result.model.lattice.ny);
    row.nz = uint32_t(result.model.lattice.nz);
    row.occupied_voxels = result.model.occupied_voxels;
    row.crossing_edges = result.model.crossings.size();
    row.model_bytes = result.model.memory_bytes();
    row.surface_triangles = result.stats.triangles;
    row.boundary_edges = result.stats.boundary_edges;
    row.components = result.stats.components;
  }
  row.load_ms = quantile(load, 0.5);
  row.voxelize_ms = quantile(vox, 0.5);
  row.contour_ms = quantile(contour, 0.5);
  row.total_ms = quantile(total, 0.5);
  row.peak_rss = peak_rss_bytes();
  // The error to the input in one more, untimed run (after the peak memory was read: the sampling
  // and its tree are not part of voxelization).
  if (error_samples > 0) {
    VoxelizeJobOptions options;
    options.mesh_path = mesh;
    options.resolution = resolution;
    options.error_samples = error_samples;
    const VoxelizeJobResult result = run_voxelize(options);
    row.error_max = result.error.max;
    row.error_mean = result.error.mean;
    row.error_rms = result.error.rms;
  }
  return row;
}

// Runs measure() in a child so each row's peak memory is its own; false when it failed.
bool measure_in_child(const std::string& mesh, int resolution, int repeats, uint64_t error_samples, VoxelizeRow& row,
                      std::string& error) {
  std::string bytes;
  const bool ok = run_in_child(
      [&] {
        const VoxelizeRow r = measure(mesh, resolution, repeats, error_samples);
        return std::string(reinterpret_cast<const char*>(&r), sizeof r);
      },
      bytes, error);
  if (!ok) return false;
  if (bytes.size() != sizeof row) {
    error = "child process returned a truncated result";
    return false;
  }
  std::copy(bytes.begin(), bytes.end(), reinterpret_cast<char*>(&row));
  return true;
}

}  // namespace

std::vector<std::string> default_bench_meshes() {
  const std::filesystem::path shared = DIVVOX_SHARED_ASSETS_DEFAULT;
  std::vector<std::string> meshes;
  for (const char* name : {"bunny_closed_70k.obj", "armadillo_100k.obj", "liver_sofa_smooth.obj"}) {
    if (std::filesystem::exists(shared / name)) meshes.push_back((shared / name).string());
  }
  if (meshes.empty()) {
    meshes.push_back((std::filesystem::path(DIVVOX_SOURCE_DIR_DEFAULT) / "assets/meshes/bunny_npm.obj").string());
  }
  return meshes;
}

std::string bench_voxelize(const BenchVoxelizeOptions& options) {
  const std::vector<std::string> meshes = options.meshes.empty() ? default_bench_meshes() : options.meshes;
  make_output_dir(options.out_dir);
  for (const std::string& mesh : meshes) {
    if (!std::filesystem::exists(mesh)) throw_input(mesh, "no such file");
  }

  std::ostringstream csv;
  csv << "mesh,resolution,nx,ny,nz,repeats,load_ms,voxelize_ms,contour_ms,total_ms,occupied_voxels,crossing_edges,"
         "model_bytes,bytes_per_occupied_voxel,peak_rss_bytes,surface_triangles,boundary_edges,components,"
         "error_max_voxels,error_mean_voxels,error_rms_voxels,voxel_size,status\n";
  nlohmann::json rows = nlohmann::json::array();
  for (const std::string& mesh : meshes) {
    for (int resolution : options.resolutions) {
      const std::string name = std::filesystem::path(mesh).filename().string();
      if (options.progress) std::fprintf(stderr, "divvox bench: %s at %d\n", name.c_str(), resolution);
      VoxelizeRow row;
      std::string error;
      const bool ok = measure_in_child(mesh, resolution, options.repeats, options.error_samples, row, error);
      const double per_voxel = row.occupied_voxels ? double(row.model_bytes) / double(row.occupied_voxels) : 0.0;
      std::string status = ok ? "ok" : error;
      for (char& c : status) {
        if (c == ',' || c == '\n') c = ';';
      }
      csv << name << ',' << resolution << ',' << row.nx << ',' << row.ny << ',' << row.nz << ',' << options.repeats
          << ',' << row.load_ms << ',' << row.voxelize_ms << ',' << row.contour_ms << ',' << row.total_ms << ','
          << row.occupied_voxels << ',' << row.crossing_edges << ',' << row.model_bytes << ',' << per_voxel << ','
          << row.peak_rss << ',' << row.surface_triangles << ',' << row.boundary_edges << ',' << row.components
          << ',' << status << '\n';
      rows.push_back({{"mesh", name},
                      {"resolution", resolution},
                      {"lattice", {row.nx, row.ny, row.nz}},
                      {"time_ms",
                       {{"load", row.load_ms},
                        {"voxelize", row.voxelize_ms},
                        {"contour", row.contour_ms},
                        {"total", row.total_ms}}},
                      {"occupied_voxels", row.occupied_voxels},
                      {"crossing_edges", row.crossing_edges},
                      {"model_bytes", row.model_bytes},
                      {"bytes_per_occupied_voxel", per_voxel},
                      {"peak_rss_bytes", row.peak_rss},
                      {"surface_triangles", row.surface_triangles},
                      {"boundary_edges", row.boundary_edges},
                      {"components", row.components},
                      {"voxel_size", row.voxel_size},
                      {"error_voxels", {{"max", row.error_max}, {"mean", row.error_mean}, {"rms", row.error_rms}}},
                      {"status", status}});
    }
  }
  const std::string csv_path = (std::filesystem::path(options.out_dir) / "bench_voxelize.csv").string();
  write_text_file(csv_path, csv.str());
  write_json_file((std::filesystem::path(options.out_dir) / "bench_voxelize.json").string(),
                  {{"benchmark", "voxelize"}, {"machine", machine_summary()}, {"repeats", options.repeats}, {"error_samples", options.error_samples}, {"statistic", "median"}, {"rows", rows}});
  return csv_path;
}

}  // namespace dvx
