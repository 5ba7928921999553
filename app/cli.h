// The divvox command line: subcommands, flags, exit codes (0 ok, 2 bad input, 1 internal). Parsing
// (parse_cli: argv -> one CliCommand with every option typed and checked) is apart from running
// (run_command), so the tests check what each flag becomes without running anything.
#pragma once

#include "bench/bench.h"
#include "bench/bench_contact.h"
#include "bench/bench_elastic.h"
#include "engine/replay.h"
#include "ui/app.h"

#include <cstdint>
#include <string>

namespace dvx {

// `divvox voxelize`: flags as parsed.
struct VoxelizeArgs {
  std::string mesh;
  std::string scene;
  int resolution = 0;  // 0: from the scene, else 128
  std::string out = "out/voxelize";
  uint64_t error_samples = 100000;
  uint64_t seed = 1;
};

// One parsed command line: which command runs, with its options.
struct CliCommand {
  enum Kind {
    kExit,  // nothing to run: --help or --version was printed, or the line was refused (exit_code)
    kWindow,
    kVoxelize,
    kReplay,
    kBenchVoxelize,
    kBenchCut,
    kBenchDeform,
    kBenchElastic,
    kBenchScaling,
    kBenchCutLength,
    kBenchQuality,
    kBenchReplay,
    kBenchContact,
    kBenchReport,
  } kind = kExit;
  int exit_code = 0;  // with kExit
  WindowOptions window;
  VoxelizeArgs voxelize;
  ReplayOptions replay;
  BenchVoxelizeOptions bench_voxelize;
  BenchCutOptions bench_cut;
  BenchDeformOptions bench_deform;
  BenchElasticOptions bench_elastic;
  BenchScalingOptions bench_scaling;
  BenchCutLengthOptions bench_cut_length;
  BenchQualityOptions bench_quality;
  BenchReplayOptions bench_replay;
  BenchContactOptions bench_contact;
  BenchReportOptions bench_report;
};

// Parses argv. Prints --help / --version (kExit, code 0) and flag errors CLI11 finds (kExit, code 2,
// one line on stderr). Throws InputError for values checked after parsing (WxH sizes, resolution
// lists, a mistyped subcommand, --play with a scene).
CliCommand parse_cli(int argc, char** argv);

// Runs a parsed command; returns the exit code. Throws InputError for bad input it meets.
int run_command(const CliCommand& command);

// parse_cli + run_command with every error turned into its one-line message and exit code. Never throws.
int run_cli(int argc, char** argv);

// A size "WxH" (also "WXH") with 16 <= W, H <= 8192; throws InputError naming `flag` otherwise.
void parse_size(const std::string& flag, const std::string& text, int& width, int& height);

}  // namespace dvx
