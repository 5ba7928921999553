#include "sim/contour.h"

#include "sim/cut.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

namespace dvx {

namespace {

// The QEF written about a centre point m, y = x - m:
//   E(y) = y^T H y - 2 y^T r + const,   H = A^T A,   r = A^T b - A^T A m.
//
// Its minimiser uses a truncated pseudo-inverse of H: the eigenvalues of A^T A are the squared
// singular values of A, so dropping singular values of A below `truncation * sigma_max` means
// dropping eigenvalues below truncation^2 * lambda_max. Along dropped directions y stays 0 (the
// mass-point bias).
//
// When that minimiser leaves the box [lo, hi], the result is the minimiser of E over the box
// (not a coordinate clamp, which can pull the point off a sharp feature that does cross the
// box): every face, edge and corner of the box is tried with its coordinates fixed and the
// others solved with the same truncation; the feasible candidate of least E wins (ties: the one
// nearest the mass point, then enumeration order).
struct CentredQef {
  Eigen::Matrix3d h;
  Vec3d r;
  double threshold;  // eigenvalues at or below are dropped

  double energy(const Vec3d& y) const { return y.dot(h * y) - 2.0 * y.dot(r); }
};

// Minimiser over the free coordinates (mask bit a set: coordinate a free, at most two) with
// the fixed coordinates set to the given y values.
Vec3d solve_restricted(const CentredQef& q, unsigned free_mask, const Vec3d& y_fixed) {
  int idx[3];
  int nf = 0;
  for (int a = 0; a < 3; ++a) {
    if (free_mask >> a & 1u) idx[nf++] = a;
  }
  Vec3d y = y_fixed;
  if (nf == 0) return y;
  // r' = r_F - H_F,fixed y_fixed
  Vec3d yfix = y_fixed;
  for (int i = 0; i < nf; ++i) yfix[idx[i]] = 0.0;
  const Vec3d rr = q.r - q.h * yfix;
  if (nf == 1) {
    const int a = idx[0];
    y[a] = q.h(a, a) > q.threshold ? rr[a] / q.h(a, a) : 0.0;
    return y;
  }
  if (nf == 2) {
    Eigen::Matrix2d h2;
    h2 << q.h(idx[0], idx[0]), q.h(idx[0], idx[1]), q.h(idx[1], idx[0]), q.h(idx[1], idx[1]);
    const Eigen::Vector2d r2(rr[idx[0]], rr[idx[1]]);
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig;
    eig.computeDirect(h2);
    Eigen::Vector2d d = Eigen::Vector2d::Zero();
    for (int i = 0; i < 2; ++i) {
      const double l = eig.eigenvalues()[i];
      if (l > q.threshold) {
        const Eigen::Vector2d v = eig.eigenvectors().col(i);
        d += v * (v.dot(r2) / l);
      }
    }
    y[idx[0]] = d[0];
    y[idx[1]] = d[1];
    return y;
  }
  return y;  // nf == 3 is the unconstrained solve, done by the caller
}

// Unconstrained minimiser y (about the centre) with the truncated pseudo-inverse. Returns false
// when H has no usable direction (zero or non-finite): y = 0 then. Fills q.threshold and the
// ascending eigenvalues.
bool free_minimiser(CentredQef& q, double truncation, Vec3d& y, Vec3d& lambda) {
  y = Vec3d::Zero();
  lambda = Vec3d::Zero();
  if (!q.h.allFinite() || !q.r.allFinite()) return false;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
  eig.computeDirect(q.h);
  lambda = eig.eigenvalues();  // ascending
  const double lmax = lambda[2];
  if (!(lmax > 0.0) || !std::isfinite(lmax)) return false;
  q.threshold = std::max(truncation * truncation, 1e-12) * lmax;
  for (int i = 0; i < 3; ++i) {
    if (lambda[i] > q.threshold) {
      const Vec3d v = eig.eigenvectors().col(i);
      y += v * (v.dot(q.r) / lambda[i]);
    }
  }
  if (!y.allFinite()) {
    y = Vec3d::Zero();
    return false;
  }
  return true;
}

bool in_box(const Vec3d& y, const Vec3d& lo, const Vec3d& hi, double eps) {
  return (y.array() >= lo.array() - eps).all() && (y.array() <= hi.array() + eps).all();
}

// Minimiser of the QEF over the box [ylo, yhi] (about the centre) when the free minimiser is
// outside it: each coordinate free, at lo or at hi (not all free), solved with the same
// truncation; the feasible candidate of least energy wins (ties: nearest the centre, then
// enumeration order). Corners are always feasible, so a candidate always exists.
Vec3d box_minimiser(const CentredQef& q, const Vec3d& ylo, const Vec3d& yhi, double eps) {
  Vec3d best_y = 0.5 * (ylo + yhi);
  double best_e = std::numeric_limits<double>::infinity();
  double best_n = std::numeric_limits<double>::infinity();
  const double tol = 1e-12 * std::max(1.0, q.h.cwiseAbs().maxCoeff());
  for (int code = 1; code < 27; ++code) {
    const int state[3] = {code % 3, code / 3 % 3, code / 9};
    unsigned free_mask = 0;
    Vec3d y_fixed = Vec3d::Zero();
    for (int a = 0; a < 3; ++a) {
      if (state[a] == 0) {
        free_mask |= 1u << a;
      } else {
        y_fixed[a] = state[a] == 1 ? ylo[a] : yhi[a];
      }
    }
    Vec3d cand = solve_restricted(q, free_mask, y_fixed);
    if (!cand.allFinite() || !in_box(cand, ylo, yhi, eps)) continue;
    cand = cand.cwiseMax(ylo).cwiseMin(yhi);
    const double e = q.energy(cand);
    const double n = cand.squaredNorm();
    if (e < best_e - tol || (e <= best_e + tol && n < best_n)) {
      best_e = std::min(e, best_e);
      best_n = n;
      best_y = cand;
    }
  }
  return best_y;
}

Vec3d solve_centred(const Eigen::Matrix3d& ata, const Vec3d& rhs, const Vec3d& centre, const Vec3d& lo, const Vec3d& hi,
                    double truncation) {
  const Vec3d box_centre = 0.5 * (lo + hi);
  if (!centre.allFinite()) return box_centre;
  CentredQef q{ata, rhs, 0.0};
  Vec3d y, lambda;
  if (!free_minimiser(q, truncation, y, lambda)) return centre.cwiseMax(lo).cwiseMin(hi);
  const Vec3d ylo = lo - centre, yhi = hi - centre;
  const double eps = 1e-9 * std::max(1.0, (hi - lo).maxCoeff());
  if (!in_box(y, ylo, yhi, eps)) y = box_minimiser(q, ylo, yhi, eps);
  Vec3d x = (centre + y).cwiseMax(lo).cwiseMin(hi);
  if (!x.allFinite()) x = box_centre;
  return x;
}

// snorm16 -> unit vector (same convention as decode_normal: value / 32767, clamped to [-1, 1]),
// renormalised so every crossing weighs the same in the QEF.
inline Vec3d unpack_normal(const int16_t in[3]) {
  Vec3d n(std::max(-1.0, in[0] / 32767.0), std::max(-1.0, in[1] / 32767.0), std::max(-1.0, in[2] / 32767.0));
  const double len = n.norm();
  return len > 0.0 ? Vec3d(n / len) : Vec3d::Zero();
}

// QEF accumulator of one surface vertex, in lattice units relative to its voxel's lowest
// corner (so every coordinate is in [0, 1] and sums stay well conditioned).
struct QefSum {
  double a00, a01, a02, a11, a12, a22;  // A^T A
  double b0, b1, b2;                    // A^T b
  double btb;                           // b^T b (for the residual)
  double p0, p1, p2;                    // sum of points (mass point numerator)
  double count;

