#include "sim/pbd_kernels.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <limits>
#include <type_traits>

#if defined(__x86_64__)
// GCC 12 warns inside its own AVX-512 intrinsics (the `__Y = __Y` of _mm512_undefined_pd: GCC bug
// 105593, fixed in 13).
#if !defined(__clang__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
#include <immintrin.h>
#if !defined(__clang__)
#pragma GCC diagnostic pop
#endif
#endif

namespace dvx {

namespace {

using Eigen::Matrix3d;
using Eigen::Quaterniond;
using Eigen::Vector3d;

// Rotation extraction, on A scaled so that max |a_ij| = 1 (all thresholds below are then absolute).
//
// Why not plain Müller et al. 2016: their step omega = g / |tr(R^T A)| is the gradient of
// f(R) = tr(R^T A) scaled by the trace only. It converges linearly with rate up to s_max / tr(S) per
// iteration (S the stretch), so a stretched cluster or a start far from the answer needs far more than
// 20 iterations to reach 1e-9, and it crawls near saddles (a start ~180 degrees away). We keep its
// robustness (never a raw polar decomposition, warm start, no NaN on singular A) and take better steps:
//   * f(exp([t u]) R) = f + c sin t - b (1 - cos t) along any unit axis u, with c = u.g and b = u^T B u,
//     g = sum_i r_i x a_i (Müller's numerator), B = tr(R^T A) I - sym(A R^T) (minus the Hessian of f).
//     Its exact maximum, t = atan2(c, b), gains hypot(c, b) - b >= 0: every iteration is an exact line
//     search, so f never decreases, which is why warm-started calls cannot alternate between answers.
//   * Axis: Newton's, B^-1 g, when B is clearly positive definite (the usual case near the answer;
//     with the exact line search the error falls ~cubically: 1-2 iterations when warm-started).
//     Otherwise (far from the answer, inverted or flattened A) the best of: the gradient (Müller's
//     direction), the saddle-free Newton axis |B|^-1 g, and the eigenvector of B's most negative
//     eigenvalue (escapes a saddle where g = 0).
//   * tr(R^T A) has no local maxima other than the global one on SO(3), so ascent finds the rotation
//     nearest to A (for det A < 0, the one that flips the smallest singular direction). A flat maximum
//     (rank-1 A, or equal singular values with det A < 0) does not move once reached: steps that gain
//     less than kMinGain are not taken.
constexpr double kPivotMin = 1e-10;        // smallest LDL^T pivot of B (scaled A) for a Newton step
constexpr double kMinGain = 1e-14;         // least gain of f (scaled A) for a step in the fallback branch
constexpr double kMinAngle = 1e-15;        // a Newton step below this angle (radians) is not taken
constexpr double kLastAngle = 1e-5;        // after a Newton step below this the error is ~angle^3 (measured): stop
constexpr double kSaddleFreeFloor = 1e-3;  // |eigenvalue| floor of B in the saddle-free Newton axis

// q <- exp(angle * axis) q, for a unit axis (small angles without sin/cos: the series is exact in
// double precision there).
inline Quaterniond rotate(const Quaterniond& q, double angle, const Vector3d& axis) {
  const double half = 0.5 * angle;
  double c, s;
  if (std::fabs(half) < 1e-4) {
    const double h2 = half * half;
    c = 1.0 - h2 * (0.5 - h2 * (1.0 / 24.0));
    s = half * (1.0 - h2 * (1.0 / 6.0));
  } else {
    c = std::cos(half);
    s = std::sin(half);
  }
  Quaterniond r = Quaterniond(c, s * axis.x(), s * axis.y(), s * axis.z()) * q;
  r.normalize();
  return r;
}

// Newton axis B^-1 g by an LDL^T factorisation of the symmetric 3x3 B; false when a pivot is not
// above kPivotMin (B not clearly positive definite).
inline bool newton_axis(const Matrix3d& b, const Vector3d& g, Vector3d& out) {
  const double d0 = b(0, 0);
  if (!(d0 > kPivotMin)) return false;
  const double l10 = b(1, 0) / d0, l20 = b(2, 0) / d0;
  const double d1 = b(1, 1) - l10 * l10 * d0;
  if (!(d1 > kPivotMin)) return false;
  const double l21 = (b(2, 1) - l20 * l10 * d0) / d1;
  const double d2 = b(2, 2) - l20 * l20 * d0 - l21 * l21 * d1;
  if (!(d2 > kPivotMin)) return false;
  // Forward (L y = g), diagonal, backward (L^T x = z).
  const double y0 = g[0], y1 = g[1] - l10 * y0, y2 = g[2] - l20 * y0 - l21 * y1;
  const double x2 = y2 / d2;
  const double x1 = y1 / d1 - l21 * x2;
  const double x0 = y0 / d0 - l10 * x1 - l20 * x2;
  out = Vector3d(x0, x1, x2);
  return out.allFinite();
}

// Exact maximum of f along the unit axis u: returns the gain and writes the angle.
inline double line_maximum(const Vector3d& u, const Vector3d& g, const Matrix3d& b, double& angle) {
  const double c = u.dot(g);
  const double curvature = u.dot(b * u);
  angle = std::atan2(c, curvature);
  return std::hypot(c, curvature) - curvature;
}

// Lanes: the rotation step and R(q) are written once over a lane type T: double (the scalar path),
// V4 or V8, four or eight doubles in GCC's vector extension (the blocks: V4 in SSE2 pairs in the
// baseline path and in ymm registers in the AVX2 path, V8 in zmm registers in the AVX-512 path). Per
// lane a vector operation is the same IEEE operation as on a double, so all give the same bits. M is
// the comparison result (bool, or a lane mask of 0 / -1).
// (Internal helpers, always inlined: the warning about passing vectors without AVX does not apply.)
#pragma GCC diagnostic ignored "-Wpsabi"
// Kernels in an AVX2 and a baseline clone, picked when the program loads (an ifunc).
// ThreadSanitizer instruments the clones' resolver, which runs before its runtime is up (the binary
// crashed while loading), so a TSan build keeps the baseline clone only: the same bits either way.
// (The solver's constraint kernels pick their path by KernelIsa instead: no ifunc, any build.)
#if defined(__SANITIZE_THREAD__)
#define DVX_CLONES
#elif defined(__has_feature)
#if __has_feature(thread_sanitizer)
#define DVX_CLONES
#endif
#endif
#ifndef DVX_CLONES
#define DVX_CLONES __attribute__((target_clones("avx2", "default")))
#endif
// The functions of each path: the vector helpers below are always inlined into them, so each path
// compiles them for its own instruction set.
#define DVX_AVX2_PATH __attribute__((target("avx2")))
#define DVX_AVX512_PATH __attribute__((target("avx512f,avx512dq,avx512vl,avx512bw")))
typedef double V4 __attribute__((vector_size(32)));
typedef int64_t M4 __attribute__((vector_size(32)));
typedef double V8 __attribute__((vector_size(64)));
typedef int64_t M8 __attribute__((vector_size(64)));
// One lane: the hexahedra's scalar path (solve_elastic_rows) is their lane code on V1.
typedef double V1 __attribute__((vector_size(8)));
typedef int64_t M1 __attribute__((vector_size(8)));
static_assert(kShapeLanes == 8, "a block is one V8, or two V4 halves");
// Lanes of a vector type.
template <class V>
constexpr int kWidth = int(sizeof(V) / sizeof(double));
// The lane mask type of a vector type (spelled out: clang's comparisons give vectors of long long,
// GCC's of long).
template <class V>
using MaskOf = std::conditional_t<sizeof(V) == sizeof(V8), M8, std::conditional_t<sizeof(V) == sizeof(V1), M1, M4>>;
// Particle slots of a cluster.
constexpr int kS = kShapeMaxParticles;

// Unaligned forms (the typed loads in pbd_kernels_lanes.inc) and the lane masks of four flags.
typedef double V2 __attribute__((vector_size(16)));
typedef double V4u __attribute__((vector_size(32), aligned(8), may_alias));
typedef double V8u __attribute__((vector_size(64), aligned(8), may_alias));
typedef int64_t M4u __attribute__((vector_size(32), aligned(8), may_alias));
struct LaneMasks {
  int64_t mask[16][4];
  constexpr LaneMasks() : mask() {
    for (int i = 0; i < 16; ++i) {
      for (int l = 0; l < 4; ++l) mask[i][l] = (i >> l & 1) ? -1 : 0;
    }
  }
};
alignas(32) constexpr LaneMasks kLaneMasks;

// The lane code once per path (see pbd_kernels_lanes.inc): `lanes` for the scalar and baseline
// paths, `avx2_lanes` and `avx512_lanes` compiled for their instruction sets.
namespace lanes {
#include "sim/pbd_kernels_lanes.inc"
}  // namespace lanes
// (clang lowers vector operations only after inlining: it needs no target regions, and has no
// `#pragma GCC target`.)
#if defined(__x86_64__)
#if !defined(__clang__)
#pragma GCC push_options
#pragma GCC target("avx2")
#endif
namespace avx2_lanes {
#include "sim/pbd_kernels_lanes.inc"
}  // namespace avx2_lanes
#if !defined(__clang__)
#pragma GCC pop_options
#pragma GCC push_options
#pragma GCC target("avx512f,avx512dq,avx512vl,avx512bw")
#endif
namespace avx512_lanes {
#include "sim/pbd_kernels_lanes.inc"
}  // namespace avx512_lanes
#if !defined(__clang__)
#pragma GCC pop_options
#endif
#endif

// Centre and rotation of one shape-matching cluster: everything the goals g_i = c + R (r_i - c0) need,
// from its rest frame (shape_matching_rest), in scalar loops with the axes written out (the sums run
// in slot order: the compiler may not reorder them under -ffp-contract=off and strict IEEE rules,
// so vectorising the reductions would not pay; the gathered positions stay in registers and L1).
struct ShapeFrame {
  double p[kS][3];  // gathered positions
  double centre[3];
  double rot[3][3];
};

void shape_matching_frame(const double* x, const uint32_t* indices, const ShapeRest& r, Quaterniond& rotation,
                          int rotation_iterations, ShapeFrame& f) {
  // All kS slots (padding slots weigh 0 and have zero offsets: they add exact zeros), so the loops
  // unroll and the sums stay in registers.
  double c0 = 0.0, c1 = 0.0, c2 = 0.0;
  for (int k = 0; k < kS; ++k) {
    const double* xi = x + 3 * size_t(indices[k < r.count ? k : 0]);
    const double m = r.mass[k];
    f.p[k][0] = xi[0];
    f.p[k][1] = xi[1];
    f.p[k][2] = xi[2];
    c0 += m * xi[0];
    c1 += m * xi[1];
    c2 += m * xi[2];
  }
  c0 *= r.inv_total;
  c1 *= r.inv_total;
  c2 *= r.inv_total;
  f.centre[0] = c0;
  f.centre[1] = c1;
  f.centre[2] = c2;
  // A = sum_i m_i (x_i - c)(r_i - c0)^T.
  double a00 = 0.0, a01 = 0.0, a02 = 0.0, a10 = 0.0, a11 = 0.0, a12 = 0.0, a20 = 0.0, a21 = 0.0, a22 = 0.0;
  for (int k = 0; k < kS; ++k) {
    const double m = r.mass[k];
    const double d0 = m * (f.p[k][0] - c0), d1 = m * (f.p[k][1] - c1), d2 = m * (f.p[k][2] - c2);
    const double q0 = r.offset[k][0], q1 = r.offset[k][1], q2 = r.offset[k][2];
    a00 += d0 * q0;
    a01 += d0 * q1;
    a02 += d0 * q2;
    a10 += d1 * q0;
    a11 += d1 * q1;
    a12 += d1 * q2;
    a20 += d2 * q0;
    a21 += d2 * q1;
    a22 += d2 * q2;
  }
  Matrix3d a;
  a << a00, a01, a02, a10, a11, a12, a20, a21, a22;
  // Warm-started every solve, so the rotation converges over the solver's iterations.
  rotation = rotation_iterations > 0 ? extract_rotation(a, rotation, rotation_iterations)
                                     : extract_rotation_step(a, rotation, kShapeRotationIterations);
  const double q[4] = {rotation.w(), rotation.x(), rotation.y(), rotation.z()};
  lanes::rotation_matrix_lanes<double>(q, f.rot);
}

// Goal of slot k: c + R q_k.
inline void shape_goal(const ShapeFrame& f, const double* q, double goal[3]) {
  for (int e = 0; e < 3; ++e) goal[e] = f.centre[e] + (f.rot[e][0] * q[0] + f.rot[e][1] * q[1] + f.rot[e][2] * q[2]);
}

}  // namespace

Quaterniond extract_rotation(const Matrix3d& a, const Quaterniond& q_in, int max_iterations) {
  // Start from the warm start, repaired if it is not a usable quaternion.
  Quaterniond q = q_in;
  const double qn = q.norm();
  if (!std::isfinite(qn) || qn < 1e-150)
    q = Quaterniond::Identity();
  else
    q.coeffs() /= qn;
  if (!a.allFinite()) return q;
  // Scale A to max |a_ij| = 1: the rotation does not change, the thresholds become absolute.
  const double scale = a.cwiseAbs().maxCoeff();
  if (!(scale > 0.0)) return q;
  const double inv_scale = 1.0 / scale;  // infinite only for a subnormal scale
  const Matrix3d as = std::isfinite(inv_scale) ? Matrix3d(a * inv_scale) : Matrix3d(a / scale);

  for (int iteration = 0; iteration < max_iterations; ++iteration) {
    // Gradient g and curvature B of f = tr(R^T A) at the current rotation.
    const Matrix3d r = q.toRotationMatrix();
    const double f = r.col(0).dot(as.col(0)) + r.col(1).dot(as.col(1)) + r.col(2).dot(as.col(2));
    const Vector3d g = r.col(0).cross(as.col(0)) + r.col(1).cross(as.col(1)) + r.col(2).cross(as.col(2));
    const Matrix3d ar = as * r.transpose();
    const Matrix3d b = f * Matrix3d::Identity() - 0.5 * (ar + ar.transpose());

    Vector3d axis;
    double angle = 0.0;
    Vector3d newton;
    if (newton_axis(b, g, newton)) {
      // Concave here: Newton axis, exact step along it (b > 0, so the step is atan(c / b)); a
      // negligible step means converged, a small one leaves an error ~angle^3: take it and stop.
      const double axis_norm = newton.norm();
      if (!(axis_norm > 0.0)) break;
      axis = newton / axis_norm;
      const double ratio = axis.dot(g) / axis.dot(b * axis);
      if (std::fabs(ratio) < 1e-4) {
        const double r2 = ratio * ratio;
        angle = ratio * (1.0 - r2 * (1.0 / 3.0 - r2 * (1.0 / 5.0)));
      } else {
        angle = std::atan(ratio);
      }
      if (!(std::fabs(angle) > kMinAngle)) break;
      if (std::fabs(angle) < kLastAngle) {
        q = rotate(q, angle, axis);
        break;
      }
    } else {
      // Not concave (far away, inverted or flat): best of gradient, saddle-free Newton and the
      // most negative curvature direction.
      Eigen::SelfAdjointEigenSolver<Matrix3d> eigen;
      eigen.computeDirect(b);
      const Matrix3d& v = eigen.eigenvectors();
      const Vector3d& lambda = eigen.eigenvalues();  // ascending
      double best_gain = 0.0, candidate_angle = 0.0;
      const double g_norm = g.norm();
      if (g_norm > 0.0) {
        const Vector3d gradient_axis = g / g_norm;
        double gain = line_maximum(gradient_axis, g, b, candidate_angle);
        if (gain > best_gain) {
          best_gain = gain;
          axis = gradient_axis;
          angle = candidate_angle;
        }
        Vector3d local = v.transpose() * g;
        for (int k = 0; k < 3; ++k) local[k] /= std::max(std::fabs(lambda[k]), kSaddleFreeFloor);
        const Vector3d saddle_free = v * local;
        const double saddle_free_norm = saddle_free.norm();
        if (saddle_free_norm > 0.0) {
          const Vector3d saddle_free_axis = saddle_free / saddle_free_norm;
          gain = line_maximum(saddle_free_axis, g, b, candidate_angle);
          if (gain > best_gain) {
            best_gain = gain;
            axis = saddle_free_axis;
            angle = candidate_angle;
          }
        }
      }
      if (lambda[0] < 0.0) {
        const Vector3d negative_axis = v.col(0);
        const double gain = line_maximum(negative_axis, g, b, candidate_angle);
        if (gain > best_gain) {
          best_gain = gain;
          axis = negative_axis;
          angle = candidate_angle;
        }
      }
      if (!(best_gain > kMinGain)) break;
    }

    q = rotate(q, angle, axis);
  }
  return q;
}

Quaterniond extract_rotation_step(const Matrix3d& a, const Quaterniond& q, int fallback_iterations) {
  // The usual case (q a unit quaternion, B clearly positive definite) in rotation_step_lanes: the
  // exact line search along the Newton axis n = B^-1 g has a closed form there: along n/|n|,
  // c = n.g/|n| and b = n.Bn/|n|^2 = n.g/|n|^2, so the step is atan(c / b) = atan(|n|). No scaling
  // of A: the axis and |n| do not depend on it, and the pivots are compared with kPivotMin x max |a_ij|.
  double al[3][3], ql[4] = {q.w(), q.x(), q.y(), q.z()};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) al[i][j] = a(i, j);
  }
  if (!lanes::rotation_step_lanes<double>(al, ql)) return extract_rotation(a, q, fallback_iterations);
  return Quaterniond(ql[0], ql[1], ql[2], ql[3]);
}

