#include "sim/pbd_global.h"

#include "sim/pbd.h"
#include "sim/pbd_kernels.h"

#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>

#include <algorithm>
#include <cmath>

namespace dvx {

// The global step's structure (rebuilt with the model or the substep) and its scratch.
struct GlobalStepCache {
  // The key of the factorisation: the model's revision and the constants in the matrix.
  uint64_t revision = ~uint64_t(0);
  double h = -1.0, mu = -1.0, lame = -1.0, damping = -1.0;
  bool ok = false;  // the factorisation succeeded
  // Unknowns: each particle of a hexahedron with material that is not anchored, in particle order.
  std::vector<uint32_t> unknown;   // (particles) its unknown, kNone: not solved
  std::vector<uint32_t> particle;  // (unknowns) its particle
  Eigen::VectorXd mass_h2;         // (unknowns) m / h^2
  // The hexahedra with material, as (colour, index) into PbdCache::elastic_rows, and their corners'
  // unknowns (8 per row, kNone where anchored).
  std::vector<uint32_t> row_colour, row_index, row_unknown;
  // Each row's stiffness in its own frame (R = I), 24 x 24 column-major: apply_row on each corner axis
  // and mode amplitude once per structure, the modes condensed out; the step's K is R K0 R^T per
  // corner block plus the centre's volume term.
  std::vector<double> stiffness;
  // The incompatible modes (pbd_elastic.h) condensed out: the stiffness above is K_xx - K_xb K_bb^-1
  // K_bx; per row T = K_bb^-1 K_bx (9 x 24, column-major) and K_bb^-1 (9 x 9) in its own frame, its
  // modes' means (3), and per substep the modes' right-hand side -dPsi/dbeta at x_prev (9, world).
  std::vector<double> mode_solve, mode_inverse, mode_mean, mode_rhs;
  // The preconditioner: the step's matrix with each row's rotation when it was factorised.
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> preconditioner;
  // Per substep, per row: its rotation R (9, row-major) and the centre volume's gradient c_a (24) at
  // x_prev.
  std::vector<double> rotation, cof;
  // The rows' rotations when the preconditioner was factorised (9 each), and per unknown the rotation
  // from those frames to the current ones (9 each; the warp below).
  std::vector<double> factorised_rotation, warp;
  // What a refactorisation costs against what the stale factorisation has cost since (operation
  // counts, not the clock): factorise_work = sum over L's columns of their entries squared;
  // iteration_work = one CG iteration (the rows' products and the two triangular solves); stale_work
  // accumulates the iterations beyond kFreshIterations since the last factorisation.
  double factorise_work = 0.0, iteration_work = 0.0, stale_work = 0.0;
  // The conjugate gradients' vectors (unknown u's axis e at 3 u + e, the factorisation's order).
  Eigen::VectorXd b, d, r, z, p, q;
  double load = 0.0;  // |M (x~ - x_prev)| / h^2: the substep's inertia and gravity, the residual's scale
  GlobalStepStats stats;
};

namespace {

constexpr uint32_t kNone = ~0u;

// F (row-major) of the corners xs with the gradient table Gs, as the kernels sum it (differences
// from corner 0).
void gradient_at(const double (*xs)[3], const double (*Gs)[3], double F[9]) {
  for (int i = 0; i < 9; ++i) F[i] = 0.0;
  for (int a = 1; a < 8; ++a) {
    for (int i = 0; i < 3; ++i) {
      const double d = xs[a][i] - xs[0][i];
      for (int j = 0; j < 3; ++j) F[3 * i + j] += d * Gs[a][j];
    }
  }
}

// Cofactor matrix of F (row-major) and its determinant.
double cofactor(const double F[9], double cof[9]) {
  cof[0] = F[4] * F[8] - F[5] * F[7];
  cof[1] = F[5] * F[6] - F[3] * F[8];
  cof[2] = F[3] * F[7] - F[4] * F[6];
  cof[3] = F[2] * F[7] - F[1] * F[8];
  cof[4] = F[0] * F[8] - F[2] * F[6];
  cof[5] = F[1] * F[6] - F[0] * F[7];
  cof[6] = F[1] * F[5] - F[2] * F[4];
  cof[7] = F[2] * F[3] - F[0] * F[5];
  cof[8] = F[0] * F[4] - F[1] * F[3];
  return F[0] * cof[0] + F[1] * cof[1] + F[2] * cof[2];
}

// M (row-major 3x3) times v.
void mul3(const double M[9], const double v[3], double out[3]) {
  for (int i = 0; i < 3; ++i) out[i] = M[3 * i] * v[0] + M[3 * i + 1] * v[1] + M[3 * i + 2] * v[2];
}

// F_g += the incompatible modes' gradient at Gauss point q (pbd_elastic.h; the kernels' sum).
void add_modes(int q, const double* mean, const double* beta, double F[9]) {
  for (int m = 0; m < 3; ++m) {
    const double sm = mode_sign(q, m) - mean[m];
    for (int i = 0; i < 3; ++i) F[3 * i + m] += sm * beta[3 * m + i];
  }
}

// The transpose of add_modes: out_b[m] += the derivative through mode m of a stress-like X at Gauss
// point q (column m of X times the mode's weight there).
void add_modes_transposed(int q, const double* mean, const double X[9], double (&out_b)[3][3]) {
  for (int m = 0; m < 3; ++m) {
    const double sm = mode_sign(q, m) - mean[m];
    for (int i = 0; i < 3; ++i) out_b[m][i] += sm * X[3 * i + m];
  }
}

// A Gauss point of the enhanced element as the kernels compute it: S = sym(R^T F) - I; returns C^2 =
// |S|^2 + volume_ratio tr(S)^2 and sets P = R (S + volume_ratio tr(S) I) (R row-major).
double symmetric_strain(const double* R, const double F[9], double volume_ratio, double P[9]) {
  double RtF[9], S[9], c2 = 0.0;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) RtF[3 * i + j] = R[i] * F[j] + R[3 + i] * F[3 + j] + R[6 + i] * F[6 + j];
  }
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      S[3 * i + j] = 0.5 * (RtF[3 * i + j] + RtF[3 * j + i]) - (i == j ? 1.0 : 0.0);
      c2 += S[3 * i + j] * S[3 * i + j];
    }
  }
  const double trace = S[0] + S[4] + S[8];
  c2 += volume_ratio * trace * trace;
  for (int i = 0; i < 3; ++i) S[4 * i] += volume_ratio * trace;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) P[3 * i + j] = R[3 * i] * S[j] + R[3 * i + 1] * S[3 + j] + R[3 * i + 2] * S[6 + j];
  }
  return c2;
}

