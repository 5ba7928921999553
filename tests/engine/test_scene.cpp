#include "engine/errors.h"
#include "engine/scene.h"
#include "engine/session.h"
#include "sim/surface_metrics.h"
#include "support.h"

#include <doctest/doctest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <filesystem>
#include <map>

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
    CHECK(scene.pbd.resolution == 128);
    CHECK(scene.pbd.sim_resolution == 16);
    CHECK(std::filesystem::exists(scene.mesh_path));
    CHECK(std::filesystem::path(scene.mesh_path).filename() == "bunny_npm.obj");
    REQUIRE(scene.pbd.fixed.size() == 1);
    CHECK(scene.pbd.gravity.y() == doctest::Approx(-9.81));
    REQUIRE(scene.pbd.planes.size() == 1);  // the tray under the bunny
    CHECK(scene.pbd.planes[0].normal.y() == 1.0);
  }

  TEST_CASE("the liver scene loads: its mesh ships, its ligament region is anchored, it lies on a tray") {
    const Scene scene = load_scene(dvx_test::source_path("assets/scenes/liver.json"));
    CHECK(std::filesystem::exists(scene.mesh_path));
    CHECK(std::filesystem::path(scene.mesh_path).filename() == "liver_sofa_smooth.obj");
    CHECK(scene.pbd.fixed.size() >= 1);
    REQUIRE(scene.pbd.planes.size() == 1);
    CHECK(scene.pbd.planes[0].normal.dot(-scene.pbd.gravity) > 0.0);  // a tray under it, against gravity
  }

  TEST_CASE("only mesh is required, defaults fill the rest") {
    const Scene scene = parse_scene(json{{"mesh", "m.obj"}}, "dir/s.json");
    CHECK(scene.mesh_path == "dir/m.obj");
    CHECK(scene.pbd.resolution == 128);
    CHECK(scene.pbd.iterations == 10);
    CHECK(scene.pbd.fixed.empty());
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

  TEST_CASE("contact planes: normal normalised, friction read, bad values are errors naming the key") {
    const json tray = {{"point", {0, -0.1, 0}}, {"normal", {0, 2, 0}}, {"friction", 0.7}};
    const Scene scene = parse_scene(json{{"mesh", "m.obj"}, {"planes", {tray}}}, "s.json");
    REQUIRE(scene.pbd.planes.size() == 1);
    CHECK(scene.pbd.planes[0].normal.isApprox(Vec3d(0, 1, 0)));
    CHECK(scene.pbd.planes[0].point.y() == doctest::Approx(-0.1));
    CHECK(scene.pbd.planes[0].kinetic_friction == 0.7);
    CHECK(scene.pbd.planes[0].static_friction == 0.7);  // defaults to friction
    const auto with_plane = [](json plane) { return json{{"mesh", "m.obj"}, {"planes", {plane}}}; };
    json bad = tray;
    bad["normal"] = {0, 0, 0};
    CHECK(parse_error(with_plane(bad)).find("planes[0].normal: must be a non-zero vector") != std::string::npos);
    bad = tray;
    bad["normal"] = {0, 1};
    CHECK(parse_error(with_plane(bad)).find("planes[0].normal: must be an array of 3") != std::string::npos);
    bad = tray;
    bad["point"] = {0, "x", 0};
    CHECK(parse_error(with_plane(bad)).find("planes[0].point[1]: must be a number") != std::string::npos);
    bad = tray;
    bad["friction"] = -0.5;
    CHECK(parse_error(with_plane(bad)).find("planes[0].friction: must be in") != std::string::npos);
    bad = tray;
    bad["static_friction"] = "high";
    CHECK(parse_error(with_plane(bad)).find("planes[0].static_friction: must be a number") != std::string::npos);
    bad = tray;
    bad["frction"] = 0.5;
    CHECK(parse_error(with_plane(bad)).find("planes[0].frction: unknown key") != std::string::npos);
    bad = tray;
    bad.erase("normal");
    CHECK(parse_error(with_plane(bad)).find("planes[0].normal: missing") != std::string::npos);
    CHECK(parse_error(json{{"mesh", "m.obj"}, {"planes", tray}}).find("planes: must be an array") != std::string::npos);
    CHECK(parse_error(json{{"mesh", "m.obj"}, {"planes", {tray, 3}}}).find("planes[1]: must be an object") !=
          std::string::npos);
    // Piece-piece contact: on by default, switchable, friction >= 0.
    CHECK(parse_scene(json{{"mesh", "m.obj"}}, "s.json").pbd.piece_contact);
    CHECK_FALSE(parse_scene(json{{"mesh", "m.obj"}, {"contact", {{"pieces", false}}}}, "s.json").pbd.piece_contact);
    CHECK(parse_error(json{{"mesh", "m.obj"}, {"contact", {{"pieces", 1}}}}).find("contact.pieces: must be true or false") !=
          std::string::npos);
    CHECK(parse_error(json{{"mesh", "m.obj"}, {"contact", {{"friction", -1}}}}).find("contact.friction: must be in") !=
          std::string::npos);
  }

  TEST_CASE("the grab block: defaults for the liver, validated, scaled into metres, round-tripped") {
    // Defaults: 500 N/m, 15 mm, 30 N; no block: the key is left out of the JSON (older headers stay).
    const Scene plain = parse_scene(json{{"mesh", "m.obj"}}, "s.json");
    CHECK(plain.grab.stiffness == 500.0);
    CHECK(plain.grab.radius == 0.015);
    CHECK(plain.grab.force_limit == 30.0);
    CHECK_FALSE(scene_to_json(plain).contains("grab"));
    const Scene scene = parse_scene(json{{"mesh", "m.obj"}, {"units", {{"metres_per_unit", 0.01}}},
                                         {"grab", {{"stiffness", 800}, {"radius", 2}, {"force_limit", 0}}}},
                                    "s.json");
    CHECK(scene.grab.stiffness == 800.0);
    CHECK(scene.grab.radius == doctest::Approx(0.02));  // a length: scaled like the others
    CHECK(scene.grab.force_limit == 0.0);                // no limit
    const Scene again = parse_scene(scene_to_json(scene), "s.json");
    CHECK(again.grab.stiffness == 800.0);
    CHECK(again.grab.radius == scene.grab.radius);
    CHECK(again.grab.force_limit == 0.0);
    // Bad values: one line naming the key.
    const auto grab = [](json g) { return parse_error(json{{"mesh", "m.obj"}, {"grab", g}}); };
    CHECK(grab({{"stiffness", 0}}).find("grab.stiffness: must be positive") != std::string::npos);
    CHECK(grab({{"stiffness", -5}}).find("grab.stiffness: must be in") != std::string::npos);
    CHECK(grab({{"stiffness", "stiff"}}).find("grab.stiffness: must be a number") != std::string::npos);
    CHECK(grab({{"radius", -1}}).find("grab.radius: must be in") != std::string::npos);
    CHECK(grab({{"force_limit", -1}}).find("grab.force_limit: must be in") != std::string::npos);
    CHECK(grab({{"strength", 7}}).find("grab.strength: unknown key") != std::string::npos);
    CHECK(grab(5).find("grab: must be an object") != std::string::npos);
  }

  TEST_CASE("a scene round-trips through JSON") {
    Scene scene = parse_scene(json{{"mesh", "m.obj"}, {"resolution", 64}, {"sim_resolution", 8}}, "s.json");
    scene.pbd.fixed.push_back({Vec3d(0, 0, 0), Vec3d(1, 1, 1)});
    CHECK_FALSE(scene_to_json(scene).contains("planes"));  // no planes: the key is left out
    scene.pbd.planes.push_back({Vec3d(0, -1, 0), Vec3d(0, 0.6, 0.8), /*static*/ 0.4, /*kinetic*/ 0.3});
    const Scene again = parse_scene(scene_to_json(scene), "s.json");
    REQUIRE(again.pbd.planes.size() == 1);
    CHECK(again.pbd.planes[0].normal.isApprox(scene.pbd.planes[0].normal));
    CHECK(again.pbd.planes[0].kinetic_friction == 0.3);
    CHECK(again.pbd.planes[0].static_friction == 0.4);
    CHECK(again.pbd.resolution == 64);
    CHECK(again.pbd.sim_resolution == 8);
    CHECK(again.pbd.fixed.size() == 1);
    CHECK(again.pbd.dt == scene.pbd.dt);
  }

  TEST_CASE("a physical material selects the material model, and units scale every length into metres") {
    const Scene scene = parse_scene(json{{"mesh", "m.obj"},
                                         {"units", {{"metres_per_unit", 0.01}}},
                                         {"material", {{"youngs_modulus", 5400}, {"poisson_ratio", 0.47}, {"density", 1060}}},
                                         {"fixed", {{{"box", {{0, 0, 0}, {10, 20, 30}}}}}},
                                         {"scalpel", {{"length", 50}}},
                                         {"planes", {{{"point", {0, 100, 0}}, {"normal", {0, 1, 0}}}}}},
                                    "s.json");
    CHECK(scene.pbd.elastic == ElasticModel::kNeoHookean);
    CHECK(scene.pbd.youngs_modulus == 5400);
    CHECK(scene.pbd.poisson_ratio == 0.47);
    CHECK(scene.pbd.density == 1060);
    CHECK(scene.metres_per_unit == 0.01);
    CHECK(scene.pbd.fixed[0].max.z() == doctest::Approx(0.3));
    CHECK(scene.scalpel.length == doctest::Approx(0.5));
    CHECK(scene.pbd.planes[0].point.y() == doctest::Approx(1.0));
    CHECK(scene.pbd.gravity.y() == doctest::Approx(-9.81));  // m/s^2 whatever the unit
    // The paper's keys keep the paper's model; "model" names either explicitly.
    CHECK(parse_scene(json{{"mesh", "m.obj"}, {"material", {{"shape_stiffness", 0.5}}}}, "s.json").pbd.elastic ==
          ElasticModel::kPaper);
    CHECK(parse_scene(json{{"mesh", "m.obj"}, {"material", {{"model", "neo_hookean"}}}}, "s.json").pbd.elastic ==
          ElasticModel::kNeoHookean);
    // The round trip keeps the model, the material and the lengths (written in metres) exactly.
    const Scene again = parse_scene(scene_to_json(scene), "s.json");
    CHECK(again.pbd.elastic == ElasticModel::kNeoHookean);
    CHECK(again.pbd.youngs_modulus == 5400);
    CHECK(again.metres_per_unit == 0.01);
    CHECK(again.pbd.fixed[0].max == scene.pbd.fixed[0].max);
    CHECK(again.pbd.planes[0].point == scene.pbd.planes[0].point);
    CHECK(again.scalpel.length == scene.scalpel.length);
    // A paper scene's JSON has no units and the paper's keys (recorded headers stay as they were).
    const json paper = scene_to_json(parse_scene(json{{"mesh", "m.obj"}}, "s.json"));
    CHECK_FALSE(paper.contains("units"));
    CHECK(paper["material"].contains("shape_stiffness"));
    CHECK_FALSE(paper["material"].contains("model"));
  }

  TEST_CASE("bad material values and units are errors naming the key") {
    const auto material = [](json m) { return parse_error(json{{"mesh", "m.obj"}, {"material", m}}); };
    CHECK(material({{"poisson_ratio", 0.5}}).find("material.poisson_ratio") != std::string::npos);
    CHECK(material({{"poisson_ratio", -0.2}}).find("material.poisson_ratio") != std::string::npos);
    CHECK(material({{"poisson_ratio", "0.3"}}).find("material.poisson_ratio: must be a number") != std::string::npos);
    CHECK(material({{"youngs_modulus", 0}}).find("material.youngs_modulus") != std::string::npos);
    CHECK(material({{"youngs_modulus", -5}}).find("material.youngs_modulus") != std::string::npos);
    CHECK(material({{"youngs_modulus", 1e15}}).find("material.youngs_modulus") != std::string::npos);
    CHECK(material({{"stiffness_damping", -1}}).find("material.stiffness_damping") != std::string::npos);
    CHECK(material({{"model", "rubber"}}).find("material.model") != std::string::npos);
    CHECK(material({{"youngs_modulus", 5000}, {"shape_stiffness", 0.2}}).find("material.shape_stiffness") != std::string::npos);
    CHECK(material({{"model", "paper"}, {"youngs_modulus", 5000}}).find("material.youngs_modulus") != std::string::npos);
    const auto units = [](json u) { return parse_error(json{{"mesh", "m.obj"}, {"units", u}}); };
    CHECK(units({{"metres_per_unit", 0}}).find("units.metres_per_unit") != std::string::npos);
    CHECK(units({{"metres_per_unit", -1}}).find("units.metres_per_unit") != std::string::npos);
    CHECK(units({{"metre_per_unit", 1}}).find("units.metre_per_unit: unknown key") != std::string::npos);
    CHECK(units({{"scene_lengths", "feet"}}).find("units.scene_lengths") != std::string::npos);
  }

  TEST_CASE("solver.global_step: the material model's global step, validated, round-tripped, absent by default") {
    const json base = {{"mesh", "m.obj"}, {"material", {{"youngs_modulus", 5e6}, {"poisson_ratio", 0.3}}}};
    json on = base;
    on["solver"] = {{"global_step", true}, {"substeps", 1}, {"iterations", 1}};
    const Scene scene = parse_scene(on, "s.json");
    CHECK(scene.pbd.global_step);
    CHECK(parse_scene(scene_to_json(scene), "s.json").pbd.global_step);
    // Off by default, and then absent from the JSON (recorded headers stay as they were).
    const Scene off = parse_scene(base, "s.json");
    CHECK_FALSE(off.pbd.global_step);
    CHECK_FALSE(scene_to_json(off)["solver"].contains("global_step"));
    // Bad values name the key: not a boolean, or the paper's model (it has no hexahedra to solve).
    json bad = base;
    bad["solver"] = {{"global_step", 1}};
    CHECK(parse_error(bad).find("solver.global_step: must be true or false") != std::string::npos);
    CHECK(parse_error(json{{"mesh", "m.obj"}, {"solver", {{"global_step", true}}}}).find("solver.global_step: needs the material model") !=
          std::string::npos);
  }

  TEST_CASE("the liver is a human liver in SI units: ~0.2 m, ~1-2 kg, it hangs from its box onto its tray") {
    const Scene scene = load_scene(dvx_test::source_path("assets/scenes/liver.json"));
    CHECK(scene.pbd.elastic == ElasticModel::kNeoHookean);
    Session session;
    open_session(scene, scene.pbd.dt, true, 1, session);
    const PbdState& s = *session.state.pbd;
    const Aabb bounds = mesh_bounds(session.input.mesh);
    MESSAGE("liver " << bounds.extent().transpose() << " m, " << total_mass(s.model) << " kg");
    CHECK(std::abs(bounds.extent().maxCoeff() / 0.2 - 1.0) < 0.02);  // 0.1996 m
    CHECK(total_mass(s.model) > 1.0);
    CHECK(total_mass(s.model) < 2.0);
    const double mass = total_mass(s.model);
    for (int i = 0; i < 60; ++i) session_step(session, StepCommands());
    CHECK(count_nonfinite(s.model, s.data) == 0);
    CHECK(total_mass(s.model) == mass);
    // The anchored particles stay; the rest sags (down, not away), and the surface stays on the tray
    // (its lowest vertex within a millimetre of it: the contact's resting offset).
    double sag = 0.0, moving = 0.0;
    for (size_t p = 0; p < s.data.position.size(); ++p) {
      if (s.model.refs[p] == 0) continue;
      if (s.model.inv_mass[p] == 0.0) {
        CHECK(s.data.position[p] == s.model.rest[p]);
        continue;
      }
      sag += s.model.mass[p] * (s.model.rest[p].y() - s.data.position[p].y());
      moving += s.model.mass[p];
    }
    const double tray = scene.pbd.planes[0].point.y();
    double lowest = 1e30;
    for (size_t v = 0; v < s.model.embedding.size() && v < s.data.deformed.size(); ++v) {
      if (s.model.embedding[v].sim_voxel != kDeadIndex) lowest = std::min(lowest, double(s.data.deformed[v].y()));
    }
    MESSAGE("mean sag " << sag / moving << " m, lowest surface vertex " << lowest - tray << " m above the tray");
    CHECK(sag / moving > 0.001);
    CHECK(sag / moving < 0.05);
    CHECK(lowest > tray - 0.001);
    CHECK(lowest < tray + 0.005);  // it reached the tray
  }

  // Issue 30: an incision in loaded tissue opens. The liver hangs from its ligaments onto its tray;
  // after it has settled for 1 s, a vertical blade is swept through its depth in half a second just beside the
  // anchored region, from its top down a third of its height: the top of the lobe there is in tension
  // (it bends down from the anchors), so the cut's two faces draw apart.
  TEST_CASE("a cut across the loaded liver gapes within 1 s") {
    const Scene scene = load_scene(dvx_test::source_path("assets/scenes/liver.json"));
    Session session;
    open_session(scene, scene.pbd.dt, true, 1, session);
    for (int i = 0; i < 60; ++i) session_step(session, StepCommands());
    const Aabb b = mesh_bounds(session.input.mesh);
    const Vec3d size = b.extent();
    // The cut plane: a tenth of the liver's width beyond the anchor box's -x face, where the left
    // lobe leaves the anchored region.
    const double x = scene.pbd.fixed[0].min.x() - 0.1 * size.x();
    const double top = b.max.y() + 0.05 * size.y(), bottom = b.max.y() - 0.6 * size.y();
    MESSAGE("bounds " << b.min.transpose() << " .. " << b.max.transpose() << ", anchor box x " << scene.pbd.fixed[0].min.x() << " .. " << scene.pbd.fixed[0].max.x() << ", cut at x " << x);
    // The stroke: 30 steps (half a second) through the liver's depth, then the blade lifted.
    const double z0 = b.min.z() - 0.05 * size.z(), z1 = b.max.z() + 0.05 * size.z();
    uint64_t voxels_cut = 0;
    for (int i = 0; i <= 31; ++i) {
      StepCommands c;
      c.has_blade = true;
      const double z = z0 + (z1 - z0) * std::min(i, 30) / 30.0;
      c.blade = {Vec3d(x, top, z), Vec3d(x, bottom, z)};
      c.cutting = i > 0 && i <= 30;
      voxels_cut += session_step(session, c).cut.voxels_cut;
    }
    CHECK(voxels_cut > 100);
    // The cut's vertices come in twins, one per side, at the same rest point; the incision's width
    // at a twin is the distance between the two deformed positions (0 when the cut is made).
    const auto widths = [&]() {
      const CutSurface& surface = session.state.cut.surface;
      const PbdState& s = *session.state.pbd;
      std::map<std::array<float, 3>, std::vector<uint32_t>> at;
      for (size_t t = 0; t < surface.triangles.size(); ++t) {
        const Tri& tri = surface.triangles[t];
        if (!surface.triangle_cut[t] || tri[0] >= surface.positions.size()) continue;
        for (uint32_t v : tri) {
          const Vec3f& p = surface.positions[v];
          std::vector<uint32_t>& slots = at[{p.x(), p.y(), p.z()}];
          if (std::find(slots.begin(), slots.end(), v) == slots.end()) slots.push_back(v);
        }
      }
      std::vector<double> w;
      for (const auto& [point, slots] : at) {
        if (slots.size() == 2) w.push_back((s.data.deformed[slots[0]] - s.data.deformed[slots[1]]).norm());
      }
      std::sort(w.begin(), w.end());
      return w;
    };
    const auto quantile = [](const std::vector<double>& w, double q) { return w[size_t(q * double(w.size() - 1))]; };
    const std::vector<double> at_cut = widths();
    REQUIRE(at_cut.size() > 100);
    for (int i = 0; i < 60; ++i) session_step(session, StepCommands());
    const std::vector<double> after = widths();
    REQUIRE(after.size() > 100);
    MESSAGE("cut " << voxels_cut << " voxels, " << after.size() << " twin vertices; the incision's width: median "
                   << 1e3 * quantile(at_cut, 0.5) << " mm at the stroke's end, median / p90 " << 1e3 * quantile(after, 0.5)
                   << " / " << 1e3 * quantile(after, 0.9) << " mm 1 s later");
    CHECK(count_nonfinite(session.state.pbd->model, session.state.pbd->data) == 0);
    CHECK(quantile(after, 0.5) > 0.001);  // open by more than a millimetre
    CHECK(quantile(after, 0.5) < 0.05);   // and not a piece that fell away: the lobe still hangs on
    std::vector<Tri> live;
    for (const Tri& t : session.state.cut.surface.triangles) {
      if (t[0] < session.state.cut.surface.positions.size()) live.push_back(t);
    }
    uint32_t components = 0;
    triangle_components(live, uint32_t(session.state.cut.surface.positions.size()), components);
    CHECK(components == 1);
  }
}
