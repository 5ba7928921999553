// divvox_peers bullet: Bullet's soft body (btSoftBody, Debian libbullet-dev) on divvox's own PBD model
// of a scene. The soft body gets the same particles (the simulation grid's live corner particles, at
// their rest positions, with their masses; anchored ones get mass 0), the same links (the stretch
// constraints' particle pairs, at their rest lengths), the same iteration count, time step, damping
// and gravity. Bullet's links alone do not resist shear (a hexahedron of 12 edges folds), so its
// bending links (node pairs two links apart: face and body diagonals) stand in for divvox's shape
// matching. Both run single-threaded from rest for the same simulated time; per step we time (thread CPU time)
// divvox's pbd_step (which also embeds the surface; the embedding alone is timed too) and Bullet's
// predictMotion + solveConstraints + integrateMotion. Sag: the mean drop of the free particles, and
// each run's RMS distance to a converged reference (divvox with many iterations).
#include "tools/peers/peers.h"

#include "engine/errors.h"
#include "engine/output.h"
#include "engine/scene.h"
#include "engine/session.h"
#include "engine/stats.h"
#include "sim/pbd.h"

#include <BulletSoftBody/btSoftBody.h>
#include <BulletSoftBody/btSoftBodyHelpers.h>
#include <LinearMath/btScalar.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <memory>

namespace dvx::peers {
namespace {

// Time per step as the calling thread's CPU time: both run single-threaded on it, and on a shared
// machine wall time counts the other processes too.
double thread_ms() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return 1e3 * double(t.tv_sec) + 1e-6 * double(t.tv_nsec);
}

// The live particles of a PBD model (slots with references), in slot order.
std::vector<uint32_t> live_slots(const PbdModel& s) {
  std::vector<uint32_t> live;
  for (uint32_t p = 0; p < s.refs.size(); ++p) {
    if (s.refs[p] != 0) live.push_back(p);
  }
  return live;
}

// Sag and distance to a reference of one run's final particle positions (live slots order).
struct Shape {
  std::vector<Vec3d> positions;
};

double mean_sag(const PbdModel& s, const std::vector<uint32_t>& live, const Shape& shape) {
  double sum = 0.0;
  uint64_t count = 0;
  for (size_t i = 0; i < live.size(); ++i) {
    if (s.inv_mass[live[i]] == 0.0) continue;
    sum += s.rest[live[i]].y() - shape.positions[i].y();
    ++count;
  }
  return count ? sum / double(count) : 0.0;
}

double rms_distance(const PbdModel& s, const std::vector<uint32_t>& live, const Shape& a, const Shape& b) {
  double sum = 0.0;
  uint64_t count = 0;
  for (size_t i = 0; i < live.size(); ++i) {
    if (s.inv_mass[live[i]] == 0.0) continue;
    sum += (a.positions[i] - b.positions[i]).squaredNorm();
    ++count;
  }
  return count ? std::sqrt(sum / double(count)) : 0.0;
}

// divvox from rest: `steps` steps of one substep at `iterations` (the work Bullet's solver does per
// step: the scene's own substeps would multiply it), without contact (Bullet's collisions are off);
// per-step times and the final particles.
Shape run_divvox(const Session& session, const PbdState& initial, int iterations, int steps,
                 std::vector<double>& step_ms, std::vector<double>& embed_ms) {
  PbdState s = initial;
  s.model.params.iterations = iterations;
  s.model.params.substeps = 1;
  s.model.params.planes.clear();
  s.model.params.piece_contact = false;
  for (int i = 0; i < steps; ++i) {
    const double t0 = thread_ms();
    pbd_step(session.state.cut, s.model, s.data);
    step_ms.push_back(thread_ms() - t0);
  }
  // The embedding alone (pbd_step ends with it), for the PBD-only share.
  for (int i = 0; i < 10; ++i) {
    const double t0 = thread_ms();
    pbd_embed(session.state.cut, s.model, s.data);
    embed_ms.push_back(thread_ms() - t0);
  }
  Shape shape;
  for (uint32_t p : live_slots(s.model)) shape.positions.push_back(s.data.position[p]);
  return shape;
}

// Bullet from rest, the same particles, links and parameters.
Shape run_bullet(const PbdModel& initial, int iterations, int steps, double dt, uint64_t& links,
                 uint64_t& bending_links, std::vector<double>& step_ms) {
  const std::vector<uint32_t> live = live_slots(initial);
  std::vector<int> node_of(initial.refs.size(), -1);
  std::vector<btVector3> x(live.size());
  std::vector<btScalar> m(live.size());
  for (size_t i = 0; i < live.size(); ++i) {
    const Vec3d& r = initial.rest[live[i]];
    node_of[live[i]] = int(i);
    x[i] = btVector3(btScalar(r.x()), btScalar(r.y()), btScalar(r.z()));
    m[i] = initial.inv_mass[live[i]] == 0.0 ? btScalar(0) : btScalar(initial.mass[live[i]]);
  }
  btSoftBodyWorldInfo info;
  const Vec3d& g = initial.params.gravity;
  info.m_gravity = btVector3(btScalar(g.x()), btScalar(g.y()), btScalar(g.z()));
  info.m_sparsesdf.Initialize();
  auto body = std::make_unique<btSoftBody>(&info, int(live.size()), x.data(), m.data());
  // Links: the stretch constraints (rest length from the rest positions, stiffness 1).
  body->m_materials[0]->m_kLST = 1;
  links = 0;
  for (int c = 0; c < kColourGroups; ++c) {
    for (const StretchConstraint& k : initial.stretch_groups[c]) {
      body->appendLink(node_of[k.a], node_of[k.b], nullptr, false);
      ++links;
    }
  }
  body->generateBendingConstraints(2, body->m_materials[0]);
  bending_links = uint64_t(body->m_links.size()) - links;
  body->m_cfg.piterations = iterations;
  body->m_cfg.kDP = btScalar(initial.params.damping);
  body->m_cfg.collisions = 0;
  for (int i = 0; i < steps; ++i) {
    const double t0 = thread_ms();
    body->predictMotion(btScalar(dt));
    body->solveConstraints();
    body->integrateMotion();
    step_ms.push_back(thread_ms() - t0);
  }
  Shape shape;
  for (int i = 0; i < body->m_nodes.size(); ++i) {
    const btVector3& p = body->m_nodes[i].m_x;
    shape.positions.emplace_back(p.x(), p.y(), p.z());
  }
  return shape;
}

}  // namespace