void solve_distance(double* x, const double* inv_mass, uint32_t i, uint32_t j, double rest, double compliance,
                    double dt, double& lambda) {
  // alpha~ = compliance / dt^2; a soft constraint without a time step does nothing.
  double alpha = 0.0;
  if (compliance > 0.0) {
    if (!(dt > 0.0)) return;
    alpha = compliance / (dt * dt);
  }
  solve_distance_alpha(x, inv_mass, i, j, rest, alpha, lambda);
}

namespace {

DVX_CLONES
void stretch_rows_scalar(double* x, const StretchRow* rows, double* lambda, uint32_t begin, uint32_t end, double alpha) {
  for (uint32_t i = begin; i < end; ++i) solve_stretch_row(x, rows[i], alpha, lambda[i]);
}

#if defined(__x86_64__)
#define DVX_AVX2 __attribute__((target("avx2"), always_inline)) inline
// [x0 y0 x2 y2] and [x1 y1 x3 y3] -> x, y per lane; z per lane.
DVX_AVX2 void gather4(double* const* p, __m256d& gx, __m256d& gy, __m256d& gz) {
  const __m256d e = _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_loadu_pd(p[0])), _mm_loadu_pd(p[2]), 1);
  const __m256d o = _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_loadu_pd(p[1])), _mm_loadu_pd(p[3]), 1);
  gx = _mm256_unpacklo_pd(e, o);
  gy = _mm256_unpackhi_pd(e, o);
  gz = _mm256_set_pd(p[3][2], p[2][2], p[1][2], p[0][2]);
}
// The inverse of gather4.
DVX_AVX2 void scatter4(double* const* p, __m256d sx, __m256d sy, __m256d sz) {
  const __m256d e = _mm256_unpacklo_pd(sx, sy), o = _mm256_unpackhi_pd(sx, sy);
  _mm_storeu_pd(p[0], _mm256_castpd256_pd128(e));
  _mm_storeu_pd(p[1], _mm256_castpd256_pd128(o));
  _mm_storeu_pd(p[2], _mm256_extractf128_pd(e, 1));
  _mm_storeu_pd(p[3], _mm256_extractf128_pd(o, 1));
  const __m128d z01 = _mm256_castpd256_pd128(sz), z23 = _mm256_extractf128_pd(sz, 1);
  _mm_storel_pd(p[0] + 2, z01);
  _mm_storeh_pd(p[1] + 2, z01);
  _mm_storel_pd(p[2] + 2, z23);
  _mm_storeh_pd(p[3] + 2, z23);
}
// v + s d (plus) or v - s d where `valid`, else v.
DVX_AVX2 __m256d moved4(__m256d v, __m256d s, __m256d d, bool plus, __m256d valid) {
  const __m256d delta = _mm256_mul_pd(s, d);
  return _mm256_blendv_pd(v, plus ? _mm256_add_pd(v, delta) : _mm256_sub_pd(v, delta), valid);
}

