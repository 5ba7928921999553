// Recordings (JSON Lines, DESIGN §1): a header line, then one line per step that changes the
// blade (or carries other commands), and periodic state hashes. Append-only and readable while
// being written: a truncated last line is a warning, never an error.
//
//   {"format":"divvox-recording","version":1,"scene":{...inline scene...},"dt":0.016666}
//   {"step":0,"blade":[[ax,ay,az],[bx,by,bz]],"cutting":false}
//   {"step":60,"hash":"9f0c...e1"}
//
// Steps without a line keep the last pose. Readers ignore keys they do not know in step lines.
#pragma once

#include "engine/scene.h"
#include "sim/blade_sweep.h"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace dvx {

constexpr int kRecordingVersion = 1;
// A state hash every this many steps (from step 0, and after the last step) in the recordings divvox
// writes: the window's and `replay --record`'s default (engine/playback.h: SessionRecorder).
constexpr uint32_t kHashEvery = 60;

// One step line (a blade pose and/or a hash; other keys kept raw for later layers).
struct RecordedStep {
  uint32_t step = 0;
  bool has_blade = false;
  BladePose blade;
  bool cutting = false;        // only meaningful with has_blade
  bool has_hash = false;
  std::string hash;            // hex state hash after this step
  nlohmann::json extra;        // keys this reader does not interpret (grab, camera, ...), or null
  uint32_t line = 0;           // 1-based line number in the file
};

struct Recording {
  std::string file;
  Scene scene;                    // from the header's inline scene (mesh resolved against the file's folder)
  double dt = 1.0 / 60.0;
  int physics = -1;               // header "physics": 1 / 0 when the hashes were taken with / without it, -1 unknown
  std::vector<RecordedStep> steps;  // in file order; step numbers non-decreasing (pose and hash may share a step)
  std::vector<std::string> warnings;  // e.g. the truncated last line
  uint32_t last_step() const { return steps.empty() ? 0 : steps.back().step; }
};

// Reads and validates a recording. Throws InputError ("FILE:LINE: problem") for: missing or
// empty file, a header that is not a divvox recording, a version newer than kRecordingVersion,
// a malformed line other than the last, a step line without "step", a negative or non-integer
// step, steps out of order or a pose given twice for one step, a blade that is not two finite 3D
// points (NaN/Inf: the message names the step), non-boolean "cutting", a hash that is not a hex
// string. A truncated (unterminated, unparsable) last line is dropped with a warning.
Recording read_recording(const std::string& path);

// The step line of a blade pose: {"step", "blade": [[ax,ay,az],[bx,by,bz]], "cutting"}. Throws
// std::invalid_argument for a non-finite pose (JSON has no NaN: the file would be unreadable).
nlohmann::json blade_line(uint32_t step, const BladePose& blade, bool cutting);

// Writes recordings line by line, flushing after each line so a crash loses at most the line
// being written.
class RecordingWriter {
 public:
  // Creates/truncates `path` and writes the header (with "physics": bool when physics >= 0: the mode
  // the state hashes are taken in). Throws InputError when it cannot be created.
  RecordingWriter(const std::string& path, const Scene& scene, double dt, int physics = -1);
  ~RecordingWriter();
  RecordingWriter(const RecordingWriter&) = delete;
  RecordingWriter& operator=(const RecordingWriter&) = delete;

  void write_blade(uint32_t step, const BladePose& blade, bool cutting);
  void write_hash(uint32_t step, const std::string& hash);
  // Any step line (must contain "step").
  void write_line(const nlohmann::json& line);

 private:
  int fd_ = -1;
  std::string path_;
};

}  // namespace dvx