std::string run_bullet(const BulletOptions& options) {
  const Scene scene = load_scene(options.scene);
  make_output_dir(options.out_dir);
  const double dt = scene.pbd.dt;
  Session session;
  open_session(scene, dt, true, 1, session);
  const PbdState initial = *session.state.pbd;
  const std::vector<uint32_t> live = live_slots(initial.model);
  const int steps = std::max(1, int(std::lround(options.seconds / dt)));

  // The converged reference: divvox at many iterations.
  std::vector<double> ref_ms, ref_embed_ms;
  const Shape reference = run_divvox(session, initial, options.reference_iterations, steps, ref_ms, ref_embed_ms);
  const double reference_sag = mean_sag(initial.model, live, reference);

  nlohmann::json rows = nlohmann::json::array();
  std::vector<CsvRow> csv_rows;
  for (int iterations : options.iterations) {
    std::vector<double> divvox_ms, embed_ms, bullet_ms;
    const Shape ours = run_divvox(session, initial, iterations, steps, divvox_ms, embed_ms);
    uint64_t links = 0, bending = 0;
    const Shape theirs = run_bullet(initial.model, iterations, steps, dt, links, bending, bullet_ms);
    const double embed = median(embed_ms);
    const double divvox_pbd = std::max(0.0, median(divvox_ms) - embed);
    const nlohmann::json row = {{"iterations", iterations},
                                {"steps", steps},
                                {"divvox_step_ms_p50", median(divvox_ms)},
                                {"divvox_step_ms_p99", quantile(divvox_ms, 0.99)},
                                {"divvox_embed_ms_p50", embed},
                                {"divvox_pbd_ms_p50", divvox_pbd},
                                {"bullet_step_ms_p50", median(bullet_ms)},
                                {"bullet_step_ms_p99", quantile(bullet_ms, 0.99)},
                                {"speedup_pbd", divvox_pbd > 0 ? median(bullet_ms) / divvox_pbd : 0.0},
                                {"divvox_sag", mean_sag(initial.model, live, ours)},
                                {"bullet_sag", mean_sag(initial.model, live, theirs)},
                                {"reference_sag", reference_sag},
                                {"divvox_rms_to_reference", rms_distance(initial.model, live, ours, reference)},
                                {"bullet_rms_to_reference", rms_distance(initial.model, live, theirs, reference)},
                                {"bullet_links", links},
                                {"bullet_bending_links", bending}};
    rows.push_back(row);
    CsvRow csv;
    for (const auto& [key, value] : row.items()) csv.add(key, value.get<double>());
    csv_rows.push_back(std::move(csv));
  }

  const nlohmann::json report = {{"tool", "bullet_softbody"},
                                 {"bullet_version", BT_BULLET_VERSION},
                                 {"bullet_double_precision", sizeof(btScalar) == 8},
                                 {"scene", options.scene},
                                 {"particles", live.size()},
                                 {"pieces", live_pieces(initial.model)},
                                 {"stretch_constraints", stretch_count(initial.model)},
                                 {"dt", dt},
                                 {"seconds", options.seconds},
                                 {"threads", 1},
                                 {"time", "thread CPU time per step"},
                                 {"reference_iterations", options.reference_iterations},
                                 {"reference_step_ms_p50", median(ref_ms)},
                                 {"sag_unit", "mean drop of the free particles (scene units)"},
                                 {"rows", rows},
                                 {"status", "ok"}};
  const std::filesystem::path out(options.out_dir);
  write_json_file((out / "peers_bullet.json").string(), report);
  write_text_file((out / "peers_bullet.csv").string(), csv_text(csv_rows));
  return (out / "peers_bullet.json").string();
}

}  // namespace dvx::peers
