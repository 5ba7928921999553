#include "sim/pbd_elastic.h"

#include "sim/pbd_kernels.h"

#include <array>
#include <cmath>

namespace dvx {
namespace {

// Shape-function gradients of the unit-edge hexahedron (times inv_edge: the piece's) at the 8 Gauss
// points (point g at xi = +-1/sqrt(3), signs from g's bits like the corners) and at the centre (9th):
// kGrad[point][corner][axis]. dN_a/dX_0 = s0 (1 + s1 xi1)(1 + s2 xi2) / 4 for an edge of 1.
struct GradTable {
  double g[9][8][3];
};

GradTable make_grad_table() {
  GradTable t{};
  const double q = 1.0 / std::sqrt(3.0);
  for (int point = 0; point < 9; ++point) {
    double xi[3];
    for (int e = 0; e < 3; ++e) xi[e] = point == 8 ? 0.0 : (((point >> e) & 1) ? q : -q);
    for (int a = 0; a < 8; ++a) {
      double s[3];
      for (int e = 0; e < 3; ++e) s[e] = ((a >> e) & 1) ? 1.0 : -1.0;
      for (int e = 0; e < 3; ++e) {
        const int e1 = (e + 1) % 3, e2 = (e + 2) % 3;
        t.g[point][a][e] = s[e] * (1.0 + s[e1] * xi[e1]) * (1.0 + s[e2] * xi[e2]) / 4.0;
      }
    }
  }
  return t;
}

const GradTable kGrad = make_grad_table();

// F (row-major) = sum_a (x_a - x_0) (x) G_a, with G_a the table's gradient times inv_edge (sum_a
// G_a = 0, so corner 0 as the origin only keeps the differences small). Gs: the scaled table of one
// point (ElasticConstants::grad). Inlined: called 9 times a piece per iteration, it was 37 % of the
// solve's instructions as a call.
__attribute__((always_inline)) inline void deformation_gradient(const double (*xs)[3], const double (*Gs)[3], double F[9]) {
  for (int i = 0; i < 9; ++i) F[i] = 0.0;
  for (int a = 1; a < 8; ++a) {
    for (int i = 0; i < 3; ++i) {
      const double d = xs[a][i] - xs[0][i];
      for (int j = 0; j < 3; ++j) F[3 * i + j] += d * Gs[a][j];
    }
  }
}

// One XPBD constraint on the 8 corners: value c, gradient per corner grad[a] (3 each), compliance
// alpha (already / h^2), damping gamma (beta / h), multiplier lambda.
__attribute__((always_inline)) inline void apply(double (*xs)[3], const double (*prev)[3], const double* w, double c,
                                                 const double (*grad)[3], double alpha, double gamma, double& lambda) {
  double denom = 0.0, rate = 0.0;
  for (int a = 0; a < 8; ++a) {
    const double g2 = grad[a][0] * grad[a][0] + grad[a][1] * grad[a][1] + grad[a][2] * grad[a][2];
    denom += w[a] * g2;
    if (gamma > 0.0) {
      for (int e = 0; e < 3; ++e) rate += grad[a][e] * (xs[a][e] - prev[a][e]);
    }
  }
  const double d = (1.0 + gamma) * denom + alpha;
  if (!(d > 1e-300)) return;
  const double dl = (-c - alpha * lambda - gamma * rate) / d;
  if (!std::isfinite(dl)) return;
  lambda += dl;
  for (int a = 0; a < 8; ++a) {
    const double s = w[a] * dl;
    for (int e = 0; e < 3; ++e) xs[a][e] += s * grad[a][e];
  }
}

}  // namespace

const double (&kHexGradients)[9][8][3] = kGrad.g;

ElasticConstants elastic_constants(double youngs_modulus, double poisson_ratio, double beta, double sim_size, double h) {
  ElasticConstants k;
  const double E = youngs_modulus, nu = poisson_ratio;
  const double mu = E / (2.0 * (1.0 + nu));
  const double lambda = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu));
  k.inv_edge = 1.0 / sim_size;
  k.alpha_dev = 1.0 / (2.0 * mu * h * h);
  k.volume = lambda > 0.0;
  k.alpha_vol = k.volume ? 1.0 / (lambda * h * h) : 0.0;
  k.damping = beta > 0.0 ? beta / h : 0.0;
  for (int g = 0; g < 9; ++g) {
    for (int a = 0; a < 8; ++a) {
      for (int e = 0; e < 3; ++e) k.grad[g][a][e] = kGrad.g[g][a][e] * k.inv_edge;
    }
  }
  return k;
}

