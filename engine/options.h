// The DIVVOX_* environment switches, parsed in one place, strictly: a bad value is an InputError naming
// the variable (exit 2). Each is a setting for measuring or for odd machines, never physics: the same
// recording gives the same bits whatever they say. The list and defaults are in docs/commands.md.
#pragma once

#include <cstdint>
#include <string>

namespace dvx {

struct EnvOptions {
  // Engine.
  uint32_t chunk_work = 0;       // DIVVOX_CHUNK_WORK: instructions per chunk of a shared batch (0: the solver's default)
  int body_halves = -1;          // DIVVOX_BODY_HALVES=0/1: bodies solved side by side (-1: with 2 or more workers)
  uint64_t memory_limit = 0;     // DIVVOX_MEMORY_LIMIT: bytes (K/M/G suffix) a model may take (0: 80 % of available)
  bool progress = false;         // DIVVOX_PROGRESS=1: progress lines on a pipe too
  std::string gnuplot;           // DIVVOX_GNUPLOT: the gnuplot executable (empty: `gnuplot` on PATH)
  // Benchmarks.
  std::string ccx;               // DIVVOX_CCX: the CalculiX executable's path (empty: `ccx` on PATH)
  // The window.
  bool snapshot_every_step = false;  // DIVVOX_SNAPSHOT_EVERY_STEP=1
  int sim_nice = 4;                  // DIVVOX_SIM_NICE: the simulation thread's niceness, 0-19
  int msaa = -1;                     // DIVVOX_MSAA: samples 0-16 (-1: 4 on a GPU, 0 on llvmpipe)
  bool scene_cache = true;           // DIVVOX_SCENE_CACHE=0: off
  bool split_frames = false;         // DIVVOX_SPLIT_FRAMES=1: on (docs/window.md: off since 2026-12-07)
  bool frame_profile = false;        // DIVVOX_FRAME_PROFILE=1: glFinish after each phase
  int gpu_normals = -1;              // DIVVOX_GPU_NORMALS=0/1 (-1: on a GPU only)
  int shadows = -1;                  // DIVVOX_SHADOWS=0/1 (-1: the default)
  double max_fps = 60.0;             // DIVVOX_MAX_FPS: 0-1000 (0: no cap)
};

// Reads every DIVVOX_* variable (once per call; cheap). Throws InputError for a malformed value.
EnvOptions read_env_options();

}  // namespace dvx
