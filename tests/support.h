// Shared test helpers: where the real meshes live, tolerance checks.
#pragma once

#include <doctest/doctest.h>

#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

namespace dvx_test {

// Path of a mesh in ../shared/assets, or "" (with a message) when that folder is absent:
// tests on real meshes skip themselves on a fresh clone without it.
inline std::string shared_asset(const std::string& name) {
  std::filesystem::path p = std::filesystem::path(DIVVOX_SHARED_ASSETS) / name;
  if (!std::filesystem::exists(p)) {
    MESSAGE("skipped: " << p.string() << " not found (../shared/assets is absent)");
    return {};
  }
  return p.string();
}

// Whether this machine must render: DIVVOX_REQUIRE_GL=1 (tools/test.sh sets it, since its set-up
// installs Mesa's EGL and Xvfb) turns every "no GL here" skip into a failure.
inline bool gl_required() {
  const char* v = std::getenv("DIVVOX_REQUIRE_GL");
  return v != nullptr && std::string(v) == "1";
}

// A test that needs GL and cannot get it: fails where GL is required, else skips with the reason.
#define DVX_SKIP_OR_FAIL_WITHOUT_GL(reason)                             \
  do {                                                                  \
    if (dvx_test::gl_required()) FAIL("GL required here: " << reason); \
    MESSAGE("skipped: " << reason);                                     \
  } while (0)

// Path inside the repository.
inline std::string source_path(const std::string& relative) {
  return (std::filesystem::path(DIVVOX_SOURCE_DIR) / relative).string();
}

// A temporary folder removed at the end of the test (unique per process and instance).
struct TempDir {
  std::filesystem::path path;
  TempDir() {
    static int counter = 0;
    path = std::filesystem::temp_directory_path() /
           ("divvox_test_" + std::to_string(::getpid()) + "_" + std::to_string(counter++));
    std::filesystem::create_directories(path);
  }
  ~TempDir() { std::filesystem::remove_all(path); }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  // Writes a file in the folder and returns its path.
  std::string file(const std::string& name, const std::string& text) const {
    const std::filesystem::path p = path / name;
    std::ofstream(p, std::ios::binary) << text;
    return p.string();
  }
};

// A file's bytes ("" when it cannot be read).
inline std::string read_text(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

// Sets an environment variable for the scope of a test, then restores it (e.g. DIVVOX_GNUPLOT).
struct ScopedEnv {
  std::string name, old;
  bool had = false;
  ScopedEnv(const char* n, const std::string& value) : name(n) {
    const char* v = std::getenv(n);
    had = v != nullptr;
    if (had) old = v;
    setenv(n, value.c_str(), 1);
  }
  ~ScopedEnv() {
    if (had) setenv(name.c_str(), old.c_str(), 1);
    else unsetenv(name.c_str());
  }
  ScopedEnv(const ScopedEnv&) = delete;
  ScopedEnv& operator=(const ScopedEnv&) = delete;
};

}  // namespace dvx_test
