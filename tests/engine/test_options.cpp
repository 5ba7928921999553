// The DIVVOX_* switches: parsed in one place, strictly; a bad value names its variable.
#include "engine/errors.h"
#include "engine/options.h"
#include "support.h"

#include <doctest/doctest.h>

using namespace dvx;

TEST_SUITE("options") {
  TEST_CASE("the switches parse to their settings and default when unset") {
    {
      const dvx_test::ScopedEnv a("DIVVOX_MEMORY_LIMIT", "100M"), b("DIVVOX_MAX_FPS", "24.5"), c("DIVVOX_SHADOWS", "0"),
          d("DIVVOX_CHUNK_WORK", "7"), e("DIVVOX_CCX", "/opt/calculix/ccx_2.20"), f("DIVVOX_GNUPLOT", "gnuplot-qt"),
          g("DIVVOX_BODY_HALVES", "0");
      const EnvOptions o = read_env_options();
      CHECK(o.body_halves == 0);
      CHECK(o.memory_limit == 100u * 1024 * 1024);
      CHECK(o.max_fps == 24.5);
      CHECK(o.shadows == 0);
      CHECK(o.chunk_work == 7);
      CHECK(o.ccx == "/opt/calculix/ccx_2.20");
      CHECK(o.gnuplot == "gnuplot-qt");
    }
    const dvx_test::ScopedEnv empty("DIVVOX_MSAA", "");
    const EnvOptions o = read_env_options();
    CHECK(o.msaa == -1);  // empty: unset
    CHECK(o.body_halves == -1);
  }
  TEST_CASE("a malformed switch is refused naming its variable") {
    const std::pair<const char*, const char*> bad[] = {
        {"DIVVOX_MEMORY_LIMIT", "lots"}, {"DIVVOX_MEMORY_LIMIT", "0"},  {"DIVVOX_MEMORY_LIMIT", "5MB"},
        {"DIVVOX_SIM_NICE", "20"},       {"DIVVOX_MSAA", "4x"},         {"DIVVOX_SHADOWS", "yes"},
        {"DIVVOX_MAX_FPS", "-1"},        {"DIVVOX_CHUNK_WORK", "0"},    {"DIVVOX_PROGRESS", "2"},
        {"DIVVOX_BODY_HALVES", "2"}};
    for (const auto& entry : bad) {
      const char* name = entry.first;  // not a structured binding: clang 14 cannot capture one (CAPTURE)
      const char* value = entry.second;
      CAPTURE(name);
      CAPTURE(value);
      const dvx_test::ScopedEnv env(name, value);
      try {
        read_env_options();
        FAIL("accepted");
      } catch (const InputError& e) {
        CHECK(std::string(e.what()).find(name) != std::string::npos);
      }
    }
  }
}
