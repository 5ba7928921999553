// Shared test helpers: where the real meshes live, tolerance checks.
#pragma once

#include <doctest/doctest.h>

#include <filesystem>
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

// Path inside the repository.
inline std::string source_path(const std::string& relative) {
  return (std::filesystem::path(DIVVOX_SOURCE_DIR) / relative).string();
}

}  // namespace dvx_test
