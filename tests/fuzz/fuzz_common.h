// The code paths the fuzz targets drive, shared with the regression tests
// (tests/engine/test_fuzz_regressions.cpp) so a crashing input replays exactly.
// Each function returns normally or throws dvx::InputError; anything else is a bug.
#pragma once

#include "engine/errors.h"
#include "engine/mesh_io.h"
#include "engine/playback.h"
#include "engine/scene.h"
#include "engine/voxelize_job.h"
#include "sim/contour.h"
#include "sim/surface_metrics.h"
#include "sim/voxelize.h"

#include <nlohmann/json.hpp>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <stdexcept>
#include <string>
#include <unistd.h>

namespace dvx_fuzz {

// A fixed per-process temporary file: /tmp/divvox_fuzz_<pid><suffix>.
inline std::string temp_path(const std::string& suffix) {
  return "/tmp/divvox_fuzz_" + std::to_string(static_cast<long>(::getpid())) + suffix;
}

inline void write_file(const std::string& path, const uint8_t* data, size_t size) {
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (f == nullptr) throw std::runtime_error("fuzz: cannot create " + path);
  if (size > 0 && std::fwrite(data, 1, size, f) != size) {
    std::fclose(f);
    throw std::runtime_error("fuzz: cannot write " + path);
  }
  std::fclose(f);
}

// Removes this process's temporary files (the fuzz targets simply overwrite theirs).
inline void remove_temp_files() {
  for (const char* suffix : {".json", ".jsonl", "_mesh.obj", "_mesh.ply", "_mesh.stl"}) std::remove(temp_path(suffix).c_str());
}

// bytes -> JSON -> parse_scene.
inline void run_scene(const uint8_t* data, size_t size) {
  nlohmann::json json;
  try {
    json = nlohmann::json::parse(data, data + size);
  } catch (const nlohmann::json::exception&) {  // parse_error, or out_of_range for 1e999
    return;
  }
  (void)dvx::parse_scene(json, "fuzz.json");
}

// bytes -> scene file -> load_scene (not a fuzz target: the regression tests also replay the
// scene inputs through the file reader, which parses the JSON itself).
inline void run_scene_file(const uint8_t* data, size_t size) {
  const std::string path = temp_path(".json");
  write_file(path, data, size);
  (void)dvx::load_scene(path);
}

// bytes -> JSON Lines file -> load_playback (the one playback module: read_recording, then every step
// line typed), then every step handed out by next_commands and the physics-mode rule of the hashes, as
// a replay drives them (the scene's mesh need not exist: no session runs).
inline void run_recording(const uint8_t* data, size_t size) {
  const std::string path = temp_path(".jsonl");
  write_file(path, data, size);
  const dvx::Playback playback = dvx::load_playback(path);
  // Every recorded step in order (steps can be up to 2^32 apart: the loop walks the lines, not the steps).
  dvx::PlaybackCursor cursor;
  for (const dvx::PlaybackStep& recorded : playback.steps) {
    if (dvx::next_commands(playback, cursor, recorded.step) != &recorded) throw std::logic_error("fuzz: next_commands skipped a step");
  }
  std::string warning;
  (void)dvx::hashes_apply(playback, true, warning);
}

// Triangle cap above which the mesh target only loads (keeps executions fast).
constexpr size_t kMaxFuzzTriangles = 20000;

// First byte: extension (.obj/.ply/.stl) and resolution; the rest: the file. When it loads:
// voxelize at a small resolution, dual-contour, measure.
inline void run_mesh(const uint8_t* data, size_t size) {
  if (size < 1) return;
  static const char* const kExtensions[] = {".obj", ".ply", ".stl"};
  const uint8_t selector = data[0];
  const std::string path = temp_path(std::string("_mesh") + kExtensions[selector % 3]);
  write_file(path, data + 1, size - 1);
  const dvx::LoadedMesh loaded = dvx::load_mesh(path);
  if (loaded.mesh.triangles.size() > kMaxFuzzTriangles) return;
  const int resolution = 8 + selector % 24;
  dvx::check_voxelize_memory(path, dvx::mesh_bounds(loaded.mesh), loaded.mesh.triangles.size(), resolution);
  dvx::VoxelizeParams params;
  params.resolution = resolution;
  dvx::VoxelModel model;
  std::string error;
  if (!dvx::voxelize(loaded.mesh, params, model, error)) return;
  const dvx::SurfaceMesh surface = dvx::dual_contour(model);
  (void)dvx::surface_stats(surface);
}

}  // namespace dvx_fuzz
