#include "sim/pbd_elastic.h"

#include "sim/pbd_kernels.h"

#include <algorithm>
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
// G_a = 0, so corner 0 as the origin only keeps the differences small); the solver's lane code
// (pbd_kernels_lanes.inc, elastic_deformation_gradient) sums in the same order.
void deformation_gradient(const double (*xs)[3], const double (*Gs)[3], double F[9]) {
  for (int i = 0; i < 9; ++i) F[i] = 0.0;
  for (int a = 1; a < 8; ++a) {
    for (int i = 0; i < 3; ++i) {
      const double d = xs[a][i] - xs[0][i];
      for (int j = 0; j < 3; ++j) F[3 * i + j] += d * Gs[a][j];
    }
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
  k.mu = mu;
  k.lame = lambda;
  k.h = h;
  const double lame_points = std::min(lambda, kPointLameRatio * mu);
  k.volume_ratio = mu > 0.0 ? lame_points / (2.0 * mu) : 0.0;
  k.lame_centre = lambda > lame_points ? lambda - lame_points : 0.0;
  k.alpha_vol_centre = k.lame_centre > 0.0 ? 1.0 / (k.lame_centre * h * h) : 0.0;
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

}  // namespace dvx
