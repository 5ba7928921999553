// Inputs the fuzz targets (tests/fuzz) found crashing, plus the seed corpora's invalid inputs,
// replayed through the same code paths (tests/fuzz/fuzz_common.h): each must return normally or
// throw InputError.
#include "fuzz/fuzz_common.h"
#include "support.h"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

namespace {

using RunFn = void (*)(const uint8_t*, size_t);

std::vector<std::filesystem::path> regression_files(const std::string& target) {
  const std::filesystem::path dir = dvx_test::source_path("tests/fuzz/regressions/" + target);
  std::vector<std::filesystem::path> files;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    if (entry.is_regular_file()) files.push_back(entry.path());
  }
  std::sort(files.begin(), files.end());
  return files;
}

void replay_all(const std::string& target, RunFn run) {
  const auto files = regression_files(target);
  REQUIRE_FALSE(files.empty());
  for (const auto& file : files) {
    CAPTURE(file.string());
    std::ifstream in(file, std::ios::binary);
    REQUIRE(in.good());
    const std::vector<char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    const auto* data = reinterpret_cast<const uint8_t*>(bytes.data());
    try {
      run(data, bytes.size());
    } catch (const dvx::InputError&) {
      // refused with a message: fine
    }
  }
  dvx_fuzz::remove_temp_files();
}

}  // namespace

TEST_SUITE("fuzz_regressions") {
  TEST_CASE("scene inputs parse or are refused with InputError") {
    replay_all("scene", dvx_fuzz::run_scene);
  }
  TEST_CASE("scene inputs as files load or are refused with InputError") {
    replay_all("scene", dvx_fuzz::run_scene_file);
  }
  TEST_CASE("recording inputs load as a playback (read, typed, stepped) or are refused with InputError") {
    replay_all("recording", dvx_fuzz::run_recording);
  }
  TEST_CASE("mesh inputs load, voxelize and contour, or are refused with InputError") {
    replay_all("mesh", dvx_fuzz::run_mesh);
  }
}
