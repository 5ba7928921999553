#include "bench/bench_elastic.h"

#include "bench/bench.h"
#include "engine/errors.h"
#include "engine/mesh_io.h"
#include "engine/output.h"
#include "engine/scene.h"
#include "engine/stats.h"
#include "engine/task_pool.h"
#include "engine/timing.h"
#include "harness/plot.h"
#include "sim/shapes.h"
#include "sim/voxelize.h"
#include "sim/world.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <sstream>

namespace dvx {
namespace {

namespace fs = std::filesystem;

// The bar of the beam cases: 0.2 x 0.025 x 0.025 m (L/H = 8: H is a whole number of fine voxels at
// every power-of-two resolution from 8).
constexpr double kBarL = 0.2, kBarH = 0.025;

// Rayleigh stiffness damping of the settle (s): a damping ratio of beta omega / 2, about 0.4 on the
// cantilever's first mode (44 rad/s), less on the softer cases, whose averaging window does the rest.
constexpr double kStiffnessDamping = 0.02;

// The compared displacement is the mean over the last quarter of the run: the settled state when
// the run is damped, the equilibrium the motion swings about when it is not yet.
constexpr double kAveragedFraction = 0.25;

// A slab around the plane `axis` = at, half a fine voxel thick on each side, unbounded otherwise.
Aabb slab(int axis, double at, double half) {
  Aabb b;
  b.min = Vec3d::Constant(-1e9);
  b.max = Vec3d::Constant(1e9);
  b.min[axis] = at - half;
  b.max[axis] = at + half;
  return b;
}

// The half-space `axis` <= at (or >= at).
Aabb half_space(int axis, double at, bool below) {
  Aabb b;
  b.min = Vec3d::Constant(-1e9);
  b.max = Vec3d::Constant(1e9);
  (below ? b.max : b.min)[axis] = at;
  return b;
}

// The voxel model of a case (the same one the reference reads its lattice from).
VoxelModel voxelize_case(const ElasticCase& c) {
  VoxelModel model;
  VoxelizeParams params;
  params.resolution = c.resolution;
  std::string error;
  if (!voxelize(c.mesh, params, model, error)) throw std::runtime_error("bench elastic: " + c.name + ": " + error);
  return model;
}

// The bar from x = 0 to L, anchored on the lattice's first plane x = -h (one fine voxel before the
// bar: divvox anchors particles, which sit on simulation-voxel corners; that plane is one for every
// simulation resolution). The reference is clamped at x = 0.
ElasticCase bar_case(const std::string& name, int resolution, double ref_scale) {
  ElasticCase c;
  c.name = name;
  c.resolution = resolution;
  c.mesh = make_box(Vec3d(0.5 * kBarL, 0.5 * kBarH, 0.5 * kBarH), Vec3d(0.5 * kBarL, 0.5 * kBarH, 0.5 * kBarH),
                    Eigen::Matrix3d::Identity());
  const double h = kBarL / resolution;
  c.fixed = {slab(0, -h, 0.5 * h)};
  c.ref_fixed = {half_space(0, 1e-9, true)};
  const int n = std::max(1, int(std::lround(4 * ref_scale)));
  c.ref_cells = {8 * n, n, n};
  c.ref_origin = Vec3d::Zero();
  c.ref_spacing = Vec3d(kBarL / (8 * n), kBarH / n, kBarH / n);
  c.tip = Vec3d(kBarL, 0.5 * kBarH, 0.5 * kBarH);
  return c;
}

// A blade along z across the bar at x, from above the bar down to height y_end (below it: through).
ElasticCase::Cut bar_cut(double x, double y_end) {
  ElasticCase::Cut cut;
  const double m = 0.5 * kBarH;
  cut.a0 = Vec3d(x, kBarH + m, -m);
  cut.b0 = Vec3d(x, kBarH + m, kBarH + m);
  cut.a1 = Vec3d(x, y_end, -m);
  cut.b1 = Vec3d(x, y_end, kBarH + m);
  cut.reference.point = Vec3d(x, 0, 0);
  cut.reference.normal = Vec3d::UnitX();
  cut.reference.box.min = Vec3d(x - 1e-6, y_end, -1e9);
  cut.reference.box.max = Vec3d(x + 1e-6, 1e9, 1e9);
  return cut;
}

// The liver mesh: the shared asset, else the shipped copy.
std::string liver_path() {
  for (const fs::path& p : {fs::path(DIVVOX_SHARED_ASSETS_DEFAULT) / "liver_sofa_smooth.obj",
                           fs::path(DIVVOX_SOURCE_DIR_DEFAULT) / "assets/meshes/liver_sofa_smooth.obj"}) {
    if (fs::exists(p)) return p.string();
  }
  throw_input("liver_sofa_smooth.obj", "no liver mesh in ../shared/assets nor assets/meshes");
}

// Nearest-rank quantile helpers and the vertex normals of the rest surface (area-weighted).
std::vector<Vec3d> rest_normals(const CutSurface& s) {
  std::vector<Vec3d> n(s.positions.size(), Vec3d::Zero());
  for (const Tri& t : s.triangles) {
    if (t[0] == kDeadIndex) continue;
    const Vec3d a = s.positions[t[0]].cast<double>(), b = s.positions[t[1]].cast<double>(),
                c = s.positions[t[2]].cast<double>();
    const Vec3d f = (b - a).cross(c - a);
    for (uint32_t v : t) n[v] += f;
  }
  for (Vec3d& v : n) v = v.norm() > 0.0 ? Vec3d(v.normalized()) : Vec3d::Zero();
  return n;
}

// The world of a case at one configuration: voxels, parameters, then the cut steps.
struct CaseWorld {
  WorldModel model;
  WorldState state;
};

// The material model's own damping (Rayleigh, on the strains: PbdParams::stiffness_damping in seconds)
// when this build's PbdParams has it: `damping` is the paper model's only there. Picked at compile
// time, so the benchmark builds before and after the material model is merged.
template <class P>
auto set_stiffness_damping(P& p, double seconds, int) -> decltype(p.stiffness_damping = seconds, void()) {
  p.stiffness_damping = seconds;
}
template <class P>
void set_stiffness_damping(P&, double, long) {}

PbdParams case_params(const ElasticCase& c, const ElasticRun& run, double damping) {
  PbdParams p;
  p.resolution = c.resolution;
  p.sim_resolution = run.sim_resolution;
  p.substeps = run.substeps;
  p.iterations = run.iterations;
  p.elastic = run.model;
  p.global_step = run.global_step;
  p.youngs_modulus = c.youngs_modulus;
  p.poisson_ratio = c.poisson_ratio;
  p.density = c.density;
  p.gravity = c.gravity;
  p.stretch_compliance = run.stretch_compliance;
  p.shape_stiffness = run.shape_stiffness;
  p.damping = damping;
  set_stiffness_damping(p, damping > 0.0 ? kStiffnessDamping : 0.0, 0);
  p.fixed = c.fixed;
  p.planes.clear();
  p.piece_contact = false;  // the reference has no contact: pieces of a cut may overlap as in it
  return p;
}

void init_world(const ElasticCase& c, const VoxelModel& voxels, const ElasticRun& run, double damping, CaseWorld& w) {
  w.model.voxels = voxels;
  w.model.params = case_params(c, run, damping);
  w.model.physics = true;
  std::string error;
  if (!world_init(w.model, w.state, error)) throw std::runtime_error("bench elastic: " + c.name + ": " + error);
}

// A step with the case's cuts made in the first one (the blade moved to its start, then swept).
void step_world(const ElasticCase& c, CaseWorld& w, const StepContext& context) {
  StepCommands commands;
  if (w.state.step == 0 && !c.cuts.empty()) {
    for (const ElasticCase::Cut& cut : c.cuts) {
      w.state.blade = BladePose{cut.a0, cut.b0};
      w.state.have_blade = true;
      w.state.cutting = false;
      reset_sweep(w.state.sweep);
      commands.has_blade = true;
      commands.blade = BladePose{cut.a1, cut.b1};
      commands.cutting = true;
      world_step(w.model, w.state, commands, context);
    }
    return;
  }
  world_step(w.model, w.state, commands, context);
}

// Whether a simulation resolution divides the fine one by a power of two (what world_init accepts).
bool fits(int resolution, int sim) {
  if (sim < 1 || resolution % sim != 0) return false;
  const int ratio = resolution / sim;
  return (ratio & (ratio - 1)) == 0;
}

}  // namespace

std::vector<std::string> elastic_case_names() {
  return {"cantilever", "soft_bar", "cube", "liver", "bar_cut_half", "bar_cut_through"};
}

ElasticModel elastic_model_of(const std::string& name) {
  if (name == "neo_hookean" || name == "global") return ElasticModel::kNeoHookean;
  if (name == "paper") return ElasticModel::kPaper;
  throw_input("--models", "unknown model '" + name + "' (neo_hookean, global, paper)");
}

const char* elastic_run_model_name(const ElasticRun& run) {
  if (run.model == ElasticModel::kPaper) return "paper";
  return run.global_step ? "global" : "neo_hookean";
}

ElasticCase make_elastic_case(const std::string& name, int resolution, double ref_scale) {
  const int r = resolution > 0 ? resolution : 64;
  if (name == "cantilever") {
    // Small strain: E 5 MPa gives a tip sag of about 4 % of the length (linear reference).
    ElasticCase c = bar_case(name, r, ref_scale);
    c.youngs_modulus = 5e6;
    return c;
  }
  if (name == "soft_bar") {
    // Soft enough to bend far (Euler-Bernoulli would say a sag of the bar's length): NLGEOM + Neo-Hookean.
    ElasticCase c = bar_case(name, r, ref_scale);
    c.youngs_modulus = 2e5;
    c.nlgeom = true;
    c.seconds = 4.0;
    return c;
  }
  if (name == "bar_cut_half") {
    ElasticCase c = bar_case(name, r, ref_scale);
    c.youngs_modulus = 1e6;
    c.nlgeom = true;
    c.increments = 2;
    const double h = kBarL / r;
    c.cuts = {bar_cut(0.5 * kBarL + 0.5 * h, 0.5 * kBarH)};
    return c;
  }
  if (name == "bar_cut_through") {
    // Held at both ends and cut through in the middle: two cantilevers. divvox anchors the particles
    // on and beyond the far end (the first simulation-voxel plane at or past x = L + h).
    ElasticCase c = bar_case(name, r, ref_scale);
    c.youngs_modulus = 1e6;
    c.nlgeom = true;
    c.increments = 2;
    const double h = kBarL / r;
    c.fixed.push_back(half_space(0, kBarL + 0.5 * h, false));
    c.ref_fixed.push_back(half_space(0, kBarL - 1e-9, false));
    c.cuts = {bar_cut(0.5 * kBarL + 0.5 * h, -0.5 * kBarH)};
    c.tip = Vec3d(0.5 * kBarL, 0.5 * kBarH, 0.5 * kBarH);
    return c;
  }
  if (name == "cube") {
    // A 0.1 m cube on its anchored base, compressed by its weight: the bulge follows nu.
    ElasticCase c;
    c.name = name;
    c.resolution = resolution > 0 ? resolution : 32;
    const double a = 0.1, h = a / c.resolution;
    c.mesh = make_box(Vec3d::Constant(0.5 * a), Vec3d::Constant(0.5 * a), Eigen::Matrix3d::Identity());
    c.youngs_modulus = 2e4;
    c.poisson_ratio = 0.3;
    c.nlgeom = true;
    c.fixed = {slab(1, -h, 0.5 * h)};
    c.ref_fixed = {half_space(1, 1e-9, true)};
    const int n = std::max(1, int(std::lround(8 * ref_scale)));
    c.ref_cells = {n, n, n};
    c.ref_spacing = Vec3d::Constant(a / n);
    c.tip = Vec3d(a, a, a);
    return c;
  }
  if (name == "liver") {
    // The window's liver scene (assets/scenes/liver.json) as it ships: its mesh in its units (0.2 m
    // across), its anchors (ligaments and the posterior surface), its material (E, nu, rho).
    const Scene scene = load_scene((fs::path(DIVVOX_SOURCE_DIR_DEFAULT) / "assets/scenes/liver.json").string());
    ElasticCase c;
    c.name = name;
    c.resolution = resolution > 0 ? resolution : 64;
    c.mesh = load_mesh(liver_path()).mesh;
    for (Vec3d& p : c.mesh.positions) p *= scene.metres_per_unit;
    c.fixed = scene.pbd.fixed;
    c.ref_fixed = scene.pbd.fixed;
    c.youngs_modulus = scene.pbd.youngs_modulus;
    c.poisson_ratio = scene.pbd.poisson_ratio;
    c.density = scene.pbd.density;
    c.nlgeom = true;
    c.seconds = 4.0;
    c.ref_from_lattice = true;
    const Aabb b = mesh_bounds(c.mesh);
    c.tip = Vec3d(b.max.x(), b.min.y(), 0.5 * (b.min.z() + b.max.z()));
    // Cells of 4 fine voxels (2 with ref_scale 2), filled from the lattice in solve_reference.
    c.ref_cells = {std::max(1, int(std::lround(ref_scale * c.resolution / 4.0))), 0, 0};
    return c;
  }
  throw_input(name, "unknown elastic case (" + std::string("cantilever, soft_bar, cube, liver, bar_cut_half, bar_cut_through") + ")");
}

ElasticReference solve_reference(const ElasticCase& c, double timeout_seconds, const std::string& keep_dir) {
  ElasticReference ref;
  std::vector<CcxCut> cuts;
  for (const ElasticCase::Cut& cut : c.cuts) cuts.push_back(cut.reference);
  if (c.ref_from_lattice) {
    // The material as divvox counts it: the dual cells of the inside lattice nodes, in cells of
    // `stride` fine voxels whose centres fall on lattice nodes.
    const VoxelModel voxels = voxelize_case(c);
    const Lattice& l = voxels.lattice;
    const int stride = std::max(1, int(std::lround(double(c.resolution) / std::max(1, c.ref_cells[0]))));
    const Vec3d spacing = Vec3d::Constant(stride * l.voxel_size);
    const Vec3d origin = l.origin - 0.5 * spacing;
    const std::array<int, 3> n = {l.nx / stride + 1, l.ny / stride + 1, l.nz / stride + 1};
    const auto inside = [&](const Vec3d& p) {
      const Vec3d f = (p - l.origin) / l.voxel_size;
      const int i = int(std::lround(f.x())), j = int(std::lround(f.y())), k = int(std::lround(f.z()));
      if (i < 0 || j < 0 || k < 0 || i > l.nx || j > l.ny || k > l.nz) return false;
      return voxels.is_inside(l.node(i, j, k));
    };
    ref.mesh = make_hex_mesh(origin, spacing, n, inside, cuts);
  } else {
    ref.mesh = make_hex_mesh(c.ref_origin, c.ref_spacing, c.ref_cells, [](const Vec3d&) { return true; }, cuts);
  }
  CcxProblem p;
  p.youngs_modulus = c.youngs_modulus;
  p.poisson_ratio = c.poisson_ratio;
  p.density = c.density;
  p.gravity = c.gravity;
  p.nlgeom = c.nlgeom;
  p.increments = c.increments;
  p.neo_hookean = c.nlgeom;
  p.fixed = c.ref_fixed;
  ref.result = run_ccx(ref.mesh, ccx_deck(ref.mesh, p), timeout_seconds, keep_dir);
  if (ref.result.ok) interpolate_displacement(ref.mesh, ref.result.displacement, c.tip, ref.tip);
  return ref;
}

ElasticMeasure measure_elastic(const ElasticCase& c, const ElasticReference& reference, const ElasticRun& run) {
  if (!reference.result.ok) throw std::runtime_error("bench elastic: " + c.name + ": no reference: " + reference.result.error);
  const VoxelModel voxels = voxelize_case(c);
  CaseWorld w;
  init_world(c, voxels, run, c.damping, w);
  TaskPool pool(run.workers);
  StepContext context;
  context.tasks = pool.runner();
  const double dt = w.model.params.dt;
  const int steps = std::max(1, int(std::lround(c.seconds / dt)));
  std::vector<double> times;
  // The first step (its cuts, and the solver's caches built once) is not timed: the steady step is.
  step_world(c, w, context);
  const int average_from = steps - std::max(1, int(std::lround(kAveragedFraction * steps)));
  std::vector<Vec3d> mean(w.state.cut.surface.positions.size(), Vec3d::Zero());
  int averaged = 0;
  while (int(w.state.step) < steps) {
    const Clock::time_point t0 = Clock::now();
    step_world(c, w, context);
    times.push_back(ms_between(t0, Clock::now()));
    if (int(w.state.step) <= average_from) continue;
    const std::vector<Vec3f>& deformed = w.state.pbd->data.deformed;
    for (size_t v = 0; v < mean.size() && v < deformed.size(); ++v) mean[v] += deformed[v].cast<double>();
    ++averaged;
  }
  ElasticMeasure m;
  m.step_p50_ms = quantile(times, 0.5);
  m.step_p99_ms = quantile(times, 0.99);
  const PbdState& pbd = *w.state.pbd;
  for (size_t i = 0; i < pbd.model.mass.size(); ++i) m.mass += pbd.model.refs[i] > 0 ? pbd.model.mass[i] : 0.0;
  m.particles = uint32_t(pbd.data.position.size() - pbd.model.free_particles.size());
  // The surface: divvox's displacement at each live vertex against the reference's at its rest point.
  const CutSurface& s = w.state.cut.surface;
  const std::vector<Vec3d> normals = rest_normals(s);
  const double nudge = 0.25 * reference.mesh.spacing.minCoeff();
  double num = 0.0, den = 0.0, tip_d = 1e300;
  for (size_t v = 0; v < s.positions.size(); ++v) {
    if (s.vertex_piece[v] == CutSurface::kFreeKey) continue;
    ++m.vertices;
    const Vec3d rest = s.positions[v].cast<double>();
    const Vec3d u = (averaged > 0 ? Vec3d(mean[v] / averaged) : Vec3d(pbd.data.deformed[v].cast<double>())) - rest;
    m.finite = m.finite && u.allFinite();
    Vec3d u_ref;
    if (!interpolate_displacement(reference.mesh, reference.result.displacement, rest, u_ref, 3, -nudge * normals[v])) continue;
    ++m.compared;
    num += (u - u_ref).squaredNorm();
    den += u_ref.squaredNorm();
    m.max_displacement = std::max(m.max_displacement, u.norm());
    m.ref_max_displacement = std::max(m.ref_max_displacement, u_ref.norm());
    if ((rest - c.tip).squaredNorm() < tip_d) {
      tip_d = (rest - c.tip).squaredNorm();
      m.tip = u;
      m.ref_tip = u_ref;
    }
  }
  m.rms_error = den > 0.0 ? std::sqrt(num / den) : 0.0;
  m.max_error = m.ref_max_displacement > 0.0 ? std::abs(m.max_displacement - m.ref_max_displacement) / m.ref_max_displacement : 0.0;
  if (!m.finite) m.rms_error = m.max_error = std::nan("");
  return m;
}

FrequencyMeasure measure_frequency(const ElasticCase& bar, const ElasticRun& run, double seconds) {
  const VoxelModel voxels = voxelize_case(bar);
  CaseWorld w;
  init_world(bar, voxels, run, 0.0, w);
  StepContext context;
  const double dt = w.model.params.dt;
  const int steps = std::max(2, int(std::lround(seconds / dt)));
  // The free end's mean vertical displacement (surface vertices within two fine voxels of it).
  const CutSurface& s = w.state.cut.surface;
  const double h = kBarL / bar.resolution;
  std::vector<uint32_t> end;
  for (uint32_t v = 0; v < s.positions.size(); ++v) {
    if (s.vertex_piece[v] != CutSurface::kFreeKey && s.positions[v].x() > kBarL - 2 * h) end.push_back(v);
  }
  std::vector<double> y;
  for (int i = 0; i < steps; ++i) {
    step_world(bar, w, context);
    double sum = 0.0;
    for (uint32_t v : end) sum += double(w.state.pbd->data.deformed[v].y() - s.positions[v].y());
    y.push_back(end.empty() ? 0.0 : sum / double(end.size()));
  }
  FrequencyMeasure f;
  // Crossings of the mean (linear interpolation between steps): half periods.
  double mean = 0.0;
  for (double v : y) mean += v / double(y.size());
  double first = -1.0, last = -1.0;
  for (size_t i = 1; i < y.size(); ++i) {
    const double a = y[i - 1] - mean, b = y[i] - mean;
    if ((a < 0.0) == (b < 0.0) || a == b) continue;
    const double t = (double(i - 1) + a / (a - b)) * dt;
    if (first < 0.0) first = t;
    last = t;
    ++f.crossings;
  }
  if (f.crossings >= 3) f.measured_hz = 0.5 * double(f.crossings - 1) / (last - first);
  const double I = std::pow(kBarH, 4) / 12.0, A = kBarH * kBarH;
  f.analytic_hz = (1.875 * 1.875 / (2.0 * M_PI)) *
                  std::sqrt(bar.youngs_modulus * I / (bar.density * A * std::pow(kBarL, 4)));
  return f;
}

namespace {

// The shipped solver's run of the model named `model` at simulation resolution `sim`.
ElasticRun shipped_run(const std::string& model, int sim, const PbdParams& shipped, int workers) {
  ElasticRun run;
  run.model = elastic_model_of(model);
  run.global_step = model == "global";
  run.sim_resolution = sim;
  run.substeps = shipped.substeps;
  run.iterations = shipped.iterations;
  run.stretch_compliance = shipped.stretch_compliance;
  run.shape_stiffness = shipped.shape_stiffness;
  run.workers = workers;
  return run;
}

// A case's configurations, each with its kind: the shipped solver at each simulation resolution that
// fits the case ("defaults") and, with `sweep`, every other substeps x iterations of the options ("sweep").
std::vector<std::pair<ElasticRun, std::string>> elastic_runs(const ElasticCase& c, const std::string& name, bool sweep,
                                                             const std::vector<std::string>& models,
                                                             const PbdParams& shipped, const BenchElasticOptions& options) {
  std::vector<std::pair<ElasticRun, std::string>> runs;
  for (const std::string& model : models) {
    for (int sim : options.sim_resolutions) {
      if (!fits(c.resolution, sim)) {
        std::fprintf(stderr, "divvox: bench elastic: %s: sim %d skipped (resolution %d is not sim x 2^l)\n",
                     name.c_str(), sim, c.resolution);
        continue;
      }
      const ElasticRun d = shipped_run(model, sim, shipped, options.workers);
      runs.push_back({d, "defaults"});
      if (!sweep) continue;
      for (int substeps : options.substeps) {
        for (int iterations : options.iterations) {
          if (substeps == d.substeps && iterations == d.iterations) continue;
          // The global step's answer does not move with the budget (converged at 1 x 1): its sweep
          // stops at 2 x 2, which shows that, instead of paying for 5 x 20 of the same answer.
          if (d.global_step && (substeps > 2 || iterations > 2)) continue;
          ElasticRun r = d;
          r.substeps = substeps;
          r.iterations = iterations;
          runs.push_back({r, "sweep"});
        }
      }
    }
  }
  return runs;
}

// The cantilever's first natural frequency (damping off) at the shipped solver, per model and
// simulation resolution; an empty array when the cantilever is not among the cases.
nlohmann::json frequency_rows(const std::vector<std::string>& cases, const std::vector<std::string>& models,
                              const PbdParams& shipped, const BenchElasticOptions& options) {
  nlohmann::json frequency = nlohmann::json::array();
  if (std::find(cases.begin(), cases.end(), "cantilever") == cases.end()) return frequency;
  const ElasticCase bar = make_elastic_case("cantilever", options.resolution, options.ref_scale);
  for (const std::string& model : models) {
    for (int sim : options.sim_resolutions) {
      if (!fits(bar.resolution, sim)) continue;
      const ElasticRun run = shipped_run(model, sim, shipped, options.workers);
      const FrequencyMeasure f = measure_frequency(bar, run);
      frequency.push_back({{"model", elastic_run_model_name(run)},
                           {"sim_resolution", sim}, {"substeps", run.substeps}, {"iterations", run.iterations},
                           {"measured_hz", f.measured_hz}, {"analytic_hz", f.analytic_hz},
                           {"crossings", f.crossings}});
    }
  }
  return frequency;
}

}  // namespace

std::string bench_elastic(const BenchElasticOptions& options) {
  if (find_ccx().empty()) {
    throw std::runtime_error("bench elastic: ccx (CalculiX) not found: install calculix-ccx (tools/setup.sh) or set DIVVOX_CCX");
  }
  make_output_dir(options.out_dir);
  const fs::path out(options.out_dir);
  const std::vector<std::string> cases = options.cases.empty() ? elastic_case_names() : options.cases;
  const std::vector<std::string>& models = options.models;
  for (const std::string& m : models) elastic_model_of(m);  // a bad name fails before any work
  // The shipped solver (the liver scene's) is each case's "defaults" row.
  PbdParams shipped;
  try {
    shipped = load_scene((fs::path(DIVVOX_SOURCE_DIR_DEFAULT) / "assets/scenes/liver.json").string()).pbd;
  } catch (const std::exception&) {
  }

  std::ostringstream csv;
  csv << "case,model,resolution,sim_resolution,substeps,iterations,step_p50_ms,step_p99_ms,rms_error,max_error,"
         "max_displacement_m,ref_max_displacement_m,tip_dy_m,ref_tip_dy_m,particles,compared_vertices,mass_kg,"
         "ref_elements,ref_seconds,kind\n";
  nlohmann::json rows = nlohmann::json::array(), references = nlohmann::json::array();
  for (const std::string& name : cases) {
    const ElasticCase c = make_elastic_case(name, options.resolution, options.ref_scale);
    if (options.progress) std::fprintf(stderr, "divvox bench elastic: %s: CalculiX reference\n", name.c_str());
    const ElasticReference ref =
        solve_reference(c, options.ccx_timeout, options.keep_ccx.empty() ? std::string() : (fs::path(options.keep_ccx) / name).string());
    references.push_back({{"case", name},
                          {"ok", ref.result.ok},
                          {"error", ref.result.error},
                          {"elements", ref.mesh.elements.size()},
                          {"nodes", ref.mesh.nodes.size()},
                          {"seconds", ref.result.seconds},
                          {"nlgeom", c.nlgeom},
                          {"youngs_modulus", c.youngs_modulus},
                          {"poisson_ratio", c.poisson_ratio},
                          {"density", c.density},
                          {"tip_dy_m", ref.tip.y()}});
    if (!ref.result.ok) {
      std::fprintf(stderr, "divvox: bench elastic: %s: reference failed: %s\n", name.c_str(), ref.result.error.c_str());
      continue;
    }
    // The configurations: the shipped solver at each simulation resolution, and the sweep on the sweep cases.
    const bool sweep = std::find(options.sweep_cases.begin(), options.sweep_cases.end(), name) != options.sweep_cases.end();
    const std::vector<std::pair<ElasticRun, std::string>> runs = elastic_runs(c, name, sweep, models, shipped, options);
    for (const auto& [run, kind] : runs) {
      const char* model = elastic_run_model_name(run);
      if (options.progress) {
        std::fprintf(stderr, "divvox bench elastic: %s %s sim %d %dx%d\n", name.c_str(), model, run.sim_resolution,
                     run.substeps, run.iterations);
      }
      const ElasticMeasure m = measure_elastic(c, ref, run);
      csv << name << ',' << model << ',' << c.resolution << ',' << run.sim_resolution << ',' << run.substeps << ','
          << run.iterations << ',' << m.step_p50_ms << ',' << m.step_p99_ms << ',' << m.rms_error << ',' << m.max_error
          << ',' << m.max_displacement << ',' << m.ref_max_displacement << ',' << m.tip.y() << ',' << m.ref_tip.y() << ','
          << m.particles << ',' << m.compared << ',' << m.mass << ',' << ref.mesh.elements.size() << ','
          << ref.result.seconds << ',' << kind << '\n';
      rows.push_back({{"case", name}, {"model", model}, {"resolution", c.resolution},
                      {"sim_resolution", run.sim_resolution}, {"substeps", run.substeps},
                      {"iterations", run.iterations}, {"step_p50_ms", m.step_p50_ms}, {"step_p99_ms", m.step_p99_ms},
                      {"rms_error", m.rms_error}, {"max_error", m.max_error},
                      {"max_displacement_m", m.max_displacement}, {"ref_max_displacement_m", m.ref_max_displacement},
                      {"tip_dy_m", m.tip.y()}, {"ref_tip_dy_m", m.ref_tip.y()}, {"mass_kg", m.mass},
                      {"particles", m.particles}, {"compared_vertices", m.compared}, {"kind", kind}});
    }
  }
  write_text_file((out / "bench_elastic.csv").string(), csv.str());

  // Dynamics: the cantilever's first natural frequency, damping off, at the shipped solver.
  const nlohmann::json frequency = frequency_rows(cases, models, shipped, options);
  const nlohmann::json results = {
      {"benchmark", "elastic"},
      {"machine", machine_summary()},
      {"workers", options.workers},
      {"shipped",
       {{"scene", "assets/scenes/liver.json"},
        {"model", shipped.elastic == ElasticModel::kNeoHookean ? "neo_hookean" : "paper"},
        {"sim_resolution", shipped.sim_resolution},
        {"substeps", shipped.substeps},
        {"iterations", shipped.iterations},
        {"stretch_compliance", shipped.stretch_compliance},
        {"shape_stiffness", shipped.shape_stiffness}}},
      {"error",
       "relative RMS of |u - u_ref| over |u_ref| on the live surface vertices (u_ref: CalculiX C3D8I, trilinear at "
       "the vertex's rest position); max error: |max|u| - max|u_ref|| / max|u_ref|"},
      {"references", references},
      {"rows", rows},
      {"frequency", frequency}};
  write_json_file((out / "bench_elastic.json").string(), results);
  std::string error;
  if (draw_bench_plot(results, out.string(), error).empty()) {
    std::fprintf(stderr, "divvox: bench_elastic.svg skipped: %s\n", error.c_str());
  }
  return (out / "bench_elastic.csv").string();
}

}  // namespace dvx