  void add(const Vec3d& n, const Vec3d& p) {
    const double nb = n.dot(p);
    a00 += n[0] * n[0];
    a01 += n[0] * n[1];
    a02 += n[0] * n[2];
    a11 += n[1] * n[1];
    a12 += n[1] * n[2];
    a22 += n[2] * n[2];
    b0 += n[0] * nb;
    b1 += n[1] * nb;
    b2 += n[2] * nb;
    btb += nb * nb;
    p0 += p[0];
    p1 += p[1];
    p2 += p[2];
    count += 1.0;
  }
};

// A free QEF minimiser outside its voxel is trusted (within feature_margin) only for a clear
// feature: the second singular value at least this fraction of the largest (an edge or corner
// of more than ~33 degrees, not a gently curved patch).
constexpr double kFeatureMinRatio = 0.3;

// Vertex position in the voxel's local frame (lattice units, voxel = [0,1]^3) from its QEF sums:
// the free QEF minimiser when it lies in the voxel, or within feature_margin of it for a clear,
// consistent feature (a sharp edge or corner passing just outside the voxel); otherwise the QEF
// minimum over the voxel.
Vec3d place_from_sum(const QefSum& s, const ContourParams& params) {
  const double trunc = double(params.svd_truncation);
  const double margin = std::max(0.0, double(params.feature_margin));
  const double residual2 = double(params.feature_residual) * double(params.feature_residual);
  const double eps = 1e-9;
  Vec3d x = Vec3d::Constant(0.5);
  if (s.count > 0.0) {
    const Vec3d mass = Vec3d(s.p0, s.p1, s.p2) / s.count;
    CentredQef q;
    q.h << s.a00, s.a01, s.a02, s.a01, s.a11, s.a12, s.a02, s.a12, s.a22;
    const Vec3d atb(s.b0, s.b1, s.b2);
    q.r = atb - q.h * mass;
    q.threshold = 0.0;
    Vec3d y, lambda;
    if (!free_minimiser(q, trunc, y, lambda)) {
      x = mass.cwiseMax(0.0).cwiseMin(1.0);
    } else {
      const Vec3d ylo = -mass, yhi = Vec3d::Ones() - mass;
      double lo = 0.0;  // the box x is kept in: [lo, 1 - lo]
      if (!in_box(y, ylo, yhi, eps)) {
        bool feature = false;
        if (margin > 0.0 && lambda[1] >= kFeatureMinRatio * kFeatureMinRatio * lambda[2]) {
          const Vec3d mlo = ylo - Vec3d::Constant(margin), mhi = yhi + Vec3d::Constant(margin);
          const Vec3d ym = in_box(y, mlo, mhi, eps) ? y : box_minimiser(q, mlo, mhi, eps);
          const Vec3d xf = mass + ym;  // residual sum (n.x - n.p)^2 = x'Hx - 2x'A'b + b'b
          const double e = xf.dot(q.h * xf) - 2.0 * xf.dot(atb) + s.btb;
          if (e <= residual2 * s.count) {
            feature = true;
            y = ym;
            lo = -margin;
          }
        }
        if (!feature) y = box_minimiser(q, ylo, yhi, eps);
      }
      x = (mass + y).cwiseMax(lo).cwiseMin(1.0 - lo);
    }
    if (!x.allFinite()) x = Vec3d::Constant(0.5);
  }
  return x;
}

}  // namespace

Vec3d solve_qef(const Vec3d* points, const Vec3d* normals, int count, const Vec3d& lo, const Vec3d& hi,
                float svd_truncation) {
  if (count <= 0 || points == nullptr || normals == nullptr) {
    return 0.5 * (lo + hi);
  }
  Vec3d mass = Vec3d::Zero();
  for (int i = 0; i < count; ++i) mass += points[i];
  mass /= double(count);
  if (!mass.allFinite()) return 0.5 * (lo + hi);

  Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
  Vec3d rhs = Vec3d::Zero();  // A^T b - A^T A m = sum n (n . (p - m))
  for (int i = 0; i < count; ++i) {
    const Vec3d& n = normals[i];
    if (!n.allFinite()) continue;
    ata.noalias() += n * n.transpose();
    rhs += n * n.dot(points[i] - mass);
  }
  return solve_centred(ata, rhs, mass, lo, hi, double(svd_truncation));
}

Vec3d place_voxel_vertex(const Vec3d* points_local, const Vec3d* normals, int count, const ContourParams& params) {
  QefSum sum{};
  for (int i = 0; i < count; ++i) sum.add(normals[i], points_local[i]);
  return place_from_sum(sum, params);
}

SurfaceMesh dual_contour(const VoxelModel& model, const ContourParams& params) {
  // One construction: the surface of a cut state without cuts (manifold dual contouring, cut.h).
  CutState state;
  init_cut_state(model, state, params);
  return compact_surface(state.surface);
}

}  // namespace dvx
