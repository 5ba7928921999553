#include "engine/session.h"

#include "engine/errors.h"
#include "engine/voxelize_job.h"
#include "sim/state_hash.h"
#include "sim/voxelize.h"

#include <chrono>
#include <cstdlib>

namespace dvx {
namespace {


bool same_pose(const BladePose& a, const BladePose& b) { return a.a == b.a && a.b == b.b; }

}  // namespace

PbdParams pbd_params(const Scene& scene, double dt) {
  PbdParams p = scene.pbd;
  p.dt = dt;
  return p;
}

void open_session(const Scene& scene, double dt, bool physics, int workers, Session& s, bool progress) {
  s.scene = scene;
  s.dt = dt;
  s.input = load_mesh(scene.mesh_path, progress);
  check_voxelize_memory(scene.mesh_path, mesh_bounds(s.input.mesh), s.input.mesh.triangles.size(), scene.pbd.resolution);
  VoxelizeParams params;
  params.resolution = scene.pbd.resolution;
  std::string error;
  if (!voxelize(s.input.mesh, params, s.model, error)) throw_input(scene.mesh_path, error);
  const Clock::time_point t0 = Clock::now();
  init_cut_state(s.model, s.cut);
  s.init_ms = ms_between(t0, Clock::now());
  if (physics) {
    s.pbd = std::make_unique<PbdState>();
    if (!init_pbd(s.model, s.cut, pbd_params(scene, dt), *s.pbd, error)) throw_input(scene.file, error);
    // DIVVOX_CHUNK_WORK: the work per chunk of a step's shared batches (sim/pbd.h kDefaultChunkWork;
    // lower splits smaller batches across the workers, the same bits either way).
    if (const char* text = std::getenv("DIVVOX_CHUNK_WORK"); text != nullptr && *text != '\0') {
      char* end = nullptr;
      const unsigned long value = std::strtoul(text, &end, 10);
      if (*end != '\0' || value == 0 || value > 0xffffffffu || text[0] == '-') {
        throw_input("DIVVOX_CHUNK_WORK", std::string("must be a positive integer (instructions per chunk), not '") + text + "'");
      }
      s.pbd->chunk_work = uint32_t(value);
    }
    s.pool = std::make_unique<TaskPool>(workers);
    s.initial_mass = total_mass(*s.pbd);
  }
}

StepReport session_step(Session& s, const StepCommands& commands) {
  StepReport report;
  report.step = s.step;
  const BladePose previous = s.blade;
  const bool had_blade = s.have_blade;
  if (commands.has_blade) {
    s.blade = commands.blade;
    s.cutting = commands.cutting;
    s.have_blade = true;
  }
  report.cutting = s.cutting;
  if (s.pbd) {
    if (commands.grab.kind == GrabCommand::kRelease) grab_end(*s.pbd);
    if (commands.grab.kind == GrabCommand::kTarget) {
      if (s.pbd->grab_particle == ~0u) {
        grab_begin(*s.pbd, commands.grab.target, commands.grab.compliance);
      } else {
        grab_move(*s.pbd, commands.grab.target);
      }
    }
  }
  if (!(s.cutting && had_blade)) reset_sweep(s.sweep);  // a new cut starts from the blade where it is

  const Clock::time_point t0 = Clock::now();
  // With physics the blade moves relative to the tissue even when it stands still.
  if (s.cutting && had_blade && (s.pbd || !same_pose(previous, s.blade))) {
    if (s.pbd) {
      // The world-space sweep mapped into rest space through the deformed pieces.
      const Clock::time_point m0 = Clock::now();
      map_sweep(s.model, *s.pbd, previous, s.blade, s.sweep, &s.sweep_stats);
      s.map_ms += ms_between(m0, Clock::now());
      uint32_t hits = 0;
      for (const RestQuad& q : s.sweep.quads) {
        cut_divide(s.model, s.cut, q.from, q.to, report.cut);
        hits += report.cut.edges_hit;
      }
      report.cut.edges_hit = hits;
    } else {
      cut_divide(s.model, s.cut, previous, s.blade, report.cut);
    }
    const Clock::time_point t1 = Clock::now();
    cut_update_surface(s.model, s.cut, report.cut);
    const Clock::time_point t2 = Clock::now();
    if (s.pbd) report.sim_voxels_cut = pbd_apply_cut(s.model, s.cut, *s.pbd, &report.pbd);
    report.timings.cut_ms = ms_between(t0, t1) + ms_between(t2, Clock::now());  // map, divide, fine and coarse
    report.timings.surface_ms = ms_between(t1, t2);
  }
  if (s.pbd) {
    const Clock::time_point t3 = Clock::now();
    pbd_step(s.cut, *s.pbd, s.pool->runner(), s.embed_surface);
    report.timings.deform_ms = ms_between(t3, Clock::now());
  }
  report.timings.total_ms = ms_between(t0, Clock::now());
  ++s.step;
  return report;
}

void session_embed(Session& s) {
  if (s.pbd && !s.embed_surface) pbd_embed(s.cut, *s.pbd, s.pool->runner());
}

uint64_t session_hash(const Session& s) {
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
