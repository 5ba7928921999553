#include "engine/options.h"

#include "engine/errors.h"

#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>

namespace dvx {
namespace {

const char* value_of(const char* name) {
  const char* v = std::getenv(name);
  return v != nullptr && *v != '\0' ? v : nullptr;
}

[[noreturn]] void bad(const char* name, const char* value, const std::string& what) {
  throw_input(name, std::string("must be ") + what + ", not '" + value + "'");
}

// An integer in [lo, hi].
int64_t integer(const char* name, const char* text, int64_t lo, int64_t hi) {
  char* end = nullptr;
  errno = 0;
  const long long v = std::strtoll(text, &end, 10);
  if (errno != 0 || end == text || *end != '\0' || v < lo || v > hi) {
    bad(name, text, "an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
  }
  return v;
}

// 0 or 1.
bool flag(const char* name, const char* text) { return integer(name, text, 0, 1) == 1; }

}  // namespace

EnvOptions read_env_options() {
  EnvOptions o;
  if (const char* t = value_of("DIVVOX_CHUNK_WORK")) {
    o.chunk_work = uint32_t(integer("DIVVOX_CHUNK_WORK", t, 1, 0xffffffffLL));
  }
  if (const char* t = value_of("DIVVOX_BODY_HALVES")) o.body_halves = flag("DIVVOX_BODY_HALVES", t) ? 1 : 0;
  if (const char* t = value_of("DIVVOX_MEMORY_LIMIT")) {
    char* end = nullptr;
    double value = std::strtod(t, &end);
    const char suffix = char(std::toupper(static_cast<unsigned char>(*end)));
    const bool has_suffix = suffix == 'K' || suffix == 'M' || suffix == 'G';
    if (end == t || !std::isfinite(value) || value <= 0.0 || (*end != '\0' && !(has_suffix && end[1] == '\0'))) {
      bad("DIVVOX_MEMORY_LIMIT", t, "a positive number of bytes with an optional K, M or G suffix");
    }
    value *= suffix == 'K' ? 1024.0 : suffix == 'M' ? 1048576.0 : suffix == 'G' ? 1073741824.0 : 1.0;
    o.memory_limit = value >= 1.8e19 ? UINT64_MAX : uint64_t(value);
  }
  if (const char* t = value_of("DIVVOX_PROGRESS")) o.progress = flag("DIVVOX_PROGRESS", t);
  if (const char* t = value_of("DIVVOX_GNUPLOT")) o.gnuplot = t;
  if (const char* t = value_of("DIVVOX_CCX")) o.ccx = t;
  if (const char* t = value_of("DIVVOX_SNAPSHOT_EVERY_STEP")) o.snapshot_every_step = flag("DIVVOX_SNAPSHOT_EVERY_STEP", t);
  if (const char* t = value_of("DIVVOX_SIM_NICE")) o.sim_nice = int(integer("DIVVOX_SIM_NICE", t, 0, 19));
  if (const char* t = value_of("DIVVOX_MSAA")) o.msaa = int(integer("DIVVOX_MSAA", t, 0, 16));
  if (const char* t = value_of("DIVVOX_SCENE_CACHE")) o.scene_cache = flag("DIVVOX_SCENE_CACHE", t);
  if (const char* t = value_of("DIVVOX_SPLIT_FRAMES")) o.split_frames = flag("DIVVOX_SPLIT_FRAMES", t);
  if (const char* t = value_of("DIVVOX_FRAME_PROFILE")) o.frame_profile = flag("DIVVOX_FRAME_PROFILE", t);
  if (const char* t = value_of("DIVVOX_GPU_NORMALS")) o.gpu_normals = flag("DIVVOX_GPU_NORMALS", t) ? 1 : 0;
  if (const char* t = value_of("DIVVOX_SHADOWS")) o.shadows = flag("DIVVOX_SHADOWS", t) ? 1 : 0;
  if (const char* t = value_of("DIVVOX_MAX_FPS")) {
    char* end = nullptr;
    const double v = std::strtod(t, &end);
    if (end == t || *end != '\0' || !(v >= 0.0 && v <= 1000.0)) bad("DIVVOX_MAX_FPS", t, "a number in [0, 1000]");
    o.max_fps = v;
  }
  return o;
}

}  // namespace dvx