// The rotation of F at the centre, from the piece's warm start (kept for the kernels' next solve).
Eigen::Matrix3d centre_rotation(const double F[9], Eigen::Quaterniond& rotation) {
  Eigen::Matrix3d a;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) a(i, j) = F[3 * i + j];
  }
  rotation = extract_rotation_step(a, rotation, kShapeRotationIterations);
  return rotation.toRotationMatrix();
}

const ElasticRow& row_of(const PbdData& data, const GlobalStepCache& g, size_t r) {
  return data.cache.elastic_rows[g.row_colour[r]][g.row_index[r]];
}

// A row's stiffness K applied to corner displacements d (times 1 + beta / h), in the row's own frame
// (R = I): the Hessian of the enhanced element's energy at small strain, sum_g V_g (2 mu |sym D_g|^2 +
// lambda tr(D_g)^2) / 2 with D_g = sum_a d_a (x) G_g[a] plus the modes' db (add_modes), so a rotation
// costs nothing. out_b gets the modes' part. (The centre's volume term, lame_centre V c c^T with c_a =
// cof(F) G_c[a], is added where the rotation is known: factorise, apply_matrix.)
void apply_row(const ElasticRow& row, const ElasticConstants& k, const double (&d)[8][3],
               double (&out)[8][3], const double (&mean)[3], const double (&db)[3][3], double (&out_b)[3][3]) {
  const double scale = 1.0 + k.damping;
  for (int q = 0; q < 8; ++q) {
    if (!(row.octant[q] > 0.0)) continue;
    double Dg[9], E[9];
    gradient_at(d, k.grad[q], Dg);
    add_modes(q, mean, &db[0][0], Dg);
    const double w = scale * 2.0 * k.mu * row.octant[q];
    const double trace = k.volume_ratio * (Dg[0] + Dg[4] + Dg[8]);
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) E[3 * i + j] = w * (0.5 * (Dg[3 * i + j] + Dg[3 * j + i]) + (i == j ? trace : 0.0));
    }
    for (int a = 0; a < 8; ++a) {
      double f[3];
      mul3(E, k.grad[q][a], f);
      for (int e = 0; e < 3; ++e) out[a][e] += f[e];
    }
    add_modes_transposed(q, mean, E, out_b);
  }
}

