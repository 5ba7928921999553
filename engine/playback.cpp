#include "engine/playback.h"

#include "engine/errors.h"
#include "sim/state_hash.h"

#include <nlohmann/json.hpp>

#include <cmath>

namespace dvx {
namespace {

using json = nlohmann::json;

// A camera command from a recording's "camera" value; throws InputError naming the line otherwise.
CameraCommand parse_camera(const json& c, const std::string& file, uint32_t line) {
  const auto bad = [&] {
    throw_input(file, "line " + std::to_string(line) +
                          ": camera must be {\"target\": [x,y,z], \"distance\": d, \"yaw\": a, \"pitch\": b}");
  };
  const auto number = [&](const json& v) {
    if (!v.is_number() || !std::isfinite(v.get<double>())) bad();
    return float(v.get<double>());
  };
  if (!c.is_object() || !c.contains("target") || !c["target"].is_array() || c["target"].size() != 3) bad();
  CameraCommand camera;
  for (int a = 0; a < 3; ++a) camera.target[a] = number(c["target"][a]);
  for (const char* key : {"distance", "yaw", "pitch"}) {
    if (!c.contains(key)) bad();
  }
  camera.distance = number(c["distance"]);
  camera.yaw = number(c["yaw"]);
  camera.pitch = number(c["pitch"]);
  return camera;
}

// The step line of a step's commands (and camera): {"step", "blade", "cutting", "grab", "camera"};
// null when there is nothing to write.
json commands_line(uint32_t step, const StepCommands& commands, const CameraCommand* camera) {
  json line;
  if (commands.has_blade) line = blade_line(step, commands.blade, commands.cutting);
  if (commands.grab.kind != GrabCommand::kNone) line["grab"] = grab_to_json(commands.grab);
  if (camera != nullptr) {
    line["camera"] = {{"target", {camera->target.x(), camera->target.y(), camera->target.z()}},
                      {"distance", camera->distance},
                      {"yaw", camera->yaw},
                      {"pitch", camera->pitch}};
  }
  if (!line.is_null()) line["step"] = step;
  return line;
}

}  // namespace

GrabCommand parse_grab(const json& grab, const std::string& file, uint32_t line) {
  GrabCommand g;
  if (grab.is_string() && grab.get<std::string>() == "release") {
    g.kind = GrabCommand::kRelease;
    return g;
  }
  const auto fail = [&](const std::string& problem) { throw_input(file, "line " + std::to_string(line) + ": " + problem); };
  const auto bad = [&] {
    fail("grab must be {\"target\": [x,y,z], \"stiffness\": N/m, \"radius\": r, \"force_limit\": N}, "
         "{\"target\": [x,y,z], \"compliance\": c} or \"release\"");
  };
  if (!grab.is_object() || !grab.contains("target") || !grab["target"].is_array() || grab["target"].size() != 3) bad();
  for (int a = 0; a < 3; ++a) {
    if (!grab["target"][a].is_number()) bad();
    g.target[a] = grab["target"][a].get<double>();
  }
  if (!g.target.allFinite()) bad();
  // A number of the grab's, finite and at least 0 (above 0 when `positive`).
  const auto number = [&](const char* key, bool positive) {
    const json& v = grab[key];
    const double x = v.is_number() ? v.get<double>() : NAN;
    if (!std::isfinite(x) || x < 0.0 || (positive && x == 0.0)) {
      fail(std::string("grab.") + key + " must be a finite number " + (positive ? "above 0" : "of at least 0") +
           ", got " + v.dump());
    }
    return x;
  };
  // The region grab (stiffness in N/m), or the single-particle grab of older recordings (compliance).
  if (grab.contains("stiffness")) {
    if (grab.contains("compliance")) fail("grab has both stiffness (the region grab) and compliance (the single-particle grab)");
    g.stiffness = number("stiffness", true);
    if (grab.contains("radius")) g.radius = number("radius", false);
    if (grab.contains("force_limit")) g.force_limit = number("force_limit", false);
  } else {
    if (grab.contains("radius") || grab.contains("force_limit")) fail("grab.radius and grab.force_limit need grab.stiffness");
    if (grab.contains("compliance")) {
      if (!grab["compliance"].is_number() || !(grab["compliance"].get<double>() >= 0.0)) bad();
      g.compliance = grab["compliance"].get<double>();
    }
  }
  g.kind = GrabCommand::kTarget;
  return g;
}

json grab_to_json(const GrabCommand& g) {
  if (g.kind == GrabCommand::kRelease) return "release";
  json out = {{"target", {g.target.x(), g.target.y(), g.target.z()}}};
  if (g.stiffness > 0.0) {
    out["stiffness"] = g.stiffness;
    out["radius"] = g.radius;
    out["force_limit"] = g.force_limit;
  } else {
    out["compliance"] = g.compliance;
  }
  return out;
}

Playback playback_of(const Recording& rec) {
  Playback p;
  p.file = rec.file;
  p.scene = rec.scene;
  p.dt = rec.dt;
  p.physics = rec.physics;
  p.warnings = rec.warnings;
  // Lines in file order (steps never decrease); lines of one step merge into one PlaybackStep.
  for (const RecordedStep& r : rec.steps) {
    if (p.steps.empty() || p.steps.back().step != r.step) {
      PlaybackStep s;
      s.step = r.step;
      s.line = r.line;
      p.steps.push_back(s);
    }
    PlaybackStep& s = p.steps.back();
    if (r.has_blade) {
      s.commands.has_blade = true;
      s.commands.blade = r.blade;
      s.commands.cutting = r.cutting;
    }
    if (r.has_hash) {
      s.has_hash = true;
      s.hash = r.hash;
    }
    if (!r.extra.is_object()) continue;
    // Later values of the same step win (a newer grab target, a release; a newer camera).
    if (r.extra.contains("grab")) s.commands.grab = parse_grab(r.extra["grab"], rec.file, r.line);
    if (r.extra.contains("camera")) {
      s.camera = parse_camera(r.extra["camera"], rec.file, r.line);
      s.has_camera = true;
    }
  }
  return p;
}

Playback load_playback(const std::string& path) { return playback_of(read_recording(path)); }

const PlaybackStep* next_commands(const Playback& playback, PlaybackCursor& cursor, uint32_t step) {
  while (cursor.next < playback.steps.size() && playback.steps[cursor.next].step < step) ++cursor.next;
  if (cursor.next < playback.steps.size() && playback.steps[cursor.next].step == step) {
    return &playback.steps[cursor.next++];
  }
  return nullptr;
}

bool hashes_apply(const Playback& playback, bool physics, std::string& warning) {
  if (playback.physics < 0 || playback.physics == (physics ? 1 : 0)) return true;
  warning = playback.file + ": its state hashes were taken with the physics " + (playback.physics ? "on" : "off") +
            "; not checked";
  return false;
}

bool check_hash(const PlaybackStep& recorded, const Session& session, HashChecks& checks) {
  if (!recorded.has_hash) return true;
  ++checks.checked;
  if (hash_hex(session_hash(session)) == recorded.hash) return true;
  ++checks.mismatched;
  if (checks.first_mismatch_step < 0) checks.first_mismatch_step = recorded.step;
  return false;
}

SessionRecorder::SessionRecorder(const std::string& path, const Scene& scene, double dt, bool physics,
                                 uint32_t hash_every)
    : writer_(path, scene, dt, physics ? 1 : 0), path_(path), hash_every_(hash_every) {}

void SessionRecorder::record(uint32_t step, const StepCommands& commands, const CameraCommand* camera,
                             const Session& session) {
  const json line = commands_line(step, commands, camera);
  if (!line.is_null()) writer_.write_line(line);
  if (hash_every_ > 0 && step % hash_every_ == 0) {
    writer_.write_hash(step, hash_hex(session_hash(session)));
    last_hash_step_ = step;
  }
}

void SessionRecorder::finish(const Session& session) {
  if (finished_) return;
  finished_ = true;
  if (session.state.step == 0 || last_hash_step_ == int64_t(session.state.step) - 1) return;
  writer_.write_hash(session.state.step - 1, hash_hex(session_hash(session)));
}

}  // namespace dvx
