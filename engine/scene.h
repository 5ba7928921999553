// Scene files (JSON, DESIGN §1): which mesh, at which resolution, with which material,
// solver, gravity, anchors, scalpel and contact planes. Only `mesh` is required; unknown keys are errors.
#pragma once

#include "sim/mesh.h"

#include <nlohmann/json_fwd.hpp>

#include <string>
#include <vector>

namespace dvx {

struct FixedBox {
  Vec3d min, max;  // particles inside this box are anchored
};

// A static contact plane (a tray, a table): material stays on the side the normal points to.
struct ScenePlane {
  Vec3d point = Vec3d::Zero();
  Vec3d normal = Vec3d(0.0, 1.0, 0.0);  // normalised when read
  double friction = 0.5;                // Coulomb coefficient while sliding (kinetic)
  double static_friction = 0.5;         // while sticking; defaults to `friction`
};

struct Scene {
  std::string file;        // the scene file ("" when built in code)
  std::string mesh;        // mesh path as written in the file (relative to the scene file)
  std::string mesh_path;   // mesh path resolved against the scene file's folder
  int resolution = 128;    // finest voxels along the longest axis
  int sim_resolution = 16;  // simulation voxels along the longest axis; resolution / sim_resolution = 2^l
  struct Material {
    double density = 1000.0;
    double stretch_compliance = 1e-6;
    double shape_stiffness = 1.0;
  } material;
  struct Solver {
    double dt = 1.0 / 60.0;
    int substeps = 1;
    int iterations = 10;
    double damping = 0.01;  // fraction of particle velocity removed per time step (whatever the substeps)
  } solver;
  Vec3d gravity = Vec3d(0.0, -9.81, 0.0);
  std::vector<FixedBox> fixed;
  struct Scalpel {
    double length = 0.5;
  } scalpel;
  std::vector<ScenePlane> planes;
  struct Contact {
    bool pieces = true;     // pieces not joined by material do not pass through each other
    double friction = 0.5;  // Coulomb coefficient between pieces
  } contact;
};

// Bounds on values a scene may hold (also used by the CLI for --resolution).
constexpr int kMaxResolution = 4096;
constexpr size_t kMaxPlanes = 32;  // contact planes per scene

// Reads and validates a scene file. Throws InputError ("FILE: key: problem") for malformed
// JSON (with line), unknown keys, wrong types and out-of-range values.
Scene load_scene(const std::string& path);

// Parses a scene from JSON; `file` names the source in messages and anchors relative paths.
Scene parse_scene(const nlohmann::json& json, const std::string& file);

// The scene as JSON (every key, defaults included): recordings embed it.
nlohmann::json scene_to_json(const Scene& scene);

}  // namespace dvx