// Each row's rotation R and centre volume gradient c_a at the substep's start (x_prev); R kept for
// the kernels' warm start too.
void row_frames(PbdData& data, GlobalStepCache& g, const ElasticConstants& k) {
  const size_t rows = g.row_colour.size();
  const double* prev = data.previous[0].data();
  g.rotation.resize(9 * rows);
  g.cof.assign(24 * rows, 0.0);
  for (size_t r = 0; r < rows; ++r) {
    const ElasticRow& row = row_of(data, g, r);
    double ps[8][3];
    for (int a = 0; a < 8; ++a) {
      for (int e = 0; e < 3; ++e) ps[a][e] = prev[3 * size_t(row.p[a]) + e];
    }
    double F[9], cof[9];
    gradient_at(ps, k.grad[8], F);
    const Eigen::Matrix3d R = centre_rotation(F, data.rotation[row.piece]);
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) g.rotation[9 * r + 3 * i + j] = R(i, j);
    }
    cofactor(F, cof);
    for (int a = 0; a < 8; ++a) mul3(cof, k.grad[8][a], &g.cof[24 * r + 3 * a]);
  }
}

// The unknowns and the preconditioner's factorisation: the step's matrix with the rows' current
// frames, assembled from apply_row on each corner axis (24 columns a row).
void build_structure(const PbdModel& s, PbdData& data, GlobalStepCache& g, const ElasticConstants& k) {
  const uint32_t particles = uint32_t(data.position.size());
  g.unknown.assign(particles, kNone);
  g.particle.clear();
  g.row_colour.clear();
  g.row_index.clear();
  for (uint32_t c = 0; c < kColourGroups; ++c) {
    const std::vector<ElasticRow>& rows = data.cache.elastic_rows[c];
    for (uint32_t i = 0; i < rows.size(); ++i) {
      if (!(rows[i].volume > 0.0)) continue;
      g.row_colour.push_back(c);
      g.row_index.push_back(i);
      for (int a = 0; a < 8; ++a) {
        const uint32_t p = rows[i].p[a];
        if (p < particles && s.inv_mass[p] > 0.0) g.unknown[p] = 0;
      }
    }
  }
  for (uint32_t p = 0; p < particles; ++p) {
    if (g.unknown[p] == kNone) continue;
    g.unknown[p] = uint32_t(g.particle.size());
    g.particle.push_back(p);
  }
  const size_t n = g.particle.size(), rows = g.row_colour.size();
  g.row_unknown.resize(8 * rows);
  for (size_t r = 0; r < rows; ++r) {
    const ElasticRow& row = row_of(data, g, r);
    for (int a = 0; a < 8; ++a) g.row_unknown[8 * r + a] = row.p[a] < particles ? g.unknown[row.p[a]] : kNone;
  }
  g.mass_h2.resize(Eigen::Index(n));
  for (size_t u = 0; u < n; ++u) g.mass_h2[Eigen::Index(u)] = 1.0 / (s.inv_mass[g.particle[u]] * k.h * k.h);
  // Each row's K0: apply_row with R = I and no volume term on each corner axis and mode amplitude,
  // the modes then condensed out (they are the row's own: no other row sees them).
  g.stiffness.assign(576 * rows, 0.0);
  g.mode_solve.assign(216 * rows, 0.0);
  g.mode_inverse.assign(81 * rows, 0.0);
  g.mode_mean.assign(3 * rows, 0.0);
  for (size_t r = 0; r < rows; ++r) {
    const ElasticRow& row = row_of(data, g, r);
    double mean[3];
    enhanced_mode_means(row.octant, mean);
    Eigen::Matrix<double, 33, 33> K;
    for (int col = 0; col < 33; ++col) {
      double d[8][3] = {}, out[8][3] = {}, db[3][3] = {}, out_b[3][3] = {};
      if (col < 24) {
        d[col / 3][col % 3] = 1.0;
      } else {
        db[(col - 24) / 3][(col - 24) % 3] = 1.0;
      }
      apply_row(row, k, d, out, mean, db, out_b);
      for (int i = 0; i < 24; ++i) K(i, col) = out[i / 3][i % 3];
      for (int i = 0; i < 9; ++i) K(24 + i, col) = out_b[i / 3][i % 3];
    }
    // K_bb is singular for a mode whose weights are all zero (one filled octant along its axis):
    // a small multiple of its scale keeps that mode still.
    Eigen::Matrix<double, 9, 9> Kbb = K.block<9, 9>(24, 24);
    const double scale = Kbb.trace() / 9.0;
    Kbb.diagonal().array() += scale > 0.0 ? 1e-9 * scale : 1.0;
    const Eigen::Matrix<double, 9, 9> inverse = Kbb.llt().solve(Eigen::Matrix<double, 9, 9>::Identity());
    const Eigen::Matrix<double, 9, 24> T = inverse * K.block<9, 24>(24, 0);
    Eigen::Map<Eigen::Matrix<double, 24, 24>>(&g.stiffness[576 * r]) = K.block<24, 24>(0, 0) - K.block<24, 9>(0, 24) * T;
    Eigen::Map<Eigen::Matrix<double, 9, 24>>(&g.mode_solve[216 * r]) = T;
    Eigen::Map<Eigen::Matrix<double, 9, 9>>(&g.mode_inverse[81 * r]) = inverse;
    for (int m = 0; m < 3; ++m) g.mode_mean[3 * r + size_t(m)] = mean[m];
  }
  g.stats.unknowns = uint32_t(n);
}

