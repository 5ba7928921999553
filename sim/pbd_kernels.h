// Position-based dynamics kernels: pure functions on flat particle arrays (no topology, no
// allocation). The PBD model (sim/pbd.h) builds constraints from the simulation voxels and calls
// these; tests check each kernel alone.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>

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

// One XPBD distance constraint between particles i and j (Macklin et al. 2016):
//   C = |x_i - x_j| - rest,  alpha~ = compliance / dt^2,
//   dlambda = (-C - alpha~ lambda) / (w_i + w_j + alpha~), x_i += w_i dlambda n, x_j -= w_j dlambda n.
// Updates x (positions, double[3] per particle) and lambda in place. Particles with w = 0 don't move.
// A zero-length current edge (coincident particles) is skipped without NaN.
void solve_distance(double* x, const double* inv_mass, uint32_t i, uint32_t j, double rest, double compliance,
                    double dt, double& lambda);

// One shape-matching constraint (Müller et al. 2005) over `count` particles (indices), rest positions
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

}  // namespace dvx
