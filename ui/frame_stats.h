// The window's frame statistics, printed at exit: frame and phase times, fps quantiles, frames that
// showed a new snapshot or drew the scene, and CPU per frame and per step by thread kind (Linux
// /proc and per-thread CPU clocks: wall-clock frame times mean little on a shared, loaded machine).
#pragma once

#include "engine/timing.h"
#include "ui/app_state.h"

#include <ctime>
#include <string>
#include <utility>
#include <vector>

namespace dvx {

struct ThreadCpu {
  double main = 0, driver = 0, other = 0;
};

// Per-frame CPU clocks of the render thread and the GL driver's threads (Linux: a thread's CPU-time
// clock from its id, as pthread_getcpuclockid builds it; nanoseconds, where /proc counts 10 ms ticks),
// so the statistics can split the CPU between frames that drew the scene and frames that reused it.
struct FrameClocks {
  std::vector<clockid_t> driver;
  bool found = false;
};

// Finds the GL driver's threads' CPU clocks (once the driver has started them).
void find_driver_clocks(FrameClocks& c);

// How a frame drew the scene (the scene cache's image reused, or all or half of a new image drawn).
enum class SceneDraw { kNone, kWhole, kFirstHalf, kSecondHalf };
inline constexpr const char* kSceneDrawNames[4] = {"reused the scene cache", "drew the whole scene",
                                                   "drew the first half of a new image", "drew its second half"};

// The window's frame statistics from the first frame showing a scene, printed at exit.
struct FrameStats {
  std::string gl_renderer, normals_where;
  bool profiled = false;
  uint64_t counted_frames = 0;
  Clock::time_point first, last;
  std::vector<double> render_ms, interval_ms;
  std::vector<double> phase_ms[6];  // upload, normals, draw, overlays + blit, panels, swap
  ThreadCpu cpu_start;
  uint32_t step_start = 0;
  uint64_t fresh_frames = 0;  // frames that showed a new snapshot
  uint64_t scene_frames = 0;  // frames that drew the scene (the others: the scene cache's image)
  bool scene_cache = false;
  // CPU ms by frame kind ([0]: drew the scene, [1]: reused the cache): render thread, driver threads.
  FrameClocks clocks;
  std::pair<double, double> clocks_last{0.0, 0.0};
  double kind_cpu[4][2] = {};  // by SceneDraw
  std::vector<double> kind_interval_ms[4];

  // `fresh`: the frame took a new snapshot (the upload and normals phases count only those).
  void add(const AppState& app, const double phases[6], double render, double interval, Clock::time_point end,
           bool fresh, SceneDraw drawn);
  // Prints the statistics at exit (stdout, "window: ..." lines).
  void print(const AppState& app) const;
};

}  // namespace dvx