// The preconditioner's factorisation: the step's matrix with the rows' current frames (row_frames
// first), R K0_ab R^T + (1 + beta / h) lambda V c_a c_b^T per pair of unknown corners, plus M / h^2.
void factorise(GlobalStepCache& g, const ElasticConstants& k, const PbdData& data, bool analyse) {
  const size_t n = g.particle.size(), rows = g.row_colour.size();
  std::vector<Eigen::Triplet<double>> entries;
  entries.reserve(24 * 24 * rows + 3 * n);
  for (size_t r = 0; r < rows; ++r) {
    const uint32_t* u = &g.row_unknown[8 * r];
    const Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> R(&g.rotation[9 * r]);
    const Eigen::Map<const Eigen::Matrix<double, 24, 24>> K0(&g.stiffness[576 * r]);
    const double volume_k = (1.0 + k.damping) * k.lame_centre * row_of(data, g, r).volume;
    const double* c = &g.cof[24 * r];
    for (int a = 0; a < 8; ++a) {
      if (u[a] == kNone) continue;
      for (int b = 0; b < 8; ++b) {
        if (u[b] == kNone) continue;
        const Eigen::Matrix3d block = R * K0.block<3, 3>(3 * a, 3 * b) * R.transpose();
        for (int e = 0; e < 3; ++e) {
          for (int f = 0; f < 3; ++f) {
            entries.emplace_back(int(3 * u[a] + e), int(3 * u[b] + f), block(e, f) + volume_k * c[3 * a + e] * c[3 * b + f]);
          }
        }
      }
    }
  }
  for (size_t i = 0; i < n; ++i) {
    for (int e = 0; e < 3; ++e) entries.emplace_back(int(3 * i + e), int(3 * i + e), g.mass_h2[Eigen::Index(i)]);
  }
  Eigen::SparseMatrix<double> P(static_cast<Eigen::Index>(3 * n), static_cast<Eigen::Index>(3 * n));
  P.setFromTriplets(entries.begin(), entries.end());
  // The pattern (and its fill-reducing ordering) follows the structure only; a refactorisation after
  // the rotations moved is numeric.
  g.ok = n == 0;
  if (n > 0) {
    if (analyse) g.preconditioner.analyzePattern(P);
    g.preconditioner.factorize(P);
    g.ok = g.preconditioner.info() == Eigen::Success;
  }
  g.factorised_rotation = g.rotation;
  ++g.stats.factorisations;
  g.factorise_work = 0.0;
  double l_entries = 0.0;
  if (g.ok && n > 0) {
    const auto& L = g.preconditioner.matrixL().nestedExpression();
    for (Eigen::Index j = 0; j < L.outerSize(); ++j) {
      const double c = double(L.outerIndexPtr()[j + 1] - L.outerIndexPtr()[j]) + 1.0;
      g.factorise_work += c * c;
      l_entries += c;
    }
  }
  g.iteration_work = 1300.0 * double(rows) + 4.0 * l_entries;
  g.stale_work = 0.0;
}