// Four rows' constants as one vector per field: the 32 bytes from `rest` of each row (rest,
// min_length, wa, wb) transposed (unpck and perm2f128) instead of 16 single loads and inserts.
DVX_AVX2 void row_constants4(const StretchRow* r, __m256d& rest, __m256d& min_length, __m256d& wa, __m256d& wb) {
  static_assert(offsetof(StretchRow, min_length) == offsetof(StretchRow, rest) + 8 &&
                    offsetof(StretchRow, wa) == offsetof(StretchRow, rest) + 16 &&
                    offsetof(StretchRow, wb) == offsetof(StretchRow, rest) + 24,
                "rest, min_length, wa, wb are consecutive");
  const __m256d r0 = _mm256_loadu_pd(&r[0].rest), r1 = _mm256_loadu_pd(&r[1].rest);
  const __m256d r2 = _mm256_loadu_pd(&r[2].rest), r3 = _mm256_loadu_pd(&r[3].rest);
  const __m256d t0 = _mm256_unpacklo_pd(r0, r1), t1 = _mm256_unpackhi_pd(r0, r1);  // rest wa, min wb (rows 0 1)
  const __m256d t2 = _mm256_unpacklo_pd(r2, r3), t3 = _mm256_unpackhi_pd(r2, r3);  // the same, rows 2 3
  rest = _mm256_permute2f128_pd(t0, t2, 0x20);
  wa = _mm256_permute2f128_pd(t0, t2, 0x31);
  min_length = _mm256_permute2f128_pd(t1, t3, 0x20);
  wb = _mm256_permute2f128_pd(t1, t3, 0x31);
}

