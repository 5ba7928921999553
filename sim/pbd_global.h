// A global step for the material model (issue 30's stiff regime, PbdParams::global_step).
//
// Why: the XPBD hexahedra (sim/pbd_elastic.h) are solved one piece at a time, so support travels one
// simulation voxel per iteration. A stiff material (MPa) or a tall stack of pieces needs hundreds of
// substeps before gravity is carried to the anchors (a 5 MPa cantilever at the shipped 5 x 2 sags 36x
// too far). This step solves the whole body's linearised backward-Euler system once per substep,
// linearised at the substep's start x_prev (so a body at rest is at its fixed point exactly when
// grad Psi = M g):
//
//   (M / h^2 + (1 + beta / h) K) delta = M (x~ - x_prev) / h^2 - grad Psi(x_prev),   x = x_prev + delta,
//
// where Psi is the XPBD constraints' quadratic energy of the enhanced element (pbd_elastic.h: the
// incompatible modes' amplitudes are unknowns too, condensed out piece by piece and updated after the
// solve) and K its small-strain Hessian about each piece's rotation R, R K0 R^T (K0 once per model,
// rotation-free through the symmetric strain) plus the centre's volume term. Conjugate gradients solve
// it, preconditioned by a Cholesky factorisation (Eigen's SimplicialLDLT) of the same matrix with the
// rotations of the moment it was factorised, warped by each unknown's mean turn since, refactorised
// with the model and when the stale factorisation's extra iterations have cost as much as a new one.
//
// The multipliers of the XPBD constraints are then set to what the new state implies (lambda =
// -(C + gamma grad C . (x - x_prev)) / alpha~, the XPBD update's fixed point), so the substep's
// usual iterations (contact, the grab, the hexahedra themselves) start from a consistent solution and
// only correct what the global step left: a body at rest stays at the continuum's equilibrium
// whatever its stiffness, and the iterations' results keep their meaning. Serial, one scalar order:
// the same bits for any worker count.
#pragma once

#include "sim/pbd_elastic.h"

#include <cstdint>
#include <vector>

namespace dvx {

struct PbdModel;
struct PbdData;

// What the last global step did (for the bench and the tests).
struct GlobalStepStats {
  uint32_t unknowns = 0;     // particles solved (not anchored, in a hexahedron with material)
  uint32_t iterations = 0;   // conjugate-gradient iterations of the last substep
  double residual = 0.0;     // its final residual relative to max(|b|, the load)
  uint64_t factorisations = 0;  // preconditioner factorisations so far
};

// Tolerance and cap of the conjugate gradients: the residual relative to the larger of the right-hand
// side and the substep's load |M (x~ - x_prev)| / h^2 (gravity and inertia).
constexpr double kGlobalTolerance = 1e-7;
constexpr uint32_t kGlobalMaxIterations = 200;
// The preconditioner is refactorised with the rows' current rotations when the iterations a solve
// needed beyond kFreshIterations (what a fresh factorisation needs) have cost, summed since the last
// factorisation, as many operations as a factorisation. Measured on the hanging liver at sim 16
// (bench elastic, 1 x 1) with a fixed rule instead: never refactorising, 40-85 iterations a substep and
// 324 ms a step; above 10 iterations a solve, 18.5 ms; above 20 or 40, 25 and 39 ms. A fixed 10
// refactorised the 2 MPa liver in the window at every other step (13-29 iterations after each: a few
// thin pieces' rotations move), 130 ms each.
constexpr uint32_t kFreshIterations = 3;

// One global step of the current substep (h, the material's constants k, Lame's mu and lambda, the
// Rayleigh beta in seconds) on data.position from data.previous, and the multipliers of
// data.cache.elastic_lambda set to match. Needs refresh_blocks' rows (data.cache.elastic_rows).
void global_elastic_step(const PbdModel& s, PbdData& data, const ElasticConstants& k);

// The last global step's figures (zeros before the first).
GlobalStepStats global_step_stats(const PbdData& data);

}  // namespace dvx
