// Wall-clock timing of the engine's phases, in milliseconds (sim/ never reads a clock). The one
// clock and the one `ms_between` every timed loop uses: the session's step, the render thread's
// frames, the window and the benchmarks.
#pragma once

#include "sim/step_timings.h"

#include <chrono>

namespace dvx {

using Clock = std::chrono::steady_clock;

// Milliseconds from `a` to `b`.
inline double ms_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

}  // namespace dvx
