#include "engine/scene.h"

#include "engine/errors.h"

#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <sstream>

namespace dvx {
namespace {

using json = nlohmann::json;

// Reads one object's keys, checking each against the allowed set, with a path for messages.
struct Reader {
  const std::string& file;

  [[noreturn]] void fail(const std::string& key, const std::string& problem) const {
    throw_input(file, key + ": " + problem);
  }

  void check_keys(const json& object, const std::string& where, std::initializer_list<const char*> allowed) const {
    if (!object.is_object()) fail(where.empty() ? "scene" : where, "must be an object");
    for (auto it = object.begin(); it != object.end(); ++it) {
      bool known = false;
      for (const char* name : allowed) known = known || it.key() == name;
      if (!known) {
        std::string list;
        for (const char* name : allowed) list += std::string(list.empty() ? "" : ", ") + name;
        fail(where + (where.empty() ? "" : ".") + it.key(), "unknown key (allowed: " + list + ")");
      }
    }
  }

  double number(const json& value, const std::string& key, double lo, double hi) const {
    if (!value.is_number()) fail(key, "must be a number");
    const double x = value.get<double>();
    if (!std::isfinite(x) || x < lo || x > hi) {
      std::ostringstream range;
      range << "must be in [" << lo << ", " << hi << "], got " << value.dump();
      fail(key, range.str());
    }
    return x;
  }

  int integer(const json& value, const std::string& key, int lo, int hi) const {
    if (!value.is_number_integer()) fail(key, "must be an integer");
    const auto x = value.get<int64_t>();
    if (x < lo || x > hi) {
      fail(key, "must be in [" + std::to_string(lo) + ", " + std::to_string(hi) + "], got " + value.dump());
    }
    return int(x);
  }

