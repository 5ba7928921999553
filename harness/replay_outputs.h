// `divvox replay`: runs a recording (engine/replay.h) and writes what it found — summary.json,
// timings.csv, frame_timings.csv, timings.svg / .png (gnuplot) and final.ply — into the output folder
// (DESIGN §1, the output contract of `replay --out DIR`).
#pragma once

#include "engine/replay.h"

#include <cstdint>
#include <string>

namespace dvx {

// What replay found; exit code 0 when hashes matched, 1 when the replay diverged.
struct ReplayResult {
  uint32_t steps = 0;
  bool interrupted = false;      // stopped early by SIGINT (outputs cover the steps done)
  uint32_t frames_written = 0;
  uint32_t hash_checked = 0, hash_mismatched = 0;
  int64_t first_mismatch_step = -1;
  std::string final_hash;
  std::string summary_path;
};

// Throws InputError for bad input (recording, scene, mesh).
ReplayResult run_replay(const ReplayOptions& options);

}  // namespace dvx
