// `divvox bench contact`: the cost of contact (sim/contact.h) — deform step time with and without it
// on the default recording and on the liver scene cut through, and the contacts it solved.
#pragma once

#include <nlohmann/json_fwd.hpp>

#include <ostream>
#include <string>

namespace dvx {

struct BenchContactOptions {
  std::string recording;    // default: assets/recordings/bunny_cut.jsonl (its scene: assets/scenes/bunny.json)
  std::string liver_scene;  // default: assets/scenes/liver.json
  int liver_resolution = 0;      // > 0: overrides the liver scene's resolution
  int liver_cut_steps = 60;      // the blade's sweep across the liver (a horizontal through-cut)
  int liver_rest_steps = 180;    // steps after the cut (the halves rest on each other and on the tray)
  int workers = 2;
  // Sever steps: `sever_scene` (default: the default recording's, assets/scenes/bunny.json: tray and piece
  // contact) at `sever_resolution` (0: skipped) sliced by `sever_strokes` vertical
  // through-cuts (planes x = const), each swept over `sever_stroke_steps` steps and followed by
  // `sever_rest_steps` steps at rest; a step after which the pieces form more bodies (components not
  // joined by material) than before is a sever step.
  std::string sever_scene;
  int sever_resolution = 256;
  int sever_strokes = 4;
  int sever_stroke_steps = 30;
  int sever_rest_steps = 10;
  std::string out_dir;
  bool progress = false;
};

// Runs each case twice, with the scene's contact (planes and piece contact) and without it, timing
// every step's deform phase. Writes DIR/bench_contact.csv (one row per case and mode: deform and step
// p50/p99 in ms, mean contacts per step) and DIR/bench_contact.json; the sever steps: one row each in
// DIR/bench_contact_sever.csv (the step's phases) and their percentiles under "sever" in the JSON.
// Returns the CSV path.
std::string bench_contact(const BenchContactOptions& options);

// The REPORT.md section of bench_contact.json (nothing when `results` is null); a headline line goes
// to `head`.
void report_contact(const nlohmann::json& results, std::ostream& md, std::ostream& head);

}  // namespace dvx