// Four rows of one colour at once in AVX2 (x86-64 only): distance_step per lane, operation for
// operation (the same IEEE additions, products, square root and divisions in the same order, no FMA),
// its early returns as a mask (a lane that would return writes back what it read). Positions are
// gathered as (x, y) pairs and z, transposed into one vector per axis, and scattered back the same way.
// (Two groups of four written side by side, so that their chains of square root and divisions
// overlap, measured ~5 % faster for ~15 % more instructions: not kept.)
__attribute__((target("avx2"))) void stretch_rows_avx2(double* x, const StretchRow* rows, double* lambda,
                                                       uint32_t begin, uint32_t end, double alpha) {
  const __m256d zero = _mm256_setzero_pd(), sign = _mm256_set1_pd(-0.0);
  const __m256d big = _mm256_set1_pd(std::numeric_limits<double>::max()), va = _mm256_set1_pd(alpha);
  uint32_t i = begin;
  for (; i + 4 <= end; i += 4) {
    const StretchRow* r = rows + i;
    double* pa[4] = {x + 3 * size_t(r[0].a), x + 3 * size_t(r[1].a), x + 3 * size_t(r[2].a), x + 3 * size_t(r[3].a)};
    double* pb[4] = {x + 3 * size_t(r[0].b), x + 3 * size_t(r[1].b), x + 3 * size_t(r[2].b), x + 3 * size_t(r[3].b)};
    __m256d ax, ay, az, bx, by, bz, rest, min_length, wa, wb;
    gather4(pa, ax, ay, az);
    gather4(pb, bx, by, bz);
    row_constants4(r, rest, min_length, wa, wb);
    const __m256d w_sum = _mm256_add_pd(wa, wb);
    const __m256d d0 = _mm256_sub_pd(ax, bx), d1 = _mm256_sub_pd(ay, by), d2 = _mm256_sub_pd(az, bz);
    const __m256d length = _mm256_sqrt_pd(
        _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(d0, d0), _mm256_mul_pd(d1, d1)), _mm256_mul_pd(d2, d2)));
    // distance_step's early returns: w_sum > 0, length > min_length, length <= max (false on NaN).
    const __m256d valid = _mm256_and_pd(_mm256_and_pd(_mm256_cmp_pd(w_sum, zero, _CMP_GT_OQ),
                                                      _mm256_cmp_pd(length, min_length, _CMP_GT_OQ)),
                                        _mm256_cmp_pd(length, big, _CMP_LE_OQ));
    const __m256d l0 = _mm256_loadu_pd(lambda + i);
    const __m256d numerator = _mm256_sub_pd(_mm256_xor_pd(_mm256_sub_pd(length, rest), sign), _mm256_mul_pd(va, l0));
    const __m256d dl = _mm256_div_pd(numerator, _mm256_add_pd(w_sum, va));
    _mm256_storeu_pd(lambda + i, _mm256_blendv_pd(l0, _mm256_add_pd(l0, dl), valid));
    const __m256d step = _mm256_div_pd(dl, length);
    const __m256d si = _mm256_mul_pd(wa, step), sj = _mm256_mul_pd(wb, step);
    scatter4(pa, moved4(ax, si, d0, true, valid), moved4(ay, si, d1, true, valid), moved4(az, si, d2, true, valid));
    scatter4(pb, moved4(bx, sj, d0, false, valid), moved4(by, sj, d1, false, valid), moved4(bz, sj, d2, false, valid));
  }
  for (; i < end; ++i) solve_stretch_row(x, rows[i], alpha, lambda[i]);
}

