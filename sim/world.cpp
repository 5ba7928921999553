#include "sim/world.h"

#include "sim/state_hash.h"

#include <algorithm>
#include <limits>

namespace dvx {
namespace {

bool same_pose(const BladePose& a, const BladePose& b) { return a.a == b.a && a.b == b.b; }

// The piece a surface point a grab starts at is embedded in: the first piece whose material holds
// the point (world_to_rest), else — a point on the material's boundary may lie just outside every
// piece's material — the piece around the nearest live particle whose corners' centre is nearest
// to it; kDeadIndex without pieces.
uint32_t piece_holding(const VoxelModel& model, const PbdModel& pbd, const PbdData& data, const Vec3d& point) {
  PieceGrid grid;
  Aabb region;
  region.grow(point);
  build_piece_grid(pbd, data, region, pbd.sim_size, pbd.fine_size, grid);
  std::vector<RestHit> hits;
  world_to_rest(model, pbd, grid, point, hits);
  if (!hits.empty()) return hits.front().piece;
  double best = std::numeric_limits<double>::infinity();
  uint32_t nearest = kDeadIndex;
  for (uint32_t p = 0; p < data.position.size(); ++p) {
    const double d = (data.position[p] - point).squaredNorm();
    if (pbd.refs[p] > 0 && d < best) {
      best = d;
      nearest = p;
    }
  }
  best = std::numeric_limits<double>::infinity();
  uint32_t piece = kDeadIndex;
  for (uint32_t slot = 0; slot < pbd.pieces.size() && nearest != kDeadIndex; ++slot) {
    const SimPiece& sp = pbd.pieces[slot];
    if (sp.sim_voxel == kDeadIndex || std::find(sp.particles, sp.particles + 8, nearest) == sp.particles + 8) continue;
    Vec3d centre = Vec3d::Zero();
    for (uint32_t q : sp.particles) centre += data.position[q];
    const double d = (0.125 * centre - point).squaredNorm();
    if (d < best) {
      best = d;
      piece = slot;
    }
  }
  return piece;
}

// The grab's command for this step (before the cut: a grab started this step holds particles the
// cut may duplicate; pbd_apply_cut keeps each on its side).
void apply_grab(const VoxelModel& model, const PbdModel& pbd, PbdData& data, const GrabCommand& grab) {
  if (grab.kind == GrabCommand::kRelease) grab_end(data);
  if (grab.kind != GrabCommand::kTarget) return;
  if (grab_active(data)) {
    grab_move(data, grab.target);
  } else if (grab.stiffness > 0.0) {
    grab_begin_region(pbd, data, grab.target, piece_holding(model, pbd, data, grab.target), grab.stiffness, grab.radius,
                      grab.force_limit);
  } else {
    grab_begin(pbd, data, grab.target, grab.compliance);
  }
}

// The voxels a cutting step refreshed, kept for the stroke's end; their repeats dropped as they pile up.
void remember_stroke_voxels(const std::vector<uint32_t>& changed, WorldState& s) {
  std::vector<uint32_t>& stroke = s.stroke_voxels;
  stroke.insert(stroke.end(), changed.begin(), changed.end());
  if (stroke.size() >= 2 * s.stroke_voxels_unique + 1024) {
    std::sort(stroke.begin(), stroke.end());
    stroke.erase(std::unique(stroke.begin(), stroke.end()), stroke.end());
    s.stroke_voxels_unique = stroke.size();
  }
}

}  // namespace

bool world_init(const WorldModel& model, WorldState& state, std::string& error, const TaskRunner& tasks) {
  state = WorldState();
  init_cut_state(model.voxels, state.cut, {}, tasks);
  if (!model.physics) return true;
  state.pbd.emplace();
  return init_pbd(model.voxels, state.cut, model.params, state.pbd->model, state.pbd->data, error);
}

void world_step(const WorldModel& model, WorldState& s, const StepCommands& commands, const StepContext& context,
                StepReport* out) {
  StepReport local;
  StepReport& report = out ? *out : local;
  report = StepReport();
  report.step = s.step;
  const StepClock& clock = context.clock;
  const BladePose previous = s.blade;
  const bool had_blade = s.have_blade;
  if (commands.has_blade) {
    s.blade = commands.blade;
    s.cutting = commands.cutting;
    s.have_blade = true;
  }
  report.cutting = s.cutting;
  if (s.pbd) apply_grab(model.voxels, s.pbd->model, s.pbd->data, commands.grab);
  if (!(s.cutting && had_blade)) reset_sweep(s.sweep);  // a new cut starts from the blade where it is
  // A stroke through moving tissue that ends (the blade stops cutting) has its seams closed.
  const bool stroke_ends = s.pbd && s.stroke_cutting && !(s.cutting && had_blade);
  s.stroke_cutting = s.cutting && had_blade;

  const double t0 = clock.now();
  // With physics the blade moves relative to the tissue even when it stands still.
  const bool sweeps = s.cutting && had_blade && (s.pbd || !same_pose(previous, s.blade));
  if (sweeps || stroke_ends) {
    if (stroke_ends) {
      cut_close_seams(model.voxels, s.cut, s.stroke_voxels, report.cut);
    } else if (s.pbd) {
      // The world-space sweep mapped into rest space through the deformed pieces, then cut quad by quad.
      map_sweep(model.voxels, s.pbd->model, s.pbd->data, previous, s.blade, s.sweep, &s.sweep_stats);
      report.timings.map_ms = clock.now() - t0;
      uint32_t hits = 0;
      for (const RestQuad& q : s.sweep.quads) {
        cut_divide(model.voxels, s.cut, q.from, q.to, report.cut);
        hits += report.cut.edges_hit;
      }
      report.cut.edges_hit = hits;
    } else {
      cut_divide(model.voxels, s.cut, previous, s.blade, report.cut);
    }
    const double t1 = clock.now();
    cut_update_surface(model.voxels, s.cut, report.cut, context.tasks);
    if (s.pbd && !stroke_ends) remember_stroke_voxels(s.cut.changed_voxels, s);
    const double t2 = clock.now();
    if (s.pbd) report.sim_voxels_cut = pbd_apply_cut(model.voxels, s.cut, s.pbd->model, s.pbd->data, &report.pbd);
    const double t_model = clock.now();
    report.timings.model_ms = t_model - t2;
    report.timings.cut_ms = (t1 - t0) + (t_model - t2);  // map, divide, fine and coarse
    report.timings.surface_ms = t2 - t1;
    if (context.after_cut) context.after_cut(model, s, context.after_cut_user);
  }
  if (s.pbd) {
    const double t3 = clock.now();
    pbd_step(s.cut, s.pbd->model, s.pbd->data, context.tasks, context.embed_surface, &clock,
             &report.timings.contact_ms);
    report.timings.deform_ms = clock.now() - t3;
    report.grab_force_n = s.pbd->data.grab_force.norm();
    report.grab_held = uint32_t(s.pbd->data.grab_particles.size());
    report.grab_anchored = s.pbd->data.grab_anchored;
  }
  report.timings.total_ms = clock.now() - t0;
  if (!s.stroke_cutting) {
    s.stroke_voxels.clear();
    s.stroke_voxels_unique = 0;
  }
  ++s.step;
}

void world_embed(const WorldModel& /*model*/, WorldState& s, const TaskRunner& tasks) {
  if (s.pbd) pbd_embed(s.cut, s.pbd->model, s.pbd->data, tasks);
}

uint64_t world_hash(const WorldState& s) {
  uint64_t h = cut_state_hash(s.cut);
  if (s.pbd) {
    Fnv1a f;
    f.add(h);
    for (size_t p = 0; p < s.pbd->data.position.size(); ++p) {
      if (s.pbd->model.refs[p] > 0) f.bytes(s.pbd->data.position[p].data(), 3 * sizeof(double));
    }
    h = f.value;
  }
  return h;
}

}  // namespace dvx
