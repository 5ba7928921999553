// The simulation's pace (issue 31): simulated time over the wall-clock time the simulation ran, as
// the window's exit statistics and its status line report it. Plain arithmetic over per-frame
// samples, tested without a window (tests/ui/test_sim_pace.cpp).
#pragma once

#include <cstdint>
#include <vector>

namespace dvx {

// Why these spans: "×1 real time" should mean the simulation kept up with the clock while it ran.
// So only the wall time between two samples that both saw it running (ready, not paused, not
// loading) counts, with the steps run in it; paused spans (single steps included) and loading are
// left out. A new session (open, Reset, a recording started or played: `generation`) and an undo /
// redo (`restores`: the step moves back to a kept state) start the count again, so the figure
// covers one unbroken run of steps.
struct SimPace {
  bool started = false;
  uint64_t generation = 0, restores = 0;  // what the count is for
  bool running = false;                   // at the last sample
  double last_time = 0.0;                 // the last sample's wall-clock time (s)
  uint32_t last_step = 0;                 // the last sample's step (the next to run)
  double last_sim = 0.0;                  // the last sample's simulated time (sim_pace_position)
  double run_seconds = 0.0;               // wall-clock time counted
  double sim_seconds = 0.0;               // simulated time of the steps run in it (steps x their dt)
  uint64_t steps = 0;                     // the steps run in it
  // The pace must hold in every second, not only on average (a sever that stalls the simulation for
  // a second is what a user sees): consecutive windows of one second of counted time, each closed
  // window's rate in order (a window ends at the first sample at or past its second).
  double window_run = 0.0, window_sim = 0.0;  // the open window's counted and simulated time
  std::vector<float> per_second;

  // Simulated seconds per wall-clock second (1: real time); 0 before any time was counted.
  double rate() const { return run_seconds > 0.0 ? sim_seconds / run_seconds : 0.0; }
};

// The simulated time at a sample: the steps done plus the time since the last one finished, capped
// at one step. Steps done alone are quantised: a simulation paced at exactly real time has 59 or 61
// step boundaries in some one-second windows (x0.98, x1.02) though it never fell behind; with the
// time since the last step it reads x1.00 there, and a stall still shows (the position stops one
// step after the last step finished until the next one does). A step run up to a step ahead of
// the clock for a command reports its finish at its time on the clock (SimStatus::step_done): until
// then `since_step_done` is negative, down to -dt, and the position stays on the clock.
double sim_pace_position(uint32_t step, double dt, double since_step_done);

// One sample (each frame): `now` wall-clock seconds, `step` the next step to run, `dt` the step's
// length, `since_step_done` the seconds since the step before `step` finished, `running`: ready, not
// paused, not loading. The span since the last sample counts when both samples were running.
void sim_pace_sample(SimPace& pace, double now, uint32_t step, double dt, double since_step_done, bool running,
                     uint64_t generation, uint64_t restores);

}  // namespace dvx