// The warp: the preconditioner was factorised with the rows' rotations of that moment; since then each
// piece has turned by R R_f^T. Per unknown, the mean of its rows' turns (quaternions summed with one
// sign, in row order, normalised); the preconditioner is applied in the factorisation's frames, z = Q
// P^-1 Q^T r. A body that turns as a whole (a piece falling, tumbling) is then preconditioned as well
// as when it was factorised; without the warp its solves climbed past kRefactorIterations at every
// step and each step refactorised (the liver's lobe at 2 MPa in the window: 70-120 ms a step).
void update_warp(GlobalStepCache& g) {
  const size_t n = g.particle.size(), rows = g.row_colour.size();
  std::vector<Eigen::Vector4d> sum(n, Eigen::Vector4d::Zero());
  for (size_t r = 0; r < rows; ++r) {
    const Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> R(&g.rotation[9 * r]);
    const Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> F(&g.factorised_rotation[9 * r]);
    const Eigen::Quaterniond turn(Eigen::Matrix3d(R * F.transpose()));
    const Eigen::Vector4d q = turn.coeffs();
    for (int a = 0; a < 8; ++a) {
      const uint32_t u = g.row_unknown[8 * r + a];
      if (u == kNone) continue;
      sum[u] += sum[u].dot(q) < 0.0 ? Eigen::Vector4d(-q) : q;
    }
  }
  g.warp.resize(9 * n);
  for (size_t u = 0; u < n; ++u) {
    const double norm = sum[u].norm();
    const Eigen::Quaterniond q = norm > 0.0 ? Eigen::Quaterniond(sum[u] / norm) : Eigen::Quaterniond::Identity();
    Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(&g.warp[9 * u]) = q.toRotationMatrix();
  }
}

// z = Q P^-1 Q^T r (update_warp).
void precondition(GlobalStepCache& g) {
  const Eigen::Index n = Eigen::Index(g.particle.size());
  g.z.resize(3 * n);
  for (Eigen::Index u = 0; u < n; ++u) {
    const Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> Q(&g.warp[9 * size_t(u)]);
    g.z.segment<3>(3 * u) = Q.transpose() * g.r.segment<3>(3 * u);
  }
  g.z = g.preconditioner.solve(g.z);
  for (Eigen::Index u = 0; u < n; ++u) {
    const Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> Q(&g.warp[9 * size_t(u)]);
    const Eigen::Vector3d v = Q * g.z.segment<3>(3 * u);
    g.z.segment<3>(3 * u) = v;
  }
}

// Loads a row's corners (positions and substep-start positions): set_multipliers.
void load_corners(const PbdData& data, const ElasticRow& row, double (&xs)[8][3], double (&ps)[8][3]) {
  const double* x = data.position[0].data();
  const double* prev = data.previous[0].data();
  for (int a = 0; a < 8; ++a) {
    for (int e = 0; e < 3; ++e) {
      xs[a][e] = x[3 * size_t(row.p[a]) + e];
      ps[a][e] = prev[3 * size_t(row.p[a]) + e];
    }
  }
}