// Two four-lane halves as one vector.
__attribute__((target("avx512f"), always_inline)) inline __m512d join(const __m256d (&v)[2]) {
  return _mm512_insertf64x4(_mm512_castpd256_pd512(v[0]), v[1], 1);
}

// Eight rows of one colour at once in AVX-512: stretch_rows_avx2's lanes (distance_step per lane,
// operation for operation), twice as wide, its mask in a k register. Positions as there: (x, y)
// pairs and z, transposed into one vector per axis and back; the rows' constants by eight 32-byte
// loads and an 8x4 transpose. The rest of the range (fewer than eight rows) four at a time, then
// one by one.
DVX_AVX512_PATH void stretch_rows_avx512(double* x, const StretchRow* rows, double* lambda, uint32_t begin,
                                         uint32_t end, double alpha) {
  const __m512d zero = _mm512_setzero_pd(), sign = _mm512_set1_pd(-0.0);
  const __m512d big = _mm512_set1_pd(std::numeric_limits<double>::max()), va = _mm512_set1_pd(alpha);
  // Lanes (rest, wa) of rows 0-1 | 4-5 and rows 2-3 | 6-7 into rows 0-7 in order.
  const __m512i low_pairs = _mm512_setr_epi64(0, 1, 8, 9, 4, 5, 12, 13);
  const __m512i high_pairs = _mm512_setr_epi64(2, 3, 10, 11, 6, 7, 14, 15);
  uint32_t i = begin;
  for (; i + 8 <= end; i += 8) {
    const StretchRow* r = rows + i;
    double* pa[8];
    double* pb[8];
    for (int l = 0; l < 8; ++l) {
      pa[l] = x + 3 * size_t(r[l].a);
      pb[l] = x + 3 * size_t(r[l].b);
    }
    __m256d ax4[2], ay4[2], az4[2], bx4[2], by4[2], bz4[2];
    for (int h = 0; h < 2; ++h) {
      gather4(pa + 4 * h, ax4[h], ay4[h], az4[h]);
      gather4(pb + 4 * h, bx4[h], by4[h], bz4[h]);
    }
    const __m512d ax = join(ax4), ay = join(ay4), az = join(az4), bx = join(bx4), by = join(by4), bz = join(bz4);
    // Row k's (rest, min_length, wa, wb) in 256-bit lane k / 4 of register k % 4, then transposed.
    __m512d c[4];
    for (int k = 0; k < 4; ++k) {
      c[k] =
          _mm512_insertf64x4(_mm512_castpd256_pd512(_mm256_loadu_pd(&r[k].rest)), _mm256_loadu_pd(&r[k + 4].rest), 1);
    }
    const __m512d t0 = _mm512_unpacklo_pd(c[0], c[1]), t1 = _mm512_unpackhi_pd(c[0], c[1]);  // rest wa, min wb
    const __m512d t2 = _mm512_unpacklo_pd(c[2], c[3]), t3 = _mm512_unpackhi_pd(c[2], c[3]);
    const __m512d rest = _mm512_permutex2var_pd(t0, low_pairs, t2), wa = _mm512_permutex2var_pd(t0, high_pairs, t2);
    const __m512d min_length = _mm512_permutex2var_pd(t1, low_pairs, t3);
    const __m512d wb = _mm512_permutex2var_pd(t1, high_pairs, t3);
    const __m512d w_sum = _mm512_add_pd(wa, wb);
    const __m512d d0 = _mm512_sub_pd(ax, bx), d1 = _mm512_sub_pd(ay, by), d2 = _mm512_sub_pd(az, bz);
    const __m512d length = _mm512_sqrt_pd(
        _mm512_add_pd(_mm512_add_pd(_mm512_mul_pd(d0, d0), _mm512_mul_pd(d1, d1)), _mm512_mul_pd(d2, d2)));
    // distance_step's early returns: w_sum > 0, length > min_length, length <= max (false on NaN).
    const __mmask8 valid = _mm512_cmp_pd_mask(w_sum, zero, _CMP_GT_OQ) &
                           _mm512_cmp_pd_mask(length, min_length, _CMP_GT_OQ) &
                           _mm512_cmp_pd_mask(length, big, _CMP_LE_OQ);
    const __m512d l0 = _mm512_loadu_pd(lambda + i);
    const __m512d numerator = _mm512_sub_pd(_mm512_xor_pd(_mm512_sub_pd(length, rest), sign), _mm512_mul_pd(va, l0));
    const __m512d dl = _mm512_div_pd(numerator, _mm512_add_pd(w_sum, va));
    _mm512_storeu_pd(lambda + i, _mm512_mask_add_pd(l0, valid, l0, dl));
    const __m512d step = _mm512_div_pd(dl, length);
    const __m512d si = _mm512_mul_pd(wa, step), sj = _mm512_mul_pd(wb, step);
    // Where valid: a + si d, b - sj d; elsewhere what was read.
    const __m512d nax = _mm512_mask_add_pd(ax, valid, ax, _mm512_mul_pd(si, d0));
    const __m512d nay = _mm512_mask_add_pd(ay, valid, ay, _mm512_mul_pd(si, d1));
    const __m512d naz = _mm512_mask_add_pd(az, valid, az, _mm512_mul_pd(si, d2));
    const __m512d nbx = _mm512_mask_sub_pd(bx, valid, bx, _mm512_mul_pd(sj, d0));
    const __m512d nby = _mm512_mask_sub_pd(by, valid, by, _mm512_mul_pd(sj, d1));
    const __m512d nbz = _mm512_mask_sub_pd(bz, valid, bz, _mm512_mul_pd(sj, d2));
    scatter4(pa, _mm512_castpd512_pd256(nax), _mm512_castpd512_pd256(nay), _mm512_castpd512_pd256(naz));
    scatter4(pb, _mm512_castpd512_pd256(nbx), _mm512_castpd512_pd256(nby), _mm512_castpd512_pd256(nbz));
    scatter4(pa + 4, _mm512_extractf64x4_pd(nax, 1), _mm512_extractf64x4_pd(nay, 1), _mm512_extractf64x4_pd(naz, 1));
    scatter4(pb + 4, _mm512_extractf64x4_pd(nbx, 1), _mm512_extractf64x4_pd(nby, 1), _mm512_extractf64x4_pd(nbz, 1));
  }
  stretch_rows_avx2(x, rows, lambda, i, end, alpha);
}
#endif

}  // namespace