  Vec3d vec3(const json& value, const std::string& key, double bound) const {
    if (!value.is_array() || value.size() != 3) fail(key, "must be an array of 3 numbers");
    return Vec3d(number(value[0], key + "[0]", -bound, bound), number(value[1], key + "[1]", -bound, bound),
                 number(value[2], key + "[2]", -bound, bound));
  }
};

bool is_power_of_two(int x) { return x > 0 && (x & (x - 1)) == 0; }

// "planes": [{"point": [x,y,z], "normal": [nx,ny,nz], "friction": mu, "static_friction": mu_s}]; the
// normal is normalised (a zero normal is an error); friction >= 0, static_friction defaults to it.
std::vector<ContactPlane> parse_planes(const Reader& r, const json& planes) {
  if (!planes.is_array()) r.fail("planes", "must be an array of {\"point\": [x,y,z], \"normal\": [nx,ny,nz], \"friction\": f}");
  if (planes.size() > kMaxPlanes) r.fail("planes", "at most " + std::to_string(kMaxPlanes) + " planes");
  std::vector<ContactPlane> out;
  for (size_t i = 0; i < planes.size(); ++i) {
    const std::string key = "planes[" + std::to_string(i) + "]";
    const json& p = planes[i];
    r.check_keys(p, key, {"point", "normal", "friction", "static_friction"});
    ContactPlane plane;
    if (!p.contains("point")) r.fail(key + ".point", "missing (a point on the plane)");
    if (!p.contains("normal")) r.fail(key + ".normal", "missing (the side material stays on)");
    plane.point = r.vec3(p["point"], key + ".point", 1e30);
    const Vec3d normal = r.vec3(p["normal"], key + ".normal", 1e30);
    const double length = normal.norm();
    if (!(length > 1e-12) || !std::isfinite(length)) r.fail(key + ".normal", "must be a non-zero vector");
    plane.normal = normal / length;
    if (p.contains("friction")) plane.kinetic_friction = r.number(p["friction"], key + ".friction", 0.0, 1e3);
    plane.static_friction = plane.kinetic_friction;
    if (p.contains("static_friction")) {
      plane.static_friction = r.number(p["static_friction"], key + ".static_friction", 0.0, 1e3);
    }
    out.push_back(plane);
  }
  return out;
}

// Length unit: the mesh's (and, unless they are metres already, the scene's lengths'). Returns the
// factor that takes the scene's lengths into metres.
double parse_units(const Reader& r, const json& u, Scene& scene) {
  r.check_keys(u, "units", {"metres_per_unit", "scene_lengths"});
  if (u.contains("metres_per_unit")) {
    scene.metres_per_unit = r.number(u["metres_per_unit"], "units.metres_per_unit", 1e-9, 1e9);
  }
  double scale = scene.metres_per_unit;
  if (u.contains("scene_lengths")) {
    const json& l = u["scene_lengths"];
    if (!l.is_string() || (l != "mesh" && l != "metres")) r.fail("units.scene_lengths", "must be \"mesh\" or \"metres\"");
    if (l == "metres") scale = 1.0;
  }
  return scale;
}

// Material: physical (E, nu, rho: the corotated hexahedra) or the paper's solver knobs.
void parse_material(const Reader& r, const json& m, PbdParams& pbd) {
  r.check_keys(m, "material",
               {"model", "density", "youngs_modulus", "poisson_ratio", "stiffness_damping", "stretch_compliance",
                "shape_stiffness"});
  const bool physical_keys = m.contains("youngs_modulus") || m.contains("poisson_ratio") || m.contains("stiffness_damping");
  const bool paper_keys = m.contains("stretch_compliance") || m.contains("shape_stiffness");
  pbd.elastic = physical_keys ? ElasticModel::kNeoHookean : ElasticModel::kPaper;
  if (m.contains("model")) {
    const json& model = m["model"];
    if (!model.is_string() || (model != "neo_hookean" && model != "paper")) {
      r.fail("material.model", "must be \"neo_hookean\" or \"paper\"");
    }
    pbd.elastic = model == "paper" ? ElasticModel::kPaper : ElasticModel::kNeoHookean;
  }
  const bool physical = pbd.elastic == ElasticModel::kNeoHookean;
  if (physical && paper_keys) {
    r.fail(m.contains("stretch_compliance") ? "material.stretch_compliance" : "material.shape_stiffness",
           "belongs to the paper's model, not to a physical material (youngs_modulus, poisson_ratio)");
  }
  if (!physical && physical_keys) {
    r.fail(m.contains("youngs_modulus") ? "material.youngs_modulus"
           : m.contains("poisson_ratio") ? "material.poisson_ratio"
                                          : "material.stiffness_damping",
           "needs \"model\": \"neo_hookean\" (the paper's model has no Young's modulus)");
  }
  if (m.contains("density")) pbd.density = r.number(m["density"], "material.density", 1e-9, 1e9);
  if (m.contains("youngs_modulus")) {
    pbd.youngs_modulus = r.number(m["youngs_modulus"], "material.youngs_modulus", 1e-3, 1e12);
    if (!(pbd.youngs_modulus > 0.0)) r.fail("material.youngs_modulus", "must be positive (Pa)");
  }
  if (m.contains("poisson_ratio")) {
    // nu < 0 (auxetic) is not modelled: the volume term's lambda would be negative.
    pbd.poisson_ratio = r.number(m["poisson_ratio"], "material.poisson_ratio", 0.0, 0.5);
    if (!(pbd.poisson_ratio < 0.5)) {
      r.fail("material.poisson_ratio", "must be below 0.5 (0.5 is incompressible: use 0.45-0.499 for tissue)");
    }
  }
  if (m.contains("stiffness_damping")) {
    pbd.stiffness_damping = r.number(m["stiffness_damping"], "material.stiffness_damping", 0.0, 10.0);
  }
  if (m.contains("stretch_compliance")) {
    pbd.stretch_compliance = r.number(m["stretch_compliance"], "material.stretch_compliance", 0.0, 1e6);
  }
  if (m.contains("shape_stiffness")) {
    pbd.shape_stiffness = r.number(m["shape_stiffness"], "material.shape_stiffness", 0.0, 1.0);
  }
}

// Anchor boxes: [{"box": [[min], [max]]}, ...].
void parse_fixed(const Reader& r, const json& fixed, std::vector<Aabb>& boxes) {
  if (!fixed.is_array()) r.fail("fixed", "must be an array of {\"box\": [[min],[max]]}");
  for (size_t i = 0; i < fixed.size(); ++i) {
    const std::string key = "fixed[" + std::to_string(i) + "]";
    r.check_keys(fixed[i], key, {"box"});
    const json& box = fixed[i].contains("box") ? fixed[i]["box"] : json();
    if (!box.is_array() || box.size() != 2) r.fail(key + ".box", "must be [[xmin,ymin,zmin],[xmax,ymax,zmax]]");
    Aabb b;
    b.min = r.vec3(box[0], key + ".box[0]", 1e30);
    b.max = r.vec3(box[1], key + ".box[1]", 1e30);
    if ((b.min.array() > b.max.array()).any()) r.fail(key + ".box", "min is greater than max");
    boxes.push_back(b);
  }
}

// The grab tool: stiffness (N/m) > 0, radius (scene lengths) >= 0, force limit (N) >= 0 (0: none).
void parse_grab(const Reader& r, const json& g, Scene::Grab& grab) {
  r.check_keys(g, "grab", {"stiffness", "radius", "force_limit"});
  if (g.contains("stiffness")) {
    grab.stiffness = r.number(g["stiffness"], "grab.stiffness", 0.0, 1e12);
    if (!(grab.stiffness > 0.0)) r.fail("grab.stiffness", "must be positive (N/m)");
  }
  if (g.contains("radius")) grab.radius = r.number(g["radius"], "grab.radius", 0.0, 1e9);
  if (g.contains("force_limit")) grab.force_limit = r.number(g["force_limit"], "grab.force_limit", 0.0, 1e12);
  grab.given = true;
}

// Contact between pieces: on or off, its friction.
void parse_contact(const Reader& r, const json& c, PbdParams& pbd) {
  r.check_keys(c, "contact", {"pieces", "friction"});
  if (c.contains("pieces")) {
    if (!c["pieces"].is_boolean()) r.fail("contact.pieces", "must be true or false");
    pbd.piece_contact = c["pieces"].get<bool>();
  }
  if (c.contains("friction")) pbd.piece_friction = r.number(c["friction"], "contact.friction", 0.0, 1e3);
}

}  // namespace

Scene parse_scene(const json& root, const std::string& file) {
  const Reader r{file};
  r.check_keys(root, "",
               {"mesh", "resolution", "sim_resolution", "units", "material", "solver", "gravity", "fixed", "scalpel", "planes",
                "contact", "grab"});
  Scene scene;
  scene.file = file;

  // Mesh path, relative to the scene file.
  if (!root.contains("mesh")) r.fail("mesh", "missing (the scene needs a mesh file)");
  if (!root["mesh"].is_string() || root["mesh"].get<std::string>().empty()) r.fail("mesh", "must be a non-empty string");
  scene.mesh = root["mesh"].get<std::string>();
  const std::filesystem::path mesh_path(scene.mesh);
  const std::filesystem::path base = file.empty() ? std::filesystem::path() : std::filesystem::path(file).parent_path();
  scene.mesh_path = (mesh_path.is_absolute() ? mesh_path : base / mesh_path).lexically_normal().string();

  PbdParams& pbd = scene.pbd;
  if (root.contains("resolution")) pbd.resolution = r.integer(root["resolution"], "resolution", 1, kMaxResolution);
  if (root.contains("sim_resolution")) {
    pbd.sim_resolution = r.integer(root["sim_resolution"], "sim_resolution", 1, kMaxResolution);
  } else if (pbd.sim_resolution > pbd.resolution) {
    pbd.sim_resolution = pbd.resolution;
  }
  // Simulation voxels hold (2^l)^3 fine voxels.
  if (pbd.resolution % pbd.sim_resolution != 0 || !is_power_of_two(pbd.resolution / pbd.sim_resolution)) {
    r.fail("sim_resolution", "resolution / sim_resolution must be a power of two (resolution " +
                                 std::to_string(pbd.resolution) + ", sim_resolution " +
                                 std::to_string(pbd.sim_resolution) + ")");
  }

  // Length unit: the mesh's (and, unless they are metres already, the scene's lengths').
  double scale = 1.0;
  if (root.contains("units")) scale = parse_units(r, root["units"], scene);
  if (root.contains("material")) parse_material(r, root["material"], pbd);
  if (root.contains("solver")) {
    const json& s = root["solver"];
    r.check_keys(s, "solver", {"dt", "substeps", "iterations", "damping", "global_step"});
    if (s.contains("dt")) pbd.dt = r.number(s["dt"], "solver.dt", 1e-6, 1.0);
    if (s.contains("substeps")) pbd.substeps = r.integer(s["substeps"], "solver.substeps", 1, 1000);
    if (s.contains("iterations")) pbd.iterations = r.integer(s["iterations"], "solver.iterations", 1, 10000);
    if (s.contains("damping")) pbd.damping = r.number(s["damping"], "solver.damping", 0.0, 1.0);
    if (s.contains("global_step")) {
      if (!s["global_step"].is_boolean()) r.fail("solver.global_step", "must be true or false");
      pbd.global_step = s["global_step"].get<bool>();
      if (pbd.global_step && pbd.elastic != ElasticModel::kNeoHookean) {
        r.fail("solver.global_step", "needs the material model (\"material\" with youngs_modulus / poisson_ratio)");
      }
    }
  }
  if (root.contains("gravity")) pbd.gravity = r.vec3(root["gravity"], "gravity", 1e6);
  if (root.contains("fixed")) parse_fixed(r, root["fixed"], pbd.fixed);
  if (root.contains("scalpel")) {
    const json& s = root["scalpel"];
    r.check_keys(s, "scalpel", {"length"});
    if (s.contains("length")) scene.scalpel.length = r.number(s["length"], "scalpel.length", 1e-9, 1e9);
  }
  if (root.contains("planes")) pbd.planes = parse_planes(r, root["planes"]);
  if (root.contains("grab")) parse_grab(r, root["grab"], scene.grab);
  if (root.contains("contact")) parse_contact(r, root["contact"], pbd);
  // Every length into metres (gravity is m/s^2 whatever the unit).
  if (scale != 1.0) {
    for (Aabb& b : pbd.fixed) {
      b.min *= scale;
      b.max *= scale;
    }
    for (ContactPlane& p : pbd.planes) p.point *= scale;
    scene.scalpel.length *= scale;
    if (scene.grab.given) scene.grab.radius *= scale;
  }
  return scene;
}

Scene load_scene(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) throw_input(path, "no such file");
  std::ifstream in(path);
  if (!in) throw_input(path, "cannot be opened for reading");
  json root;
  try {
    root = json::parse(in, nullptr, true, /*ignore_comments=*/true);
  } catch (const json::exception& e) {  // parse_error, or out_of_range for a number like 1e999
    throw_input(path, std::string("malformed JSON: ") + e.what());
  }
  return parse_scene(root, path);
}

