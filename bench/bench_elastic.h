// `divvox bench elastic`: divvox's elasticity against a finite-element reference (CalculiX, bench/ccx.h)
// and against beam theory, and its speed against that error (issue 30). Every divvox run goes through
// world_step on a WorldModel built in code (a box or the liver voxelized at the case's resolution).
//
// The material comes from PbdParams (elastic, youngs_modulus, poisson_ratio, density): with
// ElasticModel::kNeoHookean the solver's stiffness is the material's, with kPaper (the paper's
// stretch + shape matching) it is the solver budget's and the error only says how far that is.
#pragma once

#include "bench/ccx.h"
#include "sim/pbd.h"

#include <string>
#include <vector>

namespace dvx {

// One static problem: geometry, anchors, gravity, material, optional cuts, and its reference mesh.
struct ElasticCase {
  std::string name;
  TriMesh mesh;                 // metres
  int resolution = 64;          // divvox's fine voxels along the longest axis
  double youngs_modulus = 5e6, poisson_ratio = 0.45, density = 1060.0;
  Vec3d gravity = Vec3d(0.0, -9.81, 0.0);
  std::vector<Aabb> fixed;      // divvox's anchored particles (rest positions in a box)
  std::vector<Aabb> ref_fixed;  // the reference's fixed nodes (the same support on the true geometry)
  bool nlgeom = false;          // the reference: geometric nonlinearity + Neo-Hookean material
  int increments = 4;           // with nlgeom: CalculiX's first increment is 1 / increments of the load
  // Cuts: the blade's sweep divvox makes in its first step (a segment from blade_from to blade_to,
  // both poses given as segment ends), and the rectangle the reference meshes.
  struct Cut {
    Vec3d a0, b0, a1, b1;  // blade edge before (a0-b0) and after (a1-b1)
    CcxCut reference;
  };
  std::vector<Cut> cuts;
  // The reference mesh: a grid of cells over `ref_origin`, filled where ref_inside (empty: every cell).
  Vec3d ref_origin = Vec3d::Zero(), ref_spacing = Vec3d::Ones();
  std::array<int, 3> ref_cells = {1, 1, 1};
  bool ref_from_lattice = false;  // cells filled from the fine lattice's inside nodes (a meshed shape)
  double seconds = 3.0;           // simulated time before the comparison (settled with damping)
  double damping = 0.05;          // PbdParams::damping during the settle
  Vec3d tip = Vec3d::Zero();      // a point whose displacement is reported (the free end)
};

// The cases of the benchmark: "cantilever" (small strain, linear), "soft_bar" (bends far:
// NLGEOM + Neo-Hookean), "cube" (compressed under its weight on its fixed base: nu), "liver" (the
// SOFA liver scaled to 0.2 m, hanging from its fixed box), "bar_cut_half" (the cantilever cut
// halfway down at mid-length), "bar_cut_through" (a bar held at both ends, cut through in the middle).
// `resolution` 0: each case's default. Throws InputError for an unknown name or a missing liver mesh.
ElasticCase make_elastic_case(const std::string& name, int resolution = 0, double ref_scale = 1.0);
std::vector<std::string> elastic_case_names();

// The reference's displacements on its mesh.
struct ElasticReference {
  HexMesh mesh;
  CcxResult result;
  Vec3d tip = Vec3d::Zero();  // displacement at the case's tip point
};
ElasticReference solve_reference(const ElasticCase& c, double timeout_seconds = 60.0, const std::string& keep_dir = "");

// The divvox side: one configuration.
struct ElasticRun {
  int sim_resolution = 16, substeps = 5, iterations = 2;
  ElasticModel model = ElasticModel::kNeoHookean;
  bool global_step = false;  // the material model with PbdParams::global_step (model "global")
  double stretch_compliance = 1e-6, shape_stiffness = 1.0;  // the paper model's knobs (kPaper only)
  int workers = 1;
};

// One divvox run compared with the reference on the surface (the displacement averaged over the run's
// last quarter: settled by the damping of either model, or the equilibrium it swings about): relative RMS displacement error
// (|u - u_ref| over |u_ref|, RMS over the live surface vertices) and the max-displacement error
// (|max |u| - max |u_ref|| / max |u_ref|).
struct ElasticMeasure {
  double rms_error = 0.0, max_error = 0.0;
  double max_displacement = 0.0, ref_max_displacement = 0.0;
  Vec3d tip = Vec3d::Zero();        // divvox's displacement at the tip point (the nearest surface vertex)
  Vec3d ref_tip = Vec3d::Zero();    // the reference's at that vertex
  double step_p50_ms = 0.0, step_p99_ms = 0.0;
  uint32_t vertices = 0, compared = 0, particles = 0;
  double mass = 0.0;                // total particle mass (kg)
  bool finite = true;
};
ElasticMeasure measure_elastic(const ElasticCase& c, const ElasticReference& reference, const ElasticRun& run);

// The bar's first natural frequency, measured from the tip's oscillation with damping off, against
// Euler-Bernoulli (1.875^2 / 2 pi) sqrt(EI / (rho A L^4)).
struct FrequencyMeasure {
  double measured_hz = 0.0, analytic_hz = 0.0;
  int crossings = 0;
};
FrequencyMeasure measure_frequency(const ElasticCase& bar, const ElasticRun& run, double seconds = 2.0);

struct BenchElasticOptions {
  std::vector<std::string> cases;  // default: every case
  std::vector<std::string> sweep_cases = {"cantilever", "liver"};  // the speed-against-error sweep
  std::vector<int> sim_resolutions = {4, 8, 16};
  std::vector<int> substeps = {1, 2, 5};
  std::vector<int> iterations = {1, 2, 5, 10, 20};
  std::vector<std::string> models = {"neo_hookean", "global", "paper"};
  int resolution = 0;         // fine resolution override (0: each case's)
  double ref_scale = 1.0;     // reference cells per axis x this
  double ccx_timeout = 60.0;  // seconds each CalculiX solve may run (finer references need more)
  int workers = 1;
  std::string out_dir = "out/bench";
  std::string keep_ccx;  // when set: each case's CalculiX folder (deck, .dat, log) kept in KEEP/CASE
  bool progress = false;
};
// Writes DIR/bench_elastic.csv (one row per case x model x configuration), bench_elastic.json,
// bench_elastic.svg/.png (step time against error, Pareto front, defaults marked). Returns the CSV path.
std::string bench_elastic(const BenchElasticOptions& options);

// The models by name ("neo_hookean", "global": the material model with its global step, "paper");
// throws InputError naming --models otherwise. elastic_run_model_name: the name of a run's model.
ElasticModel elastic_model_of(const std::string& name);
const char* elastic_run_model_name(const ElasticRun& run);

}  // namespace dvx
