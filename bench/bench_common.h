// Pieces every `divvox bench` experiment shares (with engine/stats.h and engine/timing.h): the default
// meshes, the cut path (one path in scene units for every resolution), the least-squares line of
// Experiment 2.
#pragma once

#include "engine/stats.h"
#include "engine/timing.h"
#include "sim/cut.h"
#include "sim/mesh.h"
#include "sim/voxel_model.h"

#include <string>
#include <vector>

namespace dvx {

// A shared mesh from ../shared/assets when present, else the shipped bunny.
std::string shared_or_bunny(const std::string& file_name);

// The benchmark cut's blade at step s of `steps`: along z across the whole box, at `height` (fraction
// of the box's y extent), moving along x from 5 % of the box before it to 5 % after it. The blade
// sweeps the plane y = box.min.y + height * extent.y (tools/peers clips with the same plane).
// `axis` (0 x, 1 y, 2 z) names the plane's normal: the blade lies along axis + 1 and moves along
// axis + 2 (mod 3); 1 is the cut above (x: a plane x = const, blade along y, moving along z; z: a
// plane z = const, blade along x, moving along y).
BladePose cut_pose(const Aabb& box, int s, int steps, double height = 0.55, int axis = 1);

// The blade pose with its motion coordinate at `fraction` of the way along the same path (0: before the box).
BladePose cut_pose_at(const Aabb& box, double fraction, double height = 0.55, int axis = 1);

// The voxel model of a mesh at a resolution, refused (InputError naming `path`) before allocating
// when it would not fit in memory.
void voxelize_for_bench(const TriMesh& mesh, const std::string& path, int resolution, VoxelModel& model);

// One step of the benchmark cut: medians over repeats of its phase times, and what it did.
struct CutStepSample {
  double divide_ms = 0, surface_ms = 0, total_ms = 0;
  CutStepStats stats;          // deterministic: the same in every repeat
  uint32_t newly_divided = 0;  // voxels that became divided in this step
};

// The benchmark cut path (cut_pose, plane normal `axis`) in `steps` steps, `repeats` times on a fresh
// state, timed per phase (cut_divide, cut_update_surface). Returns the per-step medians; `state` holds the cut at the end, `init_ms` (when given) the time of each init_cut_state.
std::vector<CutStepSample> time_progressive_cut(const VoxelModel& model, const Aabb& box, int steps, int repeats,
                                                CutState& state, std::vector<double>* init_ms = nullptr, int axis = 1,
                                                const TaskRunner& tasks = {});

// Least-squares line y = intercept + slope * x and its coefficient of determination.
struct LineFit {
  double slope = 0, intercept = 0, r2 = 0;
  size_t samples = 0;
};
LineFit fit_line(const std::vector<double>& x, const std::vector<double>& y);

}  // namespace dvx
