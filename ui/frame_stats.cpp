#include "ui/frame_stats.h"

#include "engine/stats.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <unistd.h>

namespace dvx {

// CPU seconds used so far by this process's threads, by kind (Linux /proc; zeros elsewhere): the
// main (render) thread, the GL driver's threads (llvmpipe's rasteriser), the rest (the simulation
// thread and its workers). Wall-clock frame times mean little on a shared, loaded machine; CPU time
// per frame does not depend on the load.

namespace {

ThreadCpu thread_cpu() {
  ThreadCpu cpu;
  const double tick = double(sysconf(_SC_CLK_TCK));
  std::error_code ec;
  for (const auto& entry : std::filesystem::directory_iterator("/proc/self/task", ec)) {
    std::FILE* f = std::fopen((entry.path() / "stat").c_str(), "r");
    if (!f) continue;
    char buffer[1024] = {};
    const size_t n = std::fread(buffer, 1, sizeof buffer - 1, f);
    std::fclose(f);
    const std::string stat(buffer, n);
    const size_t open = stat.find('('), close = stat.rfind(')');
    if (open == std::string::npos || close == std::string::npos) continue;
    const std::string name = stat.substr(open + 1, close - open - 1);
    unsigned long utime = 0, stime = 0;
    // Fields after the name: state(3) ... utime(14) stime(15).
    if (std::sscanf(stat.c_str() + close + 2, "%*c %*d %*d %*d %*d %*d %*u %*u %*u %*u %*u %lu %lu", &utime, &stime) !=
        2)
      continue;
    const double seconds = double(utime + stime) / tick;
    const bool is_main = entry.path().filename() == std::to_string(getpid());
    if (is_main) {
      cpu.main += seconds;
    } else if (name.rfind("llvmpipe", 0) == 0 || name.rfind("gallium", 0) == 0 || name.rfind("softpipe", 0) == 0) {
      cpu.driver += seconds;
    } else {
      cpu.other += seconds;
    }
  }
  return cpu;
}

}  // namespace

void find_driver_clocks(FrameClocks& c) {
  c.found = true;
  std::error_code ec;
  for (const auto& entry : std::filesystem::directory_iterator("/proc/self/task", ec)) {
    std::FILE* f = std::fopen((entry.path() / "comm").c_str(), "r");
    if (!f) continue;
    char name[64] = {};
    const bool read = std::fgets(name, sizeof name, f) != nullptr;
    std::fclose(f);
    const std::string n = read ? name : "";
    if (n.rfind("llvmpipe", 0) != 0 && n.rfind("gallium", 0) != 0 && n.rfind("softpipe", 0) != 0) continue;
    const long tid = std::atol(entry.path().filename().c_str());
    c.driver.push_back(clockid_t((~tid) << 3 | 6));  // MAKE_THREAD_CPUCLOCK(tid, CPUCLOCK_SCHED)
  }
}

namespace {
double clock_ms(clockid_t id) {
  timespec t{};
  if (clock_gettime(id, &t) != 0) return 0.0;
  return 1e3 * double(t.tv_sec) + 1e-6 * double(t.tv_nsec);
}
// (render thread, driver threads) CPU ms so far.
std::pair<double, double> frame_clocks(FrameClocks& c) {
  if (!c.found) find_driver_clocks(c);
  double driver = 0.0;
  for (clockid_t id : c.driver) driver += clock_ms(id);
  return {clock_ms(CLOCK_THREAD_CPUTIME_ID), driver};
}

// "p50 (p95)" of a sample, in ms (the nearest-rank quantile of engine/stats.h, as every output).
std::string percentiles(const std::vector<double>& v) {
  if (v.empty()) return "-";
  char text[64];
  std::snprintf(text, sizeof text, "%.1f (%.1f)", quantile(v, 0.5), quantile(v, 0.95));
  return text;
}

// The frame rate at quantile q of the frames (q = 0.05: the slowest 5 % run below it).
double fps_percentile(const std::vector<double>& intervals_ms, double q) {
  if (intervals_ms.empty()) return 0.0;
  const double ms = quantile(intervals_ms, 1.0 - q);
  return ms > 0 ? 1000.0 / ms : 0.0;
}

// What a frame draws of the scene (draw_view): nothing (the scene cache's image), all of it, or a
// half of a new snapshot's image (split frames).

}  // namespace

// `fresh`: the frame took a new snapshot (the upload and normals phases count only those).
void FrameStats::add(const AppState& app, const double phases[6], double render, double interval, Clock::time_point end,
                     bool fresh, SceneDraw drawn) {
  const std::pair<double, double> now_cpu = frame_clocks(clocks);
  if (counted_frames == 0) {
    first = end;
    cpu_start = thread_cpu();
    step_start = app.status.step;
  } else {
    const int kind = int(drawn);
    kind_cpu[kind][0] += now_cpu.first - clocks_last.first;
    kind_cpu[kind][1] += now_cpu.second - clocks_last.second;
    kind_interval_ms[kind].push_back(interval);
  }
  clocks_last = now_cpu;
  last = end;
  ++counted_frames;
  render_ms.push_back(render);
  if (counted_frames > 1) interval_ms.push_back(interval);
  fresh_frames += fresh ? 1 : 0;
  scene_frames += drawn != SceneDraw::kNone ? 1 : 0;
  for (int k = 0; k < 6; ++k) {
    if (fresh || k >= 2) phase_ms[k].push_back(phases[k]);
  }
}

void FrameStats::print(const AppState& app) const {
  if (counted_frames < 2) return;
  const double seconds = std::chrono::duration<double>(last - first).count();
  std::printf("window: %llu frames in %.2f s (%.1f fps), render ms p50 %.2f p99 %.2f, %u steps, %s\n",
              static_cast<unsigned long long>(counted_frames), seconds,
              seconds > 0 ? double(counted_frames - 1) / seconds : 0.0, quantile(render_ms, 0.5),
              quantile(render_ms, 0.99), app.status.step, gl_renderer.c_str());
  std::printf(
      "window: %s phase ms p50 (p95): upload %s, normals %s, draw %s, overlays+blit %s, panels %s, swap %s; fps p50 "
      "%.1f p5 %.1f\n",
      profiled ? "(profiled)" : "(not profiled: phases overlap on the GPU)", percentiles(phase_ms[0]).c_str(),
      percentiles(phase_ms[1]).c_str(), percentiles(phase_ms[2]).c_str(), percentiles(phase_ms[3]).c_str(),
      percentiles(phase_ms[4]).c_str(), percentiles(phase_ms[5]).c_str(), fps_percentile(interval_ms, 0.5),
      fps_percentile(interval_ms, 0.05));
  std::printf("window: %llu of %llu frames showed a new snapshot (normals: %s), %llu drew the scene (%s)\n",
              static_cast<unsigned long long>(fresh_frames), static_cast<unsigned long long>(counted_frames),
              normals_where.c_str(), static_cast<unsigned long long>(scene_frames),
              scene_cache ? "the others showed the scene cache's image" : "no scene cache");
  // By frame kind (the first frame excluded): CPU per frame and its fps quantiles.
  for (int kind = 0; kind < 4; ++kind) {
    const size_t n = kind_interval_ms[kind].size();
    if (n == 0) continue;
    std::printf(
        "window: frames that %s: %zu, cpu ms per frame: render thread %.1f, GL driver threads %.1f; fps p50 %.1f p5 "
        "%.1f\n",
        kSceneDrawNames[kind], n, kind_cpu[kind][0] / double(n), kind_cpu[kind][1] / double(n),
        fps_percentile(kind_interval_ms[kind], 0.5), fps_percentile(kind_interval_ms[kind], 0.05));
  }
  const ThreadCpu cpu_end = thread_cpu();
  const double frames = double(counted_frames), steps = double(std::max(app.status.step - step_start, 1u));
  std::printf(
      "window: cpu ms per frame: render thread %.1f, GL driver threads %.1f; simulation %.1f per step (%.0f steps)\n",
      1000.0 * (cpu_end.main - cpu_start.main) / frames, 1000.0 * (cpu_end.driver - cpu_start.driver) / frames,
      1000.0 * (cpu_end.other - cpu_start.other) / steps, steps);
  // The simulation's pace (below 1: slower than real time): its simulated time over the wall time
  // it ran, since the session's start, its last Reset or undo / redo (SimPace).
  const SimPace& pace = app.history.pace;
  std::printf(
      "window: simulation x%.2f real time (%llu steps, %.2f s simulated in %.2f s running; paused time left out, "
      "counted since the last reset or undo)\n",
      pace.rate(), static_cast<unsigned long long>(pace.steps), pace.sim_seconds, pace.run_seconds);
  if (!pace.per_second.empty()) {
    std::vector<double> rates(pace.per_second.begin(), pace.per_second.end());
    // Under x0.995, not x1.0: a second that keeps up reads x0.99996 with the scenes' dt of 0.016666 s
    // (60 steps a second), and the per-second figures are floats.
    std::printf("window: simulation pace per second of running: min x%.3f p1 x%.3f p50 x%.3f over %zu s (seconds under "
                "x0.995: %zu)\n",
                *std::min_element(rates.begin(), rates.end()), quantile(rates, 0.01), quantile(rates, 0.5),
                rates.size(), size_t(std::count_if(rates.begin(), rates.end(), [](double r) { return r < 0.995; })));
  }
  if (!app.history.latency_frames.empty()) {
    double latency = 0.0;
    for (double l : app.history.latency_frames) latency += l;
    double ms = 0.0;
    for (double l : app.history.latency_ms) ms += l;
    std::printf("input to cut latency: %.2f frames mean over %zu cuts (%.0f ms)\n",
                latency / double(app.history.latency_frames.size()), app.history.latency_frames.size(),
                app.history.latency_ms.empty() ? 0.0 : ms / double(app.history.latency_ms.size()));
  }
}

double sim_pace_position(uint32_t step, double dt, double since_step_done) {
  return double(step) * dt + std::clamp(since_step_done, -dt, dt);
}

void sim_pace_sample(SimPace& pace, double now, uint32_t step, double dt, double since_step_done, bool running,
                     uint64_t generation, uint64_t restores) {
  const double position = sim_pace_position(step, dt, since_step_done);
  // A new session, an undo / redo, or a step that went back: the count starts again from here.
  if (!pace.started || generation != pace.generation || restores != pace.restores || step < pace.last_step) {
    pace = SimPace{};
    pace.started = true;
    pace.generation = generation;
    pace.restores = restores;
  } else if (pace.running && running) {
    // Running at both samples: the span and the simulated time run in it count (never negative: a
    // step that finished early, as after a stall, moves the position on from where the cap held it).
    const double span = now - pace.last_time, simulated = std::max(position - pace.last_sim, 0.0);
    pace.run_seconds += span;
    pace.steps += step - pace.last_step;
    pace.sim_seconds += simulated;
    pace.window_run += span;
    pace.window_sim += simulated;
    if (pace.window_run >= 1.0 - 1e-6) {  // (a tolerance for the sum's rounding)
      pace.per_second.push_back(float(pace.window_sim / pace.window_run));
      pace.window_run = pace.window_sim = 0.0;
    }
  }
  pace.running = running;
  pace.last_time = now;
  pace.last_step = step;
  pace.last_sim = position;
}

}  // namespace dvx