KernelIsa kernel_isa() {
#if defined(__x86_64__)
  static const KernelIsa best = __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512dq") &&
                                        __builtin_cpu_supports("avx512vl") && __builtin_cpu_supports("avx512bw")
                                    ? KernelIsa::kAvx512
                                : __builtin_cpu_supports("avx2") ? KernelIsa::kAvx2
                                                                 : KernelIsa::kBaseline;
  return best;
#else
  return KernelIsa::kBaseline;
#endif
}

void solve_stretch_rows(KernelIsa isa, double* x, const StretchRow* rows, double* lambda, uint32_t begin, uint32_t end,
                        double alpha, bool disjoint) {
#if defined(__x86_64__)
  if (disjoint && isa == KernelIsa::kAvx512) return stretch_rows_avx512(x, rows, lambda, begin, end, alpha);
  if (disjoint && isa == KernelIsa::kAvx2) return stretch_rows_avx2(x, rows, lambda, begin, end, alpha);
#endif
  stretch_rows_scalar(x, rows, lambda, begin, end, alpha);
}

void solve_stretch_rows(double* x, const StretchRow* rows, double* lambda, uint32_t begin, uint32_t end, double alpha,
                        bool disjoint) {
  solve_stretch_rows(kernel_isa(), x, rows, lambda, begin, end, alpha, disjoint);
}

