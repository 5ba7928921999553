// Position-based dynamics kernels: pure functions on flat particle arrays (no topology, no
// allocation). The PBD model (sim/pbd.h) builds constraints from the simulation voxels and calls
// these; tests check each kernel alone.
#pragma once

#include "sim/pbd_elastic.h"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

namespace dvx {

// Rotation extraction that survives flattened and inverted matrices (after Müller et al. 2016, "A
// Robust Method to Extract the Rotational Part of Deformations"): iterates q <- exp(omega) q, where
// Müller's omega = sum_i r_i x a_i / (|sum_i r_i . a_i| + eps) (r_i = columns of R(q), a_i = columns of
// A) is replaced by a Newton step on tr(R^T A) with an exact line search along its axis (Müller's
// gradient direction or a negative-curvature axis where the Newton step is undefined); see
// pbd_kernels.cpp. Warm-started from `q` (the previous step's rotation): returns the updated unit
// quaternion, R to ~1e-15 for A = R S within 20 iterations from any start, 1-2 iterations warm-started.
// Never NaN (a zero or non-finite A leaves q unchanged; a singular A moves it towards a nearest
// rotation); tr(R^T A) never decreases, so it does not flip between two answers from step to step.
Eigen::Quaterniond extract_rotation(const Eigen::Matrix3d& a, const Eigen::Quaterniond& q, int max_iterations = 20);

// One step of extract_rotation from a warm start, written out for the solver's usual case (q a unit
// quaternion near the answer, B clearly positive definite): the Newton axis n = B^-1 g with the exact
// line search along it in closed form (along n/|n| the step atan(c/b) is atan(|n|)), without scaling
// A (the axis and |n| do not depend on it; the pivots are compared with kPivotMin x max |a_ij|).
// Near the answer the error falls ~cubically per call, so a solver that calls it every iteration
// tracks the rotation. Where the step is not defined (q not unit, A not finite, B not clearly
// positive definite: far away, inverted or flattened) it is extract_rotation(a, q,
// fallback_iterations). Not bit-identical to extract_rotation (other operations).
Eigen::Quaterniond extract_rotation_step(const Eigen::Matrix3d& a, const Eigen::Quaterniond& q, int fallback_iterations);

// Rotation iterations per shape-matching solve: the solver's path takes one extract_rotation_step
// (extract_rotation with this many iterations where that step is not defined).
constexpr int kShapeRotationIterations = 3;

// One XPBD distance constraint between particles i and j (Macklin et al. 2016):
//   C = |x_i - x_j| - rest,  alpha~ = compliance / dt^2,
//   dlambda = (-C - alpha~ lambda) / (w_i + w_j + alpha~), x_i += w_i dlambda n, x_j -= w_j dlambda n.
// Updates x (positions, double[3] per particle) and lambda in place. Particles with w = 0 don't move.
// A zero-length current edge (coincident particles) is skipped without NaN.
void solve_distance(double* x, const double* inv_mass, uint32_t i, uint32_t j, double rest, double compliance,
                    double dt, double& lambda);

// The body of solve_distance_alpha for particles i, j with their inverse masses given and the
// least length it acts on, min_length = max(1e-12 rest, 1e-300), precomputed (StretchRow).
inline void distance_step(double* xi, double* xj, double wi, double wj, double rest, double min_length, double alpha,
                          double& lambda) {
  const double w_sum = wi + wj;
  if (!(w_sum > 0.0)) return;  // both anchored: nothing can move
  const double d0 = xi[0] - xj[0], d1 = xi[1] - xj[1], d2 = xi[2] - xj[2];
  const double length = std::sqrt(d0 * d0 + d1 * d1 + d2 * d2);
  // Coincident (or non-finite) particles: no direction to push along.
  if (!(length > min_length) || !(length <= std::numeric_limits<double>::max())) return;
  const double dlambda = (-(length - rest) - alpha * lambda) / (w_sum + alpha);
  lambda += dlambda;
  // x_i += w_i dlambda d / |d| (one division for the three axes).
  const double s = dlambda / length, si = wi * s, sj = wj * s;
  xi[0] += si * d0;
  xi[1] += si * d1;
  xi[2] += si * d2;
  xj[0] -= sj * d0;
  xj[1] -= sj * d1;
  xj[2] -= sj * d2;
}

inline double distance_min_length(double rest) { return std::max(1e-12 * rest, 1e-300); }

// The same with alpha~ = compliance / dt^2 computed once by the caller (0 for a rigid constraint; the
// caller skips a soft constraint without a time step).
inline void solve_distance_alpha(double* x, const double* inv_mass, uint32_t i, uint32_t j, double rest, double alpha,
                                 double& lambda) {
  distance_step(x + 3 * size_t(i), x + 3 * size_t(j), inv_mass[i], inv_mass[j], rest, distance_min_length(rest),
                alpha, lambda);
}

// A distance constraint as the solver's colour-group loop reads it: the particles' inverse masses
// and the least length copied in once per model revision (masses change only with it), so a solve
// reads the positions and one row in order, no other array. solve_stretch_row is
// solve_distance_alpha operation for operation (the same bits).
struct StretchRow {
  uint32_t a, b;
  double rest, min_length, wa, wb;
};

inline StretchRow stretch_row(const double* inv_mass, uint32_t a, uint32_t b, double rest) {
  return StretchRow{a, b, rest, distance_min_length(rest), inv_mass[a], inv_mass[b]};
}

inline void solve_stretch_row(double* x, const StretchRow& k, double alpha, double& lambda) {
  distance_step(x + 3 * size_t(k.a), x + 3 * size_t(k.b), k.wa, k.wb, k.rest, k.min_length, alpha, lambda);
}

// The instruction sets the solver's constraint kernels have a path for: SSE2 (any x86-64), AVX2
// (four double lanes in ymm registers) and AVX-512 F/DQ/VL/BW (eight in zmm). Every path does the
// same IEEE operations per lane (no FMA, no reassociation), so all give the same bits; the kernels
// take the best the CPU has (kernel_isa), tests and benchmarks may name another one it has.
enum class KernelIsa : uint8_t { kBaseline, kAvx2, kAvx512 };
// The best path this CPU has (asked once).
KernelIsa kernel_isa();

// Rows [begin, end) in order, with their lambdas. `disjoint`: no two rows share a particle (one colour
// group), so eight rows (AVX-512) or four (AVX2) are solved at once (gathered into one vector per
// axis); otherwise (the overflow group, or the baseline path) one by one. Each row does
// solve_stretch_row's IEEE operations in its order either way, so the results are the same bits on
// every machine.
void solve_stretch_rows(double* x, const StretchRow* rows, double* lambda, uint32_t begin, uint32_t end, double alpha,
                        bool disjoint = false);
// The same on a named path (at most kernel_isa(): one this CPU has).
void solve_stretch_rows(KernelIsa isa, double* x, const StretchRow* rows, double* lambda, uint32_t begin, uint32_t end,
                        double alpha, bool disjoint);

// A surface vertex embedded in a piece: its slot, the piece slot and its local position in [0,1]^3.
struct EmbedRow {
  uint32_t slot, piece;
  float u, v, w;
};

// Trilinear interpolation of rows [begin, end): out[slot] from the piece's 8 corners (corners:
// 32 floats a piece slot, corner c at 4c: x, y, z, 0), in float by lerps along x, then y, then z,
// the three axes at once in a 4-float vector; one clone per instruction set (the same bits).
void embed_rows(const float* corners, const EmbedRow* rows, uint32_t begin, uint32_t end, float* out);

// One shape-matching constraint (Müller et al. 2005) over `count` (<= kShapeMaxParticles) particles (indices), rest positions
// `rest` (double[3] per listed particle, in the same order as indices), masses from inv_mass (w = 0
// particles count as heavy: use a large fixed mass for them in the centroid, e.g. weight 1e6 x the
// others' mean, so anchored particles pin the cluster). Computes the current mass centre c, the rest
// centre c0, A = sum_i m_i (x_i - c)(r_i - c0)^T, R = extract_rotation(A, rotation), and moves each
// particle with w > 0 towards its goal g_i = c + R (r_i - c0) by stiffness * (g_i - x_i).
// `rotation` is warm-started and updated in place.
void solve_shape_matching(double* x, const double* inv_mass, const uint32_t* indices, const double* rest,
                          int count, double stiffness, Eigen::Quaterniond& rotation);

// Same, but writes the per-particle corrections into `delta` (double[3] per listed particle) instead
// of moving the particles (for Jacobi-style parallel solves with deterministic accumulation).
void shape_matching_corrections(const double* x, const double* inv_mass, const uint32_t* indices,
                                const double* rest, int count, double stiffness, Eigen::Quaterniond& rotation,
                                double* delta);

// The rest frame of one shape-matching cluster of up to kShapeMaxParticles particles: what stays the
// same between solves while the cluster's masses and rest positions do (the solver builds it once per
// step: cuts and anchoring change masses only between steps). Masses (anchored particles weigh
// kAnchorWeight x the free particles' mean), their total, and the rest offsets r_i - c0 from the rest
// mass centre (double: in float a rigidly moved cluster would drift by ~1e-9 of its size per solve
// against the double stretch rest lengths, for no fewer instructions: the kernel computes in double).
constexpr int kShapeMaxParticles = 8;
struct ShapeRest {
  int count = 0;  // 0: no particle can move (the cluster is skipped)
  double total = 0.0, inv_total = 0.0;
  double mass[kShapeMaxParticles] = {};
  double offset[kShapeMaxParticles][3] = {};  // r_i - c0
  uint8_t moves[kShapeMaxParticles] = {};     // inverse mass > 0
};

// Builds the rest frame (count <= kShapeMaxParticles); false (out.count = 0) when no particle moves.
bool shape_matching_rest(const double* inv_mass, const uint32_t* indices, const double* rest, int count,
                         ShapeRest& out);

// solve_shape_matching from a prebuilt rest frame; rotation_iterations > 0: extract_rotation with
// that many iterations (the one-shot versions above use kShapeRotationIterations); 0: one
// extract_rotation_step (the solver's path).
void solve_shape_matching(double* x, const uint32_t* indices, const ShapeRest& rest, double stiffness,
                          Eigen::Quaterniond& rotation, int rotation_iterations = kShapeRotationIterations);

// Shape-matching clusters solved kShapeLanes at a time (the solver's path): structure of arrays
// ([slot][axis][lane]), so every stage of the solve (gather, centre, A, the rotation step, goals) is a
// short loop over the lanes that the compiler vectorises: the eight lanes in one zmm register each
// on the AVX-512 path, in two halves of four on the AVX2 (ymm) and baseline (SSE2 pairs) paths (the
// halves' rotation steps side by side). Each lane does the same IEEE operations in the same order as
// the scalar
// solve_shape_matching(x, indices, rest, stiffness, rotation, 0) (no reassociation, no FMA), so
// the results are the same bits on every path and equal the scalar path. The lanes of a block must
// share no particle (one colour group). A block of fewer than kShapeLanes clusters repeats its last
// lane in the unused ones: they compute it again and store the same values to the same particles
// and rotation again; a half of four without a cluster of its own is skipped (it would only repeat
// the other half's last cluster).
constexpr int kShapeLanes = 8;
// The doubles first and the block 64-byte aligned, so each [lane] row of eight is one aligned vector.
struct alignas(64) ShapeBlock {
  double mass[kShapeMaxParticles][kShapeLanes] = {};
  double offset[kShapeMaxParticles][3][kShapeLanes] = {};  // r_i - c0
  double inv_total[kShapeLanes] = {};
  uint32_t index[kShapeMaxParticles][kShapeLanes] = {};    // particle of each cluster slot
  uint32_t piece[kShapeLanes] = {};                        // rotation slot of each lane
  uint8_t moves[kShapeMaxParticles][kShapeLanes] = {};
  int lanes = 0;
};

// Puts cluster (indices, rest frame r with r.count > 0, rotation slot `piece`) into the next lane
// of `block` (block.lanes < kShapeLanes), and into the unused ones after it.
void shape_block_add(ShapeBlock& block, uint32_t piece, const uint32_t* indices, const ShapeRest& r);

// Solves the block's clusters with stiffness `stiffness`; rotations[piece] is each lane's warm start,
// updated in place (one rotation step; extract_rotation with kShapeRotationIterations in a lane where
// the step is not defined, as in the scalar path). Every particle of the block is stored, those that
// do not move with the bits they had (so a block touches only its own particles, as before).
void solve_shape_block(double* x, const ShapeBlock& block, double stiffness, Eigen::Quaterniond* rotations);

// Blocks [begin, end): the result of solve_shape_block on each in turn, in one call. `disjoint`: no
// two of the blocks share a particle (one colour group), so the AVX-512 path solves two blocks at
// once (their rotation steps side by side); otherwise (the overflow colour's blocks) one after the
// other. The same bits either way.
void solve_shape_blocks(double* x, const ShapeBlock* blocks, uint32_t begin, uint32_t end, double stiffness,
                        Eigen::Quaterniond* rotations, bool disjoint = false);
// The same on a named path (at most kernel_isa(): one this CPU has).
void solve_shape_blocks(KernelIsa isa, double* x, const ShapeBlock* blocks, uint32_t begin, uint32_t end,
                        double stiffness, Eigen::Quaterniond* rotations, bool disjoint);

// The material's hexahedra (pbd_elastic.h's solve_elastic_rows) with the lanes of the best path:
// `disjoint` (one colour group: no two rows share a particle) solves eight rows (AVX-512) or four
// (AVX2 and SSE2's pairs) at once, one per lane; otherwise (the overflow group) in order. Each row
// does solve_elastic_rows' IEEE operations in its order either way: the same bits on every path.
// enhancement: the incompatible modes' amplitudes per piece slot (pbd_elastic.h), null for none.
void solve_elastic_blocks(double* x, const double* previous, const ElasticRow* rows, double* lambda, uint32_t begin,
                          uint32_t end, const ElasticConstants& k, Eigen::Quaterniond* rotation,
                          const double* enhancement, bool disjoint);
// The same on a named path (at most kernel_isa(): one this CPU has).
void solve_elastic_blocks(KernelIsa isa, double* x, const double* previous, const ElasticRow* rows, double* lambda,
                          uint32_t begin, uint32_t end, const ElasticConstants& k, Eigen::Quaterniond* rotation,
                          const double* enhancement, bool disjoint);

}  // namespace dvx
