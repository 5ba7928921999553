#include "engine/errors.h"
#include "engine/scene.h"
#include "support.h"

#include <doctest/doctest.h>
#include <nlohmann/json.hpp>

#include <filesystem>

using namespace dvx;
using nlohmann::json;

namespace {

// Message of the InputError a parse throws ("" when none).
std::string parse_error(const json& j) {
  try {
    parse_scene(j, "scene.json");
  } catch (const InputError& e) {
    return e.what();
  }
  return {};
}

}  // namespace

TEST_SUITE("scene") {
  TEST_CASE("the default scene loads, with its mesh resolved against the scene folder") {
    const Scene scene = load_scene(dvx_test::source_path("assets/scenes/bunny.json"));
    CHECK(scene.resolution == 128);
    CHECK(scene.sim_resolution == 16);
    CHECK(std::filesystem::exists(scene.mesh_path));
    CHECK(std::filesystem::path(scene.mesh_path).filename() == "bunny_npm.obj");
    REQUIRE(scene.fixed.size() == 1);
    CHECK(scene.gravity.y() == doctest::Approx(-9.81));
  }

  TEST_CASE("only mesh is required, defaults fill the rest") {
    const Scene scene = parse_scene(json{{"mesh", "m.obj"}}, "dir/s.json");
    CHECK(scene.mesh_path == "dir/m.obj");
    CHECK(scene.resolution == 128);
    CHECK(scene.solver.iterations == 10);
    CHECK(scene.fixed.empty());
  }

  TEST_CASE("unknown keys, wrong types and bad values are errors naming the key") {
    CHECK(parse_error(json{{"mesh", "m.obj"}, {"resolutoin", 64}}).find("resolutoin: unknown key") !=
          std::string::npos);
    CHECK(parse_error(json{{"mesh", "m.obj"}, {"material", {{"densty", 1}}}}).find("material.densty") !=
          std::string::npos);
    CHECK(parse_error(json{{"mesh", "m.obj"}, {"resolution", "high"}}).find("resolution: must be an integer") !=
          std::string::npos);
    CHECK(parse_error(json{{"mesh", "m.obj"}, {"resolution", 100000}}).find("resolution: must be in") !=
          std::string::npos);
    CHECK(parse_error(json{{"mesh", "m.obj"}, {"resolution", 96}, {"sim_resolution", 16}}).find("power of two") !=
          std::string::npos);
    CHECK(parse_error(json{{"resolution", 64}}).find("mesh: missing") != std::string::npos);
    CHECK(parse_error(json{{"mesh", 3}}).find("mesh: must be") != std::string::npos);
    CHECK(parse_error(json{{"mesh", "m.obj"}, {"gravity", {0, 1}}}).find("gravity") != std::string::npos);
    CHECK(parse_error(json{{"mesh", "m.obj"}, {"fixed", {{{"box", {{1, 1, 1}, {0, 0, 0}}}}}}})
              .find("min is greater than max") != std::string::npos);
    CHECK(parse_error(json::array()).find("must be an object") != std::string::npos);
    // Every message starts with the file.
    CHECK(parse_error(json{{"mesh", "m.obj"}, {"x", 1}}).rfind("scene.json: ", 0) == 0);
  }

  TEST_CASE("a scene round-trips through JSON") {
    Scene scene = parse_scene(json{{"mesh", "m.obj"}, {"resolution", 64}, {"sim_resolution", 8}}, "s.json");
    scene.fixed.push_back({Vec3d(0, 0, 0), Vec3d(1, 1, 1)});
    const Scene again = parse_scene(scene_to_json(scene), "s.json");
    CHECK(again.resolution == 64);
    CHECK(again.sim_resolution == 8);
    CHECK(again.fixed.size() == 1);
    CHECK(again.solver.dt == scene.solver.dt);
  }
}