void hex_deformation_gradient(const double* corners, const double xi[3], double inv_edge, double F[9]) {
  double G[8][3];
  for (int a = 0; a < 8; ++a) {
    double s[3];
    for (int e = 0; e < 3; ++e) s[e] = ((a >> e) & 1) ? 1.0 : -1.0;
    for (int e = 0; e < 3; ++e) {
      const int e1 = (e + 1) % 3, e2 = (e + 2) % 3;
      G[a][e] = s[e] * (1.0 + s[e1] * xi[e1]) * (1.0 + s[e2] * xi[e2]) / 4.0 * inv_edge;
    }
  }
  double xs[8][3];
  for (int a = 0; a < 8; ++a) {
    for (int e = 0; e < 3; ++e) xs[a][e] = corners[3 * a + e];
  }
  deformation_gradient(xs, G, F);
}

void solve_elastic_rows(double* x, const double* previous, const ElasticRow* rows, double* lambda, uint32_t begin,
                        uint32_t end, const ElasticConstants& k, Eigen::Quaterniond* rotation) {
  for (uint32_t r = begin; r < end; ++r) {
    const ElasticRow& row = rows[r];
    if (!(row.volume > 0.0)) continue;
    // The corners in a local copy (written back after the row's 9 constraints: no other row of the
    // call shares them, and the same operations run on the same values).
    double xs[8][3], prev[8][3];
    for (int a = 0; a < 8; ++a) {
      for (int e = 0; e < 3; ++e) {
        xs[a][e] = x[3 * size_t(row.p[a]) + e];
        prev[a][e] = previous[3 * size_t(row.p[a]) + e];
      }
    }
    double* lam = lambda + size_t(kElasticConstraints) * r;
    double F[9], grad[8][3];
    // The rotation of F at the centre (warm-started; kept for the next solve).
    deformation_gradient(xs, k.grad[8], F);
    Eigen::Matrix3d Fc;
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) Fc(i, j) = F[3 * i + j];
    }
    Eigen::Quaterniond& q = rotation[row.piece];
    q = extract_rotation_step(Fc, q, kShapeRotationIterations);
    const Eigen::Matrix3d R = q.toRotationMatrix();
    // Shear: |F_g - R| at each Gauss point holding material; gradient (F_g - R) G_a / C.
    for (int g = 0; g < 8; ++g) {
      if (!(row.octant[g] > 0.0)) continue;
      const double alpha_dev = k.alpha_dev / row.octant[g];
      const double (*G)[3] = kGrad.g[g];
      deformation_gradient(xs, k.grad[g], F);
      double c2 = 0.0;
      for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
          F[3 * i + j] -= R(i, j);
          c2 += F[3 * i + j] * F[3 * i + j];
        }
      }
      const double c = std::sqrt(c2);
      if (!(c > 1e-12)) continue;
      const double s = k.inv_edge / c;
      for (int a = 0; a < 8; ++a) {
        for (int i = 0; i < 3; ++i) grad[a][i] = (F[3 * i] * G[a][0] + F[3 * i + 1] * G[a][1] + F[3 * i + 2] * G[a][2]) * s;
      }
      apply(xs, prev, row.w, c, grad, alpha_dev, k.damping, lam[g]);
    }
    // Volume: det F - 1 at the centre; gradient cof(F) G_a.
    if (k.volume) {
      const double (*G)[3] = kGrad.g[8];
      deformation_gradient(xs, k.grad[8], F);
      double cof[9];
      cof[0] = F[4] * F[8] - F[5] * F[7];
      cof[1] = F[5] * F[6] - F[3] * F[8];
      cof[2] = F[3] * F[7] - F[4] * F[6];
      cof[3] = F[2] * F[7] - F[1] * F[8];
      cof[4] = F[0] * F[8] - F[2] * F[6];
      cof[5] = F[1] * F[6] - F[0] * F[7];
      cof[6] = F[1] * F[5] - F[2] * F[4];
      cof[7] = F[2] * F[3] - F[0] * F[5];
      cof[8] = F[0] * F[4] - F[1] * F[3];
      const double det = F[0] * cof[0] + F[1] * cof[1] + F[2] * cof[2];
      for (int a = 0; a < 8; ++a) {
        for (int i = 0; i < 3; ++i) {
          grad[a][i] = (cof[3 * i] * G[a][0] + cof[3 * i + 1] * G[a][1] + cof[3 * i + 2] * G[a][2]) * k.inv_edge;
        }
      }
      apply(xs, prev, row.w, det - 1.0, grad, k.alpha_vol / row.volume, k.damping, lam[8]);
    }
    for (int a = 0; a < 8; ++a) {
      for (int e = 0; e < 3; ++e) x[3 * size_t(row.p[a]) + e] = xs[a][e];
    }
  }
}

}  // namespace dvx
