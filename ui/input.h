// The window's input mapping as plain maths (no GL, no GLFW, no ImGui), unit-tested without a
// window: the cursor ray, surface picking, the scalpel's pose, the orbit camera's mouse moves, the
// grab's drag, and the validation of the scene panel's edits.
#pragma once

#include "engine/scene.h"
#include "render/camera.h"
#include "sim/blade_sweep.h"

#include <Eigen/Core>

#include <string>
#include <vector>

namespace dvx {

struct Ray {
  Vec3f origin = Vec3f::Zero();
  Vec3f direction = Vec3f(0, 0, -1);  // unit
};

// The ray from the eye through a pixel (image coordinates: x right, y down, origin top-left).
Ray cursor_ray(const Camera& camera, const Viewport& viewport, const Eigen::Vector2f& pixel);

// Surface picking: the nearest triangle the ray crosses (either side; Moller-Trumbore) among live
// slots (kDeadIndex and non-finite corners skipped). Triangles whose flags share a bit with
// `skip_flags` are ignored (during a drag the scalpel ignores cut faces, so it does not dive into
// the slit it just opened). `facing` keeps only the triangles the ray enters the tissue through
// (kEntering: their outward normal against the ray) or leaves it through (kLeaving). False when the ray
// hits nothing in front of `t_min`.
enum class Facing : uint8_t { kBoth, kEntering, kLeaving };
struct SurfaceHit {
  float t = 0.0f;        // distance along the ray
  uint32_t triangle = 0;  // slot
  Vec3f point = Vec3f::Zero();
};
// `scratch` (optional) keeps the per-vertex buffer between calls (the window picks every frame).
bool pick_surface(const Ray& ray, const std::vector<Vec3f>& positions, const std::vector<Tri>& triangles,
                  const std::vector<uint8_t>& flags, uint8_t skip_flags, float t_min, SurfaceHit& hit,
                  std::vector<Eigen::Vector2f>* scratch = nullptr, Facing facing = Facing::kBoth);

// Off the tissue: the depth along the ray of the surface vertex that appears nearest to it on screen
// (the smallest angle from the ray; live triangles' corners in front of `t_min`). A scalpel that
// starts beside the organ then stands at the depth of the tissue it is about to enter, and sweeps into
// it sideways instead of diving in from the front. False when no vertex is in front.
bool nearest_surface_depth(const Ray& ray, const std::vector<Vec3f>& positions, const std::vector<Tri>& triangles,
                           float t_min, float& t);

// The scalpel aimed at a surface point: the blade enters at `entry` (on the surface under the
// cursor) and goes `depth` into the tissue along the cursor ray tilted by `tilt` radians toward the
// bottom of the screen (a pen-held scalpel: tilted, the blade's depth shows on screen; untilted it
// would be seen end-on). The sweep starts `lead` before the entry, so the surface itself is cut.
BladePose scalpel_pose(const Camera& camera, const Ray& ray, const Vec3f& entry, double depth, double lead,
                       float tilt = 0.35f);

// The tissue under a ray, as the window aims the scalpel at it (every frame of a stroke, and at each
// sample of a fast drag's path): the entry is the first face the ray meets — while `dragging`, the
// first outer face it enters through (cut faces skipped: through the slit the blade opens the ray
// crosses cut faces and then the tissue's far side from within, and taking either as the entry would
// move the blade deep behind the surface it cuts). `exit` is the far side under the entry: from it
// along the blade's line (scalpel_pose), the first face the blade leaves through (the same faces
// skipped); `through` is its distance plus `voxel`, so a blade that reaches it cuts what it crosses
// (0: it leaves nowhere, `exits` false). `hit` false: nothing under the ray.
struct TissueUnderRay {
  bool hit = false, exits = false;
  SurfaceHit entry, exit;
  float through = 0.0f;
};
TissueUnderRay tissue_under_ray(const Camera& camera, const Ray& ray, const std::vector<Vec3f>& positions,
                                const std::vector<Tri>& triangles, const std::vector<uint8_t>& flags, bool dragging,
                                float voxel, std::vector<Eigen::Vector2f>* scratch = nullptr);

// How far past the far side of the tissue the blade reaches, in fine voxels. More than one: the aim
// reads a snapshot a few frames old (input to cut ~3.5 frames) while a hanging lobe moves a voxel or
// two, and a blade that stopped a voxel past the far side it saw left the far side's last voxels
// uncut, a hairline that kept the lobe on (docs/cutting.md).
constexpr float kReachPastFarSide = 3.0f;

// A stroke whose cursor has left the tissue keeps its depth and reach (the window's aim), but tissue
// can still lie along the blade's own line past the kept reach: a hanging lobe swinging under the
// blade, or the far side of the tissue the stroke is leaving (the window left a lobe on by a hairline
// there: docs/cutting.md). The pose lengthened along its line to kReachPastFarSide voxels past the far side of the
// first tissue its line enters within its length (outer faces, cut faces skipped), by at most
// `max_extra`; unchanged where its line enters no tissue within its length or already reaches past.
BladePose reach_through_along_blade(const BladePose& pose, const std::vector<Vec3f>& positions,
                                    const std::vector<Tri>& triangles, const std::vector<uint8_t>& flags, double voxel,
                                    double max_extra, std::vector<Eigen::Vector2f>* scratch = nullptr);

// A fast drag (issue 29): between two frames the blade sweeps the straight ruled quad from `from` to
// `to`; under a curved surface its top dips below the tissue the cursor crossed between the frames,
// which stays uncut (an incision of dashes). The screen path between `from_pixel` and `to_pixel` is
// sampled (every `step_pixels`, at most `max_samples`); at each sample the scalpel is aimed as at a
// frame (entry: the outer face the ray enters through, cut faces skipped; reach: `depth` or through
// the tissue plus `voxel`). The returned pose is `to` lengthened along its own line, its top raised and
// its tip lowered, just enough that the sweep from `from` passes `voxel` above every sampled entry and
// reaches every sampled reach: the stroke cuts along the surface the cursor crossed. A sample the
// sweep meets too early in its course (under 10 % of it) is left to the previous sweep.
struct CoverStats {
  uint32_t samples = 0, hits = 0;   // path samples, and those over the tissue
  double raised = 0.0, lowered = 0.0;  // how far the top was raised and the tip lowered
};
BladePose cover_crossed_path(const Camera& camera, const Viewport& viewport, const Eigen::Vector2f& from_pixel,
                             const Eigen::Vector2f& to_pixel, const BladePose& from, const BladePose& to,
                             const std::vector<Vec3f>& positions, const std::vector<Tri>& triangles,
                             const std::vector<uint8_t>& flags, double depth, double voxel,
                             std::vector<Eigen::Vector2f>* scratch = nullptr, CoverStats* stats = nullptr,
                             float step_pixels = 12.0f, uint32_t max_samples = 8);

// Camera moves by mouse. Orbit: yaw/pitch by pixels dragged (pitch kept within +-89 degrees);
// target and distance unchanged. Pan: the target moves in the view plane so the point under the
// cursor at the target's depth follows the cursor; distance and angles unchanged. Zoom: distance
// times `factor` (clamped), target and angles unchanged; clip planes follow (object radius `radius`).
void camera_orbit(Camera& camera, float dx_pixels, float dy_pixels, float radians_per_pixel = 0.006f);
void camera_pan(Camera& camera, const Viewport& viewport, float dx_pixels, float dy_pixels);
void camera_zoom(Camera& camera, float factor, float radius);

// Where a grabbed point goes when the cursor moves: the point of the cursor ray at the same view
// depth as `anchor` (the drag stays in the camera plane through the picked point).
Vec3f drag_target(const Camera& camera, const Viewport& viewport, const Eigen::Vector2f& pixel, const Vec3f& anchor);

// The scene panel's editable values. The material is one of the scene file's two models: a physical
// material (`physical`: E in Pa, nu, Rayleigh damping in s; the corotated hexahedra) or the paper's
// stretch + shape matching (its solver knobs); the panel shows and writes the chosen model's keys.
struct SceneEdit {
  char mesh[512] = {};
  int resolution = 128;
  int sim_resolution = 16;
  bool physical = false;
  double youngs_modulus = 5000.0, poisson_ratio = 0.45, stiffness_damping = 0.0;
  bool global_step = false;  // the material model's global step (stiff materials)
  double density = 1000.0, stretch_compliance = 1e-6, shape_stiffness = 1.0;
  double dt = 1.0 / 60.0;
  int substeps = 1, iterations = 10;
  double damping = 0.01;
  double gravity[3] = {0.0, -9.81, 0.0};
  double scalpel_length = 0.5;
};
SceneEdit scene_edit_of(const Scene& scene);
// The scene with the edits applied, validated by the scene file's own rules (parse_scene): false
// with the reason ("sim_resolution: ...") when a value is out of range.
bool apply_scene_edit(const Scene& base, const SceneEdit& edit, Scene& out, std::string& error);

}  // namespace dvx
