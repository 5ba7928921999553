// Wall-clock timing of the engine's phases, in milliseconds (sim/ never reads a clock). The one
// clock and the one `ms_between` every timed loop uses: the session's step, the render thread's
// frames, the window and the benchmarks.
#pragma once

#include <chrono>

namespace dvx {

using Clock = std::chrono::steady_clock;

// Milliseconds from `a` to `b`.
inline double ms_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

// What one simulation step's phases took: the cut (divide, fine and coarse), the surface update,
// the deformation (PBD + embedding) and the whole step.
struct StepTimings {
  double cut_ms = 0, surface_ms = 0, deform_ms = 0, total_ms = 0;
};

}  // namespace dvx
