// Scene files (JSON, DESIGN §1): which mesh, at which resolution, with which material,
// solver, gravity, anchors, scalpel and contact planes. Only `mesh` is required; unknown keys are errors.
#pragma once

#include "sim/mesh.h"
#include "sim/pbd.h"

#include <nlohmann/json_fwd.hpp>

#include <string>
#include <vector>

namespace dvx {

// A scene: the mesh, the PBD parameters it is simulated with (sim/pbd.h's PbdParams, the one source
// of truth: the session hands them to the model, with the recording's dt), and the scalpel. Keys of
// the file: "resolution", "sim_resolution", "material", "solver" (dt, substeps, iterations, damping),
// "gravity", "fixed" (anchor boxes), "planes" (static contact planes: point, normal, friction =
// kinetic, static_friction) and "contact" (pieces = piece_contact, friction = piece_friction) all
// fill `pbd`. "material" is either a physical one, {"youngs_modulus": Pa, "poisson_ratio": nu,
// "density": kg/m^3, "stiffness_damping": s} (ElasticModel::kNeoHookean, docs/material.md), or the
// paper's solver knobs {"density", "stretch_compliance", "shape_stiffness"} (kPaper); "model":
// "neo_hookean" | "paper" names it explicitly. "units": {"metres_per_unit": s} is the mesh's length
// unit: the mesh, the anchor boxes, the planes' points and the scalpel's length are scaled by s into
// metres at load (gravity is m/s^2 already); "scene_lengths": "metres" says the scene's own lengths are
// metres already (scene_to_json writes them so, so a recording's header reads back exactly).
struct Scene {
  std::string file;        // the scene file ("" when built in code)
  std::string mesh;        // mesh path as written in the file (relative to the scene file)
  std::string mesh_path;   // mesh path resolved against the scene file's folder
  PbdParams pbd;           // resolution, sim_resolution (resolution / sim_resolution = 2^l), material, solver, ...
  struct Scalpel {
    double length = 0.5;   // metres (scaled like every length)
  } scalpel;
  double metres_per_unit = 1.0;  // the mesh file's length unit (the session scales the mesh by it)
  // The window's grab tool (sim/pbd.h "Grab"): the region grab's total stiffness, the radius of the
  // tissue it holds around the picked point, its force limit (0: none). The defaults suit the liver
  // (0.2 m, E 5.4 kPa: a 150 px pull moves the point under the cursor about half the pull at
  // 15-20 N, the tens of newtons of real retraction); `given`: the scene has a "grab" block.
  struct Grab {
    double stiffness = 500.0;   // N/m
    double radius = 0.015;      // metres (scaled like every length)
    double force_limit = 30.0;  // N
    bool given = false;
  } grab;
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
