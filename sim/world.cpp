#include "sim/world.h"

#include "sim/state_hash.h"

#include <algorithm>

namespace dvx {
namespace {

bool same_pose(const BladePose& a, const BladePose& b) { return a.a == b.a && a.b == b.b; }

// The grab's command for this step (before the cut: a grab started this step holds a particle the
// cut may duplicate; pbd_apply_cut keeps it on its side).
void apply_grab(PbdState& pbd, const GrabCommand& grab) {
  if (grab.kind == GrabCommand::kRelease) grab_end(pbd);
  if (grab.kind == GrabCommand::kTarget) {
    if (pbd.grab_particle == ~0u) {
      grab_begin(pbd, grab.target, grab.compliance);
    } else {
      grab_move(pbd, grab.target);
    }
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

bool world_init(const WorldModel& model, WorldState& state, std::string& error) {
  state = WorldState();
  init_cut_state(model.voxels, state.cut);
  if (!model.physics) return true;
  state.pbd.emplace();
  return init_pbd(model.voxels, state.cut, model.params, *state.pbd, error);
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
  if (s.pbd) apply_grab(*s.pbd, commands.grab);
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
      map_sweep(model.voxels, *s.pbd, previous, s.blade, s.sweep, &s.sweep_stats);
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
    cut_update_surface(model.voxels, s.cut, report.cut);
    if (s.pbd && !stroke_ends) remember_stroke_voxels(s.cut.changed_voxels, s);
    const double t2 = clock.now();
    if (s.pbd) report.sim_voxels_cut = pbd_apply_cut(model.voxels, s.cut, *s.pbd, &report.pbd);
    const double t_model = clock.now();
    report.timings.model_ms = t_model - t2;
    report.timings.cut_ms = (t1 - t0) + (t_model - t2);  // map, divide, fine and coarse
    report.timings.surface_ms = t2 - t1;
    if (context.after_cut) context.after_cut(model, s, context.after_cut_user);
  }
  if (s.pbd) {
    const double t3 = clock.now();
    pbd_step(s.cut, *s.pbd, context.tasks, context.embed_surface, &clock, &report.timings.contact_ms);
    report.timings.deform_ms = clock.now() - t3;
  }
  report.timings.total_ms = clock.now() - t0;
  if (!s.stroke_cutting) {
    s.stroke_voxels.clear();
    s.stroke_voxels_unique = 0;
  }
  ++s.step;
}

void world_embed(const WorldModel& /*model*/, WorldState& s, const TaskRunner& tasks) {
  if (s.pbd) pbd_embed(s.cut, *s.pbd, tasks);
}

uint64_t world_hash(const WorldState& s) {
  uint64_t h = cut_state_hash(s.cut);
  if (s.pbd) {
    Fnv1a f;
    f.add(h);
    for (size_t p = 0; p < s.pbd->position.size(); ++p) {
      if (s.pbd->refs[p] > 0) f.bytes(s.pbd->position[p].data(), 3 * sizeof(double));
    }
    h = f.value;
  }
  return h;
}

}  // namespace dvx
