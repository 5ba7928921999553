// The command line: what each flag becomes (parse_cli runs nothing), the WxH and resolution-list
// parsers, and the refusals (exit 2 or InputError naming the flag).
#include "app/cli.h"
#include "engine/errors.h"

#include <doctest/doctest.h>

#include <string>
#include <vector>

using namespace dvx;

namespace {

// parse_cli on "divvox ARGS...".
CliCommand parse(std::vector<std::string> args) {
  args.insert(args.begin(), "divvox");
  std::vector<char*> argv;
  for (std::string& a : args) argv.push_back(a.data());
  return parse_cli(int(argv.size()), argv.data());
}

}  // namespace

TEST_SUITE("cli") {
  TEST_CASE("WxH sizes: 16 to 8192 on each side, nothing else") {
    int w = 0, h = 0;
    parse_size("--size", "1280x720", w, h);
    CHECK(w == 1280);
    CHECK(h == 720);
    parse_size("--size", "16X8192", w, h);
    CHECK(w == 16);
    CHECK(h == 8192);
    for (const char* bad : {"1280", "8x8", "1280x720x3", "axb", "1280x", "x720", "9000x100", "1280x720 "}) {
      CAPTURE(bad);
      CHECK_THROWS_WITH_AS(parse_size("--size", bad, w, h),
                           ("--size: '" + std::string(bad) + "' is not WxH with 16 <= W, H <= 8192").c_str(), InputError);
    }
  }

  TEST_CASE("integer lists: comma-separated integers in range") {
    CHECK(parse_int_list("--resolutions", "64,128,256", 1, kMaxResolution) == std::vector<int>{64, 128, 256});
    CHECK(parse_int_list("--resolutions", "32", 1, kMaxResolution) == std::vector<int>{32});
    for (const char* bad : {"", "64,", "64,,128", "0", "64,abc", "5000", "12x", "-3"}) {
      CAPTURE(bad);
      CHECK_THROWS_AS(parse_int_list("--resolutions", bad, 1, kMaxResolution), InputError);
    }
    // The message names the flag and the item.
    try {
      parse_int_list("--iterations", "4,x", 1, 100);
      FAIL("no error");
    } catch (const InputError& e) {
      CHECK(std::string(e.what()) == "--iterations: 'x' is not an integer in [1, 100]");
    }
    // The CLI uses it with the resolution bounds.
    CHECK_THROWS_AS(parse({"bench", "cut", "--resolutions", "64,9000"}), InputError);
  }

  TEST_CASE("replay: flags become ReplayOptions") {
    const CliCommand c = parse({"replay", "rec.jsonl", "--headless", "--no-physics", "--workers", "3", "--frames", "5",
                                "--size", "320x200", "--speed", "realtime", "--record", "o.jsonl", "--hash-every", "7"});
    REQUIRE(c.kind == CliCommand::kReplay);
    CHECK(c.replay.recording == "rec.jsonl");
    CHECK_FALSE(c.replay.physics);
    CHECK(c.replay.workers == 3);
    CHECK(c.replay.frames_every == 5);
    CHECK(c.replay.width == 320);
    CHECK(c.replay.height == 200);
    CHECK(c.replay.realtime);
    CHECK(c.replay.record_path == "o.jsonl");
    CHECK(c.replay.hash_every == 7);
    // Defaults.
    const CliCommand d = parse({"replay", "rec.jsonl"});
    CHECK(d.replay.physics);
    CHECK_FALSE(d.replay.realtime);
    CHECK(d.replay.width == 1280);
    CHECK(d.replay.hash_every == kHashEvery);
    CHECK(d.replay.out_dir == "out/replay");
  }

  TEST_CASE("bench subcommands: lists and defaults") {
    const CliCommand v = parse({"bench", "voxelize", "--resolutions", "16,32", "--repeats", "2"});
    REQUIRE(v.kind == CliCommand::kBenchVoxelize);
    CHECK(v.bench_voxelize.resolutions == std::vector<int>{16, 32});
    CHECK(v.bench_voxelize.repeats == 2);
    CHECK(v.bench_voxelize.out_dir == "out/bench");
    const CliCommand d = parse({"bench", "deform", "--iterations", "1,3"});
    REQUIRE(d.kind == CliCommand::kBenchDeform);
    CHECK(d.bench_deform.iterations == std::vector<int>{1, 3});
    CHECK(parse({"bench", "cut"}).bench_cut.resolutions == std::vector<int>{64, 128, 256});
    CHECK(parse({"bench", "cut"}).bench_cut.directions == std::vector<int>{0, 1, 2});
    CHECK(parse({"bench", "cut", "--directions", "z,x"}).bench_cut.directions == std::vector<int>{2, 0});
    CHECK_THROWS_AS(parse({"bench", "cut", "--directions", "x,w"}), InputError);
    CHECK_THROWS_AS(parse({"bench", "cut", "--directions", "y,y"}), InputError);
    CHECK(parse({"bench", "contact", "--sever-resolution", "0"}).bench_contact.sever_resolution == 0);
    CHECK(parse({"bench", "scaling"}).bench_scaling.resolutions == std::vector<int>{64, 128, 256, 512});
    CHECK(parse({"bench", "report"}).bench_report.results_dir == "bench/results");
    CHECK(parse({"bench", "replay", "--repeats", "4"}).bench_replay.repeats == 4);
    CHECK_THROWS_AS(parse({"bench", "quality", "--resolutions", "64,x"}), InputError);
  }

  TEST_CASE("the window: no subcommand, default scene, size, and --play holds its own scene") {
    const CliCommand w = parse({"--size", "640x480", "--exit-after-frames", "3"});
    REQUIRE(w.kind == CliCommand::kWindow);
    CHECK(w.window.width == 640);
    CHECK(w.window.exit_after_frames == 3);
    CHECK(w.window.scene_path.find("assets/scenes/liver.json") != std::string::npos);  // the window opens the liver
    CHECK(parse({"--play", "r.jsonl"}).window.play_path == "r.jsonl");
    CHECK_THROWS_WITH_AS(parse({"--play", "r.jsonl", "s.json"}),
                         "--play: the recording holds its own scene; drop s.json", InputError);
    CHECK_THROWS_WITH_AS(parse({"voxelise"}), "voxelise: not a subcommand (voxelize, replay, bench) nor a scene file",
                         InputError);
    CHECK_THROWS_AS(parse({"--size", "10x10"}), InputError);
  }

  TEST_CASE("flag errors and help: nothing to run, exit 2 or 0") {
    const CliCommand bad = parse({"replay"});  // the recording is required
    CHECK(bad.kind == CliCommand::kExit);
    CHECK(bad.exit_code == kExitBadInput);
    CHECK(parse({"replay", "r.jsonl", "--workers", "0"}).exit_code == kExitBadInput);
    CHECK(parse({"replay", "r.jsonl", "--speed", "slow"}).exit_code == kExitBadInput);
    CHECK(parse({"bench"}).exit_code == kExitBadInput);
    const CliCommand help = parse({"voxelize", "--help"});
    CHECK(help.kind == CliCommand::kExit);
    CHECK(help.exit_code == 0);
    CHECK(run_command(help) == 0);
  }
}