DVX_CLONES
void embed_rows(const float* corners, const EmbedRow* rows, uint32_t begin, uint32_t end, float* out) {
  typedef float F4 __attribute__((vector_size(16)));
  for (uint32_t i = begin; i < end; ++i) {
    const EmbedRow& e = rows[i];
    const float* c = corners + 32 * size_t(e.piece);
    const auto p = [c](int k) {  // one corner (loads straight into a register, no copy)
      F4 r;
      std::memcpy(&r, c + 4 * k, sizeof r);
      return r;
    };
    const float u = e.u, v = e.v, w = e.w;
    const F4 p0 = p(0), p2 = p(2), p4 = p(4), p6 = p(6);
    const F4 x0 = p0 + u * (p(1) - p0), x1 = p2 + u * (p(3) - p2);
    const F4 x2 = p4 + u * (p(5) - p4), x3 = p6 + u * (p(7) - p6);
    const F4 y0 = x0 + v * (x1 - x0), y1 = x2 + v * (x3 - x2);
    const F4 r = y0 + w * (y1 - y0);
    float* o = out + 3 * size_t(e.slot);
    o[0] = r[0];
    o[1] = r[1];
    o[2] = r[2];
  }
}

bool shape_matching_rest(const double* inv_mass, const uint32_t* indices, const double* rest, int count,
                         ShapeRest& out) {
  out = ShapeRest{};
  if (count <= 0 || count > kShapeMaxParticles) return false;
  // Mean mass of the free particles; anchored ones weigh kAnchorWeight times that.
  constexpr double kAnchorWeight = 1e6;
  double free_mass = 0.0;
  int free_count = 0;
  for (int k = 0; k < count; ++k) {
    const double w = inv_mass[indices[k]];
    if (w > 0.0) {
      free_mass += 1.0 / w;
      ++free_count;
    }
  }
  if (free_count == 0) return false;
  const double anchored_mass = kAnchorWeight * free_mass / free_count;

  // Masses and the rest mass centre, then the offsets from it.
  double total = 0.0;
  Vector3d sum_r = Vector3d::Zero();
  for (int k = 0; k < count; ++k) {
    const double w = inv_mass[indices[k]];
    const double m = w > 0.0 ? 1.0 / w : anchored_mass;
    out.mass[k] = m;
    out.moves[k] = w > 0.0;
    sum_r += m * Vector3d(rest[3 * k], rest[3 * k + 1], rest[3 * k + 2]);
    total += m;
  }
  out.total = total;
  out.inv_total = 1.0 / total;
  const Vector3d rest_centre = sum_r / total;
  for (int k = 0; k < count; ++k) {
    for (int e = 0; e < 3; ++e) out.offset[k][e] = rest[3 * k + e] - rest_centre[e];
  }
  out.count = count;
  return true;
}

void solve_shape_matching(double* x, const uint32_t* indices, const ShapeRest& r, double stiffness,
                          Quaterniond& rotation, int rotation_iterations) {
  if (r.count == 0) return;
  ShapeFrame f;
  shape_matching_frame(x, indices, r, rotation, rotation_iterations, f);
  // Goals depend only on the frame computed above, so moving particles one by one is the same as
  // applying shape_matching_corrections' deltas.
  for (int k = 0; k < r.count; ++k) {
    if (!r.moves[k]) continue;
    double goal[3];
    shape_goal(f, r.offset[k], goal);
    double* xi = x + 3 * size_t(indices[k]);
    for (int e = 0; e < 3; ++e) xi[e] = f.p[k][e] + stiffness * (goal[e] - f.p[k][e]);
  }
}

void shape_block_add(ShapeBlock& b, uint32_t piece, const uint32_t* indices, const ShapeRest& r) {
  const int lane = b.lanes++;
  // Every lane from this one on (the unused ones repeat the last lane until they are filled).
  for (int l = lane; l < kShapeLanes; ++l) {
    b.piece[l] = piece;
    b.inv_total[l] = r.inv_total;
    for (int k = 0; k < kS; ++k) {
      b.index[k][l] = indices[k < r.count ? k : 0];
      b.mass[k][l] = r.mass[k];
      b.moves[k][l] = r.moves[k];
      for (int e = 0; e < 3; ++e) b.offset[k][e][l] = r.offset[k][e];
    }
  }
}

namespace {

void shape_blocks_baseline(double* x, const ShapeBlock* blocks, uint32_t begin, uint32_t end, double stiffness,
                           Quaterniond* rotations, bool disjoint) {
  lanes::shape_blocks_lanes<V4>(x, blocks, begin, end, stiffness, rotations, disjoint);
}

#if defined(__x86_64__)
DVX_AVX2_PATH void shape_blocks_avx2(double* x, const ShapeBlock* blocks, uint32_t begin, uint32_t end,
                                     double stiffness, Quaterniond* rotations, bool disjoint) {
  avx2_lanes::shape_blocks_lanes<V4>(x, blocks, begin, end, stiffness, rotations, disjoint);
}

DVX_AVX512_PATH void shape_blocks_avx512(double* x, const ShapeBlock* blocks, uint32_t begin, uint32_t end,
                                         double stiffness, Quaterniond* rotations, bool disjoint) {
  avx512_lanes::shape_blocks_lanes<V8>(x, blocks, begin, end, stiffness, rotations, disjoint);
}
#endif

}  // namespace