// The right-hand side, M (x~ - x_prev) / h^2 - grad Psi(x_prev), on the unknowns (row_frames first).
// The step is linearised at the substep's start, not at the prediction, so a body at rest (x~ -
// x_prev = h^2 g) is at its fixed point exactly when grad Psi = M g, whatever the linearisation
// leaves out.
void build_rhs(PbdData& data, GlobalStepCache& g, const ElasticConstants& k) {
  const size_t rows = g.row_colour.size();
  const Eigen::Index n = Eigen::Index(g.particle.size());
  const double* x = data.position[0].data();
  const double* prev = data.previous[0].data();
  g.b.resize(3 * n);
  for (Eigen::Index u = 0; u < n; ++u) {
    const size_t i = 3 * size_t(g.particle[size_t(u)]);
    for (int e = 0; e < 3; ++e) g.b[3 * u + e] = g.mass_h2[u] * (x[i + e] - prev[i + e]);
  }
  g.load = g.b.norm();
  g.mode_rhs.resize(9 * rows);
  for (size_t r = 0; r < rows; ++r) {
    const ElasticRow& row = row_of(data, g, r);
    const double* R = &g.rotation[9 * r];
    double ps[8][3], out[8][3] = {};
    for (int a = 0; a < 8; ++a) {
      for (int e = 0; e < 3; ++e) ps[a][e] = prev[3 * size_t(row.p[a]) + e];
    }
    // Shear: 2 mu V_g R S_g G_g[a] (symmetric_strain), F_g with the modes' amplitudes; their own
    // derivative in out_b.
    const double* beta = &data.enhancement[9 * size_t(row.piece)];
    const double* mean = &g.mode_mean[3 * r];
    double F[9], out_b[3][3] = {};
    for (int q = 0; q < 8; ++q) {
      if (!(row.octant[q] > 0.0)) continue;
      gradient_at(ps, k.grad[q], F);
      add_modes(q, mean, beta, F);
      double T[9];
      symmetric_strain(R, F, k.volume_ratio, T);
      for (int i = 0; i < 9; ++i) T[i] *= 2.0 * k.mu * row.octant[q];
      for (int a = 0; a < 8; ++a) {
        double f[3];
        mul3(T, k.grad[q][a], f);
        for (int e = 0; e < 3; ++e) out[a][e] += f[e];
      }
      add_modes_transposed(q, mean, T, out_b);
    }
    // The modes condensed out: b_x -= R T^T R^T b_b with b_b = -dPsi/dbeta (kept for the update).
    double* rhs_b = &g.mode_rhs[9 * r];
    Eigen::Matrix<double, 9, 1> local_b;
    for (int m = 0; m < 3; ++m) {
      for (int i = 0; i < 3; ++i) rhs_b[3 * m + i] = -out_b[m][i];
      for (int e = 0; e < 3; ++e) local_b[3 * m + e] = -(R[e] * out_b[m][0] + R[3 + e] * out_b[m][1] + R[6 + e] * out_b[m][2]);
    }
    const Eigen::Matrix<double, 24, 1> through = Eigen::Map<const Eigen::Matrix<double, 9, 24>>(&g.mode_solve[216 * r]).transpose() * local_b;
    for (int a = 0; a < 8; ++a) {
      double f[3];
      mul3(R, &through[3 * a], f);
      for (int e = 0; e < 3; ++e) out[a][e] += f[e];
    }
    // Volume at the centre: lame_centre V (det F - 1) c_a.
    if (k.lame_centre > 0.0) {
      gradient_at(ps, k.grad[8], F);
      double cof[9];
      const double s = k.lame_centre * row.volume * (cofactor(F, cof) - 1.0);
      const double* c = &g.cof[24 * r];
      for (int a = 0; a < 8; ++a) {
        for (int e = 0; e < 3; ++e) out[a][e] += s * c[3 * a + e];
      }
    }
    const uint32_t* u = &g.row_unknown[8 * r];
    for (int a = 0; a < 8; ++a) {
      if (u[a] == kNone) continue;
      for (int e = 0; e < 3; ++e) g.b[3 * Eigen::Index(u[a]) + e] -= out[a][e];
    }
  }
}

// q = A p: M / h^2 p + per row R K0 R^T p + (1 + beta / h) lame_centre V c (c . p).
void apply_matrix(const PbdData& data, GlobalStepCache& g, const ElasticConstants& k) {
  g.q.resize(g.p.size());
  for (Eigen::Index i = 0; i < g.p.size(); ++i) g.q[i] = g.mass_h2[i / 3] * g.p[i];
  const size_t rows = g.row_colour.size();
  for (size_t r = 0; r < rows; ++r) {
    const uint32_t* u = &g.row_unknown[8 * r];
    const Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> R(&g.rotation[9 * r]);
    const Eigen::Map<const Eigen::Matrix<double, 24, 24>> K0(&g.stiffness[576 * r]);
    Eigen::Matrix<double, 24, 1> d, local;
    for (int a = 0; a < 8; ++a) {
      if (u[a] == kNone) {
        d.segment<3>(3 * a).setZero();
      } else {
        d.segment<3>(3 * a) = g.p.segment<3>(3 * Eigen::Index(u[a]));
      }
      local.segment<3>(3 * a) = R.transpose() * d.segment<3>(3 * a);
    }
    const Eigen::Matrix<double, 24, 1> y = K0 * local;
    double t = 0.0;
    const double* c = &g.cof[24 * r];
    if (k.lame_centre > 0.0) {
      for (int i = 0; i < 24; ++i) t += c[i] * d[i];
      t *= (1.0 + k.damping) * k.lame_centre * row_of(data, g, r).volume;
    }
    for (int a = 0; a < 8; ++a) {
      if (u[a] == kNone) continue;
      const Eigen::Vector3d f = R * y.segment<3>(3 * a);
      for (int e = 0; e < 3; ++e) g.q[3 * Eigen::Index(u[a]) + e] += f[e] + t * c[3 * a + e];
    }
  }
}

