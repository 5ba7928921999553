// The simulation's pace (ui/sim_pace.h, issue 31): simulated time over the wall time the simulation
// ran, paused spans left out, restarted by a new session (Reset) and by an undo / redo.
#include <doctest/doctest.h>

#include "ui/sim_pace.h"

#include <algorithm>
#include <cmath>
#include <vector>

using namespace dvx;

namespace {

constexpr double kDt = 0.01;

// Samples a frame each 0.1 s from `t0` to `t1`, the step advancing `steps_per_frame` a frame (each
// step finishing at the frame's sample).
void run(SimPace& pace, double& t, uint32_t& step, double t1, uint32_t steps_per_frame, bool running,
         uint64_t generation = 1, uint64_t restores = 0) {
  while (t < t1 - 1e-9) {
    t += 0.1;
    step += steps_per_frame;
    sim_pace_sample(pace, t, step, kDt, 0.0, running, generation, restores);
  }
}

}  // namespace

TEST_SUITE("ui") {
  TEST_CASE("sim pace: simulated time over the running wall time, paused spans and their single steps left out") {
    SimPace pace;
    double t = 0.0;
    uint32_t step = 0;
    CHECK(pace.rate() == 0.0);
    sim_pace_sample(pace, t, step, kDt, 0.0, true, 1, 0);
    // 2 s at half real time (5 steps of 0.01 s per 0.1 s frame).
    run(pace, t, step, 2.0, 5, true);
    CHECK(pace.run_seconds == doctest::Approx(2.0));
    CHECK(pace.steps == 100);
    CHECK(pace.rate() == doctest::Approx(0.5));
    // 15 s paused, with a few single steps meanwhile: nothing counted.
    run(pace, t, step, 17.0, 0, false);
    step += 3;
    sim_pace_sample(pace, t, step, kDt, 0.0, false, 1, 0);
    CHECK(pace.run_seconds == doctest::Approx(2.0));
    CHECK(pace.steps == 100);
    // Running again, at real time for 3 s (the first frame's span began paused: not counted).
    run(pace, t, step, 20.0, 10, true);
    CHECK(pace.run_seconds == doctest::Approx(4.9));
    CHECK(pace.steps == 390);
    CHECK(pace.sim_seconds == doctest::Approx(3.9));
    CHECK(pace.rate() == doctest::Approx(3.9 / 4.9));
  }

  TEST_CASE("sim pace: each second of running has its own rate, so a stall shows where the average hides it") {
    SimPace pace;
    double t = 0.0;
    uint32_t step = 0;
    sim_pace_sample(pace, t, step, kDt, 0.0, true, 1, 0);
    run(pace, t, step, 3.0, 10, true);   // 3 s at real time
    run(pace, t, step, 4.0, 3, true);    // a 1 s stall at x0.3
    run(pace, t, step, 5.0, 0, false);   // paused: no window grows
    run(pace, t, step, 8.05, 12, true);  // 3 s at x1.2 (the first frame's span began paused)
    CHECK(pace.rate() == doctest::Approx(6.9 / 7.0));
    REQUIRE(pace.per_second.size() == 7);
    for (int i : {0, 1, 2}) CHECK(pace.per_second[i] == doctest::Approx(1.0));
    CHECK(pace.per_second[3] == doctest::Approx(0.3));
    for (int i : {4, 5, 6}) CHECK(pace.per_second[i] == doctest::Approx(1.2));
    CHECK(pace.window_run < 1e-6);  // every second closed
    // A Reset empties them with the rest.
    sim_pace_sample(pace, t, 0, kDt, 0.0, true, 2, 0);
    CHECK(pace.per_second.empty());
  }

  TEST_CASE("sim pace: a Reset (new session) and an undo / redo start the count again") {
    SimPace pace;
    double t = 0.0;
    uint32_t step = 0;
    sim_pace_sample(pace, t, step, kDt, 0.0, true, 1, 0);
    run(pace, t, step, 15.0, 2, true);  // 15 s at x0.2
    CHECK(pace.rate() == doctest::Approx(0.2));
    // Reset: generation 2, step 0; then 5 s at real time. The figure is the new session's only (the
    // old one divided the steps since the reset by the whole wall time: x0.24 after 15 s + 5 s).
    step = 0;
    sim_pace_sample(pace, t, step, kDt, 0.0, true, 2, 0);
    CHECK(pace.run_seconds == 0.0);
    CHECK(pace.steps == 0);
    run(pace, t, step, 20.0, 10, true, 2);
    CHECK(pace.run_seconds == doctest::Approx(5.0));
    CHECK(pace.rate() == doctest::Approx(1.0));
    // An undo: back to step 120 (restores 1); then 1 s at x0.5.
    step = 120;
    sim_pace_sample(pace, t, step, kDt, 0.0, true, 2, 1);
    CHECK(pace.steps == 0);
    run(pace, t, step, 21.0, 5, true, 2, 1);
    CHECK(pace.steps == 50);
    CHECK(pace.rate() == doctest::Approx(0.5));
    // A redo moves the step forward, yet it is a restore: the count starts again too.
    step = 500;
    sim_pace_sample(pace, t, step, kDt, 0.0, true, 2, 2);
    CHECK(pace.steps == 0);
    CHECK(pace.run_seconds == 0.0);
  }

  TEST_CASE("sim pace: loading (not running) counts nothing, a step that goes back restarts") {
    SimPace pace;
    double t = 0.0;
    uint32_t step = 0;
    run(pace, t, step, 1.0, 0, false);
    CHECK(pace.run_seconds == 0.0);
    run(pace, t, step, 2.0, 10, true);
    CHECK(pace.run_seconds == doctest::Approx(0.9));  // the first running frame's span was not running at its start
    step -= 5;
    sim_pace_sample(pace, t + 0.1, step, kDt, 0.0, true, 1, 0);
    CHECK(pace.steps == 0);
  }

  TEST_CASE("sim pace: a run paced at real time reads x1.00 in every second, a 0.5 s stall shows") {
    // The window's case: steps of 1/60 s started on a real-time schedule, each finishing 7.5 ms
    // (+-2 ms) after its start; frames sampled every 1/54.6 s, unrelated to the steps. Counting
    // step boundaries alone reads x0.993 or x1.009 (60 or 61 steps in a window of 55 frames, 1.007 s):
    // off by more than the counted pace's 0.5 %.
    const double dt = 1.0 / 60.0;
    std::vector<double> done;  // each step's finish time (s)
    double start = 0.0;
    for (int k = 0; k < 60 * 12; ++k) {
      if (k == 60 * 6 + 20) start += 0.5;  // a step that stalls 0.5 s (6.33 s in); the schedule restarts after it
      done.push_back(start + 0.0075 + 0.002 * std::sin(1.7 * k));
      start += dt;
    }
    SimPace counted, quantised;
    size_t steps = 0;
    for (double t = 0.01; t < 11.9; t += 1.0 / 54.6) {
      while (steps < done.size() && done[steps] <= t) ++steps;
      const double since = steps > 0 ? t - done[steps - 1] : 0.0;
      sim_pace_sample(counted, t, uint32_t(steps), dt, since, true, 1, 0);
      sim_pace_sample(quantised, t, uint32_t(steps), dt, 0.0, true, 1, 0);
    }
    REQUIRE(counted.per_second.size() == 11);
    REQUIRE(quantised.per_second.size() == 11);
    bool quantised_off = false;
    for (size_t i = 0; i < 11; ++i) {
      const bool stall = i == 6;  // the second from 6.01 s holds the whole stall
      if (stall) {
        CHECK(counted.per_second[i] == doctest::Approx(0.5).epsilon(0.02));
      } else {
        CHECK(counted.per_second[i] == doctest::Approx(1.0).epsilon(0.005));
        quantised_off = quantised_off || std::abs(quantised.per_second[i] - 1.0) > 0.005;
      }
    }
    CHECK(quantised_off);  // what the position's time since the last step corrects
    CHECK(counted.rate() == doctest::Approx(counted.sim_seconds / counted.run_seconds));
    CHECK(counted.sim_seconds == doctest::Approx(counted.run_seconds - 0.5).epsilon(0.01));
  }

  TEST_CASE("sim pace: steps run ahead of the clock for a command read x1.00 when they report their time on the clock") {
    // The window during a stroke: each frame's blade command runs its step at once, up to one step
    // ahead of the real-time schedule (ui/sim_runner.cpp run), here every other step 0.7 dt early.
    // Reported at their actual finish, a second that starts just after early steps and ends just
    // before one reads up to a step short (x0.983); reported at their time on the clock
    // (SimStatus::step_done), every second reads x1.00.
    const double dt = 1.0 / 60.0;
    std::vector<double> actual, clocked;  // each step's finish time (s): as it ran, and on the clock
    for (int k = 0; k < 60 * 12; ++k) {
      const double on_clock = k * dt + 0.005 + 0.002 * std::sin(1.3 * k);
      const double early = (k / 7) % 2 == 1 ? 0.7 * dt : 0.0;  // runs of 7 steps early, 7 on time
      actual.push_back(on_clock - early);
      clocked.push_back(on_clock);
    }
    SimPace reported_on_clock, reported_actual;
    size_t steps = 0;
    for (double t = 0.01; t < 11.9; t += 1.0 / 43.7) {
      while (steps < actual.size() && actual[steps] <= t) ++steps;
      sim_pace_sample(reported_on_clock, t, uint32_t(steps), dt, steps > 0 ? t - clocked[steps - 1] : 0.0, true, 1, 0);
      sim_pace_sample(reported_actual, t, uint32_t(steps), dt, steps > 0 ? t - actual[steps - 1] : 0.0, true, 1, 0);
    }
    REQUIRE(reported_on_clock.per_second.size() == 11);
    REQUIRE(reported_actual.per_second.size() == 11);
    float worst_actual = 1.0f;
    for (size_t i = 0; i < 11; ++i) {
      CHECK(reported_on_clock.per_second[i] == doctest::Approx(1.0).epsilon(0.005));
      worst_actual = std::min(worst_actual, reported_actual.per_second[i]);
    }
    CHECK(worst_actual < 0.995f);  // what reporting the time on the clock corrects
    CHECK(reported_on_clock.rate() == doctest::Approx(1.0).epsilon(0.005));
  }
}