void solve_shape_blocks(KernelIsa isa, double* x, const ShapeBlock* blocks, uint32_t begin, uint32_t end,
                        double stiffness, Quaterniond* rotations, bool disjoint) {
#if defined(__x86_64__)
  if (isa == KernelIsa::kAvx512) return shape_blocks_avx512(x, blocks, begin, end, stiffness, rotations, disjoint);
  if (isa == KernelIsa::kAvx2) return shape_blocks_avx2(x, blocks, begin, end, stiffness, rotations, disjoint);
#endif
  shape_blocks_baseline(x, blocks, begin, end, stiffness, rotations, disjoint);
}

void solve_shape_blocks(double* x, const ShapeBlock* blocks, uint32_t begin, uint32_t end, double stiffness,
                        Quaterniond* rotations, bool disjoint) {
  solve_shape_blocks(kernel_isa(), x, blocks, begin, end, stiffness, rotations, disjoint);
}

// The rows one at a time: the lane code on one lane (the same operations as every path's lanes).
void solve_elastic_rows(double* x, const double* previous, const ElasticRow* rows, double* lambda, uint32_t begin,
                        uint32_t end, const ElasticConstants& k, Quaterniond* rotation, const double* enhancement) {
  lanes::elastic_rows_lanes<V1>(x, previous, rows, lambda, begin, end, k, rotation, enhancement);
}

namespace {

void elastic_rows_baseline(double* x, const double* previous, const ElasticRow* rows, double* lambda, uint32_t begin,
                           uint32_t end, const ElasticConstants& k, Quaterniond* rotation,
                           const double* enhancement) {
  lanes::elastic_rows_lanes<V4>(x, previous, rows, lambda, begin, end, k, rotation, enhancement);
}

#if defined(__x86_64__)
DVX_AVX2_PATH void elastic_rows_avx2(double* x, const double* previous, const ElasticRow* rows, double* lambda,
                                     uint32_t begin, uint32_t end, const ElasticConstants& k, Quaterniond* rotation,
                                     const double* enhancement) {
  avx2_lanes::elastic_rows_lanes<V4>(x, previous, rows, lambda, begin, end, k, rotation, enhancement);
}

DVX_AVX512_PATH void elastic_rows_avx512(double* x, const double* previous, const ElasticRow* rows, double* lambda,
                                         uint32_t begin, uint32_t end, const ElasticConstants& k,
                                         Quaterniond* rotation, const double* enhancement) {
  avx512_lanes::elastic_rows_lanes<V8>(x, previous, rows, lambda, begin, end, k, rotation, enhancement);
}
#endif

}  // namespace

void solve_elastic_blocks(KernelIsa isa, double* x, const double* previous, const ElasticRow* rows, double* lambda,
                          uint32_t begin, uint32_t end, const ElasticConstants& k, Quaterniond* rotation,
                          const double* enhancement, bool disjoint) {
  if (!disjoint) return solve_elastic_rows(x, previous, rows, lambda, begin, end, k, rotation, enhancement);
#if defined(__x86_64__)
  if (isa == KernelIsa::kAvx512) return elastic_rows_avx512(x, previous, rows, lambda, begin, end, k, rotation, enhancement);
  if (isa == KernelIsa::kAvx2) return elastic_rows_avx2(x, previous, rows, lambda, begin, end, k, rotation, enhancement);
#endif
  elastic_rows_baseline(x, previous, rows, lambda, begin, end, k, rotation, enhancement);
}

void solve_elastic_blocks(double* x, const double* previous, const ElasticRow* rows, double* lambda, uint32_t begin,
                          uint32_t end, const ElasticConstants& k, Quaterniond* rotation, const double* enhancement,
                          bool disjoint) {
  solve_elastic_blocks(kernel_isa(), x, previous, rows, lambda, begin, end, k, rotation, enhancement, disjoint);
}

void solve_shape_block(double* x, const ShapeBlock& b, double stiffness, Quaterniond* rotations) {
  solve_shape_blocks(x, &b, 0, 1, stiffness, rotations, false);
}

void solve_shape_matching(double* x, const double* inv_mass, const uint32_t* indices, const double* rest, int count,
                          double stiffness, Quaterniond& rotation) {
  ShapeRest r;
  if (shape_matching_rest(inv_mass, indices, rest, count, r)) {
    solve_shape_matching(x, indices, r, stiffness, rotation, kShapeRotationIterations);
  }
}

void shape_matching_corrections(const double* x, const double* inv_mass, const uint32_t* indices, const double* rest,
                                int count, double stiffness, Quaterniond& rotation, double* delta) {
  for (int k = 0; k < 3 * count; ++k) delta[k] = 0.0;
  ShapeRest r;
  if (!shape_matching_rest(inv_mass, indices, rest, count, r)) return;
  ShapeFrame f;
  shape_matching_frame(x, indices, r, rotation, kShapeRotationIterations, f);
  for (int k = 0; k < count; ++k) {
    if (!r.moves[k]) continue;
    double goal[3];
    shape_goal(f, r.offset[k], goal);
    for (int e = 0; e < 3; ++e) delta[3 * k + e] = stiffness * (goal[e] - f.p[k][e]);
  }
}

}  // namespace dvx