double dot(const Eigen::VectorXd& a, const Eigen::VectorXd& b) { return a.dot(b); }

// Preconditioned conjugate gradients for A d = b from d = 0; false when it met a non-finite value.
bool solve(const PbdData& data, GlobalStepCache& g, const ElasticConstants& k) {
  const Eigen::Index n = Eigen::Index(g.particle.size());
  g.d.setZero(3 * n);
  g.stats.iterations = 0;
  g.stats.residual = 0.0;
  // Converged when the residual is below kGlobalTolerance of the right-hand side or of the load (a body
  // at rest has a right-hand side near zero: its noise needs no solving).
  const double b_norm = std::sqrt(dot(g.b, g.b));
  if (!std::isfinite(b_norm)) return false;
  const double goal = kGlobalTolerance * std::max(b_norm, g.load);
  if (!(b_norm > goal)) return true;
  g.r = g.b;
  precondition(g);
  g.p = g.z;
  double rz = dot(g.r, g.z);
  double r_norm = b_norm;
  for (uint32_t it = 0; it < kGlobalMaxIterations; ++it) {
    apply_matrix(data, g, k);
    const double pq = dot(g.p, g.q);
    if (!(pq > 0.0) || !std::isfinite(pq)) break;
    const double alpha = rz / pq;
    g.d += alpha * g.p;
    g.r -= alpha * g.q;
    g.stats.iterations = it + 1;
    r_norm = std::sqrt(dot(g.r, g.r));
    if (!(r_norm > goal)) break;
    precondition(g);
    const double rz_next = dot(g.r, g.z);
    g.p = g.z + (rz_next / rz) * g.p;
    rz = rz_next;
  }
  g.stats.residual = r_norm / std::max(b_norm, g.load);
  return std::isfinite(g.stats.residual) && g.d.allFinite();
}

// The XPBD multipliers the new state implies: lambda = -(C + gamma grad C . (x - x_prev)) / alpha~
// per constraint, as the kernels compute C and its gradient (pbd_kernels_lanes.inc).
void set_multipliers(PbdData& data, GlobalStepCache& g, const ElasticConstants& k) {
  const size_t rows = g.row_colour.size();
  for (size_t r = 0; r < rows; ++r) {
    const ElasticRow& row = row_of(data, g, r);
    double* lambda = &data.cache.elastic_lambda[g.row_colour[r]][size_t(kElasticConstraints) * g.row_index[r]];
    double xs[8][3], ps[8][3];
    load_corners(data, row, xs, ps);
    double F[9];
    gradient_at(xs, k.grad[8], F);
    const Eigen::Matrix3d Rm = centre_rotation(F, data.rotation[row.piece]);
    double R[9];
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) R[3 * i + j] = Rm(i, j);
    }
    const double* beta = &data.enhancement[9 * size_t(row.piece)];
    for (int q = 0; q < 8; ++q) {
      lambda[q] = 0.0;
      if (!(row.octant[q] > 0.0)) continue;
      gradient_at(xs, k.grad[q], F);
      add_modes(q, &g.mode_mean[3 * r], beta, F);
      double P[9];
      const double c = std::sqrt(symmetric_strain(R, F, k.volume_ratio, P));
      for (int i = 0; i < 9; ++i) F[i] = P[i];
      if (!(c > 1e-12)) continue;
      double rate = 0.0;
      for (int a = 0; a < 8; ++a) {
        double grad[3];
        mul3(F, k.grad[q][a], grad);
        for (int e = 0; e < 3; ++e) rate += grad[e] / c * (xs[a][e] - ps[a][e]);
      }
      lambda[q] = -(c + k.damping * rate) * row.octant[q] / k.alpha_dev;
    }
    lambda[8] = 0.0;
    if (k.lame_centre > 0.0) {
      gradient_at(xs, k.grad[8], F);
      double cof[9];
      const double det = cofactor(F, cof);
      double rate = 0.0;
      for (int a = 0; a < 8; ++a) {
        double grad[3];
        mul3(cof, k.grad[8][a], grad);
        for (int e = 0; e < 3; ++e) rate += grad[e] * (xs[a][e] - ps[a][e]);
      }
      lambda[8] = -((det - 1.0) + k.damping * rate) * row.volume / k.alpha_vol_centre;
    }
  }
}