json scene_to_json(const Scene& scene) {
  json fixed = json::array();
  const PbdParams& pbd = scene.pbd;
  for (const Aabb& b : pbd.fixed) {
    fixed.push_back({{"box", {{b.min.x(), b.min.y(), b.min.z()}, {b.max.x(), b.max.y(), b.max.z()}}}});
  }
  json planes = json::array();
  for (const ContactPlane& p : pbd.planes) {
    planes.push_back({{"point", {p.point.x(), p.point.y(), p.point.z()}},
                      {"normal", {p.normal.x(), p.normal.y(), p.normal.z()}},
                      {"friction", p.kinetic_friction},
                      {"static_friction", p.static_friction}});
  }
  json out = {{"mesh", scene.mesh},
             {"resolution", pbd.resolution},
             {"sim_resolution", pbd.sim_resolution},
             {"material",
              pbd.elastic == ElasticModel::kNeoHookean
                  ? json{{"model", "neo_hookean"},
                         {"density", pbd.density},
                         {"youngs_modulus", pbd.youngs_modulus},
                         {"poisson_ratio", pbd.poisson_ratio},
                         {"stiffness_damping", pbd.stiffness_damping}}
                  : json{{"density", pbd.density},
                         {"stretch_compliance", pbd.stretch_compliance},
                         {"shape_stiffness", pbd.shape_stiffness}}},
             {"solver", {{"dt", pbd.dt}, {"substeps", pbd.substeps}, {"iterations", pbd.iterations},
                         {"damping", pbd.damping}}},
             {"gravity", {pbd.gravity.x(), pbd.gravity.y(), pbd.gravity.z()}},
             {"fixed", fixed},
             {"scalpel", {{"length", scene.scalpel.length}}}};
  // Absent when empty / default: older recordings keep their header.
  if (scene.metres_per_unit != 1.0) out["units"] = {{"metres_per_unit", scene.metres_per_unit}, {"scene_lengths", "metres"}};
  if (pbd.global_step) out["solver"]["global_step"] = true;
  if (!pbd.planes.empty()) out["planes"] = planes;
  if (scene.grab.given) {
    out["grab"] = {{"stiffness", scene.grab.stiffness}, {"radius", scene.grab.radius}, {"force_limit", scene.grab.force_limit}};
  }
  if (!pbd.piece_contact || pbd.piece_friction != PbdParams{}.piece_friction) {
    out["contact"] = {{"pieces", pbd.piece_contact}, {"friction", pbd.piece_friction}};
  }
  return out;
}

}  // namespace dvx