// The modes' amplitudes after the solve: db = K_bb^-1 R^T b_b - T R^T d per row (its own frame), back
// to the world with R.
void update_modes(PbdData& data, const GlobalStepCache& g) {
  const size_t rows = g.row_colour.size();
  for (size_t r = 0; r < rows; ++r) {
    const ElasticRow& row = row_of(data, g, r);
    const Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> R(&g.rotation[9 * r]);
    const uint32_t* u = &g.row_unknown[8 * r];
    Eigen::Matrix<double, 24, 1> local_d;
    for (int a = 0; a < 8; ++a) {
      local_d.segment<3>(3 * a) =
          u[a] == kNone ? Eigen::Vector3d::Zero() : Eigen::Vector3d(R.transpose() * g.d.segment<3>(3 * Eigen::Index(u[a])));
    }
    Eigen::Matrix<double, 9, 1> local_b;
    for (int m = 0; m < 3; ++m) local_b.segment<3>(3 * m) = R.transpose() * Eigen::Map<const Eigen::Vector3d>(&g.mode_rhs[9 * r + 3 * size_t(m)]);
    const Eigen::Matrix<double, 9, 1> db = Eigen::Map<const Eigen::Matrix<double, 9, 9>>(&g.mode_inverse[81 * r]) * local_b -
                                           Eigen::Map<const Eigen::Matrix<double, 9, 24>>(&g.mode_solve[216 * r]) * local_d;
    double* beta = &data.enhancement[9 * size_t(row.piece)];
    for (int m = 0; m < 3; ++m) {
      const Eigen::Vector3d world = R * db.segment<3>(3 * m);
      for (int i = 0; i < 3; ++i) beta[3 * m + i] += world[i];
    }
  }
}

}  // namespace

void global_elastic_step(const PbdModel& s, PbdData& data, const ElasticConstants& k) {
  if (!data.cache.global) data.cache.global = std::make_shared<GlobalStepCache>();
  GlobalStepCache& g = *data.cache.global;
  // The structure follows the model and the constants; the factorisation too, and the rows'
  // rotations when they have moved so far from the factorisation's that the last solve needed more
  // than kRefactorIterations.
  const bool structure = g.revision != s.revision || g.h != k.h || g.mu != k.mu || g.lame != k.lame ||
                         g.damping != k.damping || g.unknown.size() != data.position.size();
  if (structure) {
    build_structure(s, data, g, k);
    g.revision = s.revision;
    g.h = k.h;
    g.mu = k.mu;
    g.lame = k.lame;
    g.damping = k.damping;
  }
  if (!(k.h > 0.0) || g.particle.empty()) return;
  row_frames(data, g, k);
  // Refactorised when the stale factorisation's extra iterations have cost as much as a new one.
  if (g.stats.iterations > kFreshIterations) g.stale_work += double(g.stats.iterations - kFreshIterations) * g.iteration_work;
  if (structure || g.stale_work >= g.factorise_work) factorise(g, k, data, structure);
  update_warp(g);
  if (!g.ok) return;
  build_rhs(data, g, k);
  // A step that meets a non-finite value leaves the prediction to the iterations.
  const bool solved = solve(data, g, k);
  if (!solved) return;
  double* x = data.position[0].data();
  const double* prev = data.previous[0].data();
  for (size_t u = 0; u < g.particle.size(); ++u) {
    const size_t i = 3 * size_t(g.particle[u]);
    for (int e = 0; e < 3; ++e) x[i + e] = prev[i + e] + g.d[3 * Eigen::Index(u) + e];
  }
  update_modes(data, g);
  set_multipliers(data, g, k);
}

GlobalStepStats global_step_stats(const PbdData& data) {
  return data.cache.global ? data.cache.global->stats : GlobalStepStats{};
}

}  // namespace dvx
