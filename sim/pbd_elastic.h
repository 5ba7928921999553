// Elasticity of a material (issue 30, DESIGN §3 "A material, not solver knobs"): each simulation piece
// is a trilinear hexahedron on its 8 corner particles with XPBD constraints whose energy is the
// corotated elastic one, Psi = mu |F - R|^2 + lambda / 2 (J - 1)^2:
//
//   shear       C_g = |F_g - R|_F   at each of the 2x2x2 Gauss points g, compliance 1 / (2 mu V_g)
//   volume      C_H = det F - 1     at the centre,                       compliance 1 / (lambda V)
//
// F = sum_a x_a (x) grad N_a: the rest hexahedron is the piece's simulation voxel, an axis-aligned cube
// of edge sim_size, so the shape-function gradients are one table for every piece. R is the rotation
// of F at the centre (extract_rotation_step, warm-started from the piece's previous rotation, so
// flattened and inverted pieces come back). mu and lambda are Lamé's (E, nu): the energy linearises
// to mu |eps|^2 + lambda / 2 tr(eps)^2, small-strain elasticity exactly. The volume term at one point
// does not lock as nu -> 0.5; the shear terms at 8 points leave no hourglass modes. V is the piece's
// material volume (its exact eighths); V_g is half V / 8 and half the material in Gauss point g's
// octant of the block: a partly filled or cut piece is as stiff as the material it holds, more so where
// it holds it (octant weights alone leave an empty octant's corners with no stiffness: the liver's
// surface wrinkled).
//
// Why not Stable Neo-Hookean's constraints (Macklin & Müller 2021: sqrt(tr(F^T F)) and det F - gamma)?
// Measured: their rest state balances two large opposite multipliers (sqrt(3) / alpha each), which an
// XPBD solve rebuilds from zero every substep; in the stiff regime (a 1 m beam at E 100 MPa) a
// cantilever's sag fell as 1 / (substeps x iterations), to 1 % of the true sag: stiffening with the
// budget. Every constraint here is zero at rest.
//
// With the global step (pbd_global.h) the element is another one, with incompatible modes (Wilson &
// Taylor; CalculiX's C3D8I), because trilinear hexahedra lock in bending: a beam one piece thick sags
// 0.64 of Timoshenko, 0.85 at two (the shear strain at the Gauss points of a bent element). Its
// displacement gets three bubble modes a_m (1 - xi_m^2), whose gradient at Gauss point g adds
// (s_m(g) - mean_m) beta_m to column m of F_g: s_m(g) = +-1 the sign of xi_m there, beta_m the
// amplitude in units of F (a world vector per mode, 9 per piece, PbdData::enhancement), mean_m the
// mode's octant-weighted mean (enhanced_mode_means), so the modes add nothing to a uniform strain (the
// patch test) in a partly filled piece too. A mode relieves the bending's shear only in a symmetric
// strain, so the Gauss points measure S = sym(R^T F_g) - I (|F_g - R| also charges the rotation's
// change across the piece, which the modes cannot undo), and the volume sits there too, up to
// kPointLameRatio mu of lambda, the rest at the centre:
//
//   Gauss point  C_g = sqrt(|S_g|^2 + lambda_g / (2 mu) tr(S_g)^2),   compliance 1 / (2 mu V_g)
//   volume       C_H = det F - 1 at the centre,                      compliance 1 / ((lambda - lambda_g) V)
//
// which linearises to small-strain elasticity at each point. The amplitudes are the piece's own: the
// global step solves them with the corners (condensed out of its matrix), the iterations hold them.
// Without the global step they stay zero and the element is the trilinear one above.
//
// XPBD (Macklin et al. 2016): multipliers per constraint, reset at each substep, compliance
// alpha / h^2, so the stiffness is the material's whatever the iterations or substeps (fewer of them
// are softer, never stiffer). Damping is stiffness-proportional (Rayleigh beta, seconds) through the
// constraints (XPBD eq. 26): it acts on the rate of the strains only, so a rigid motion is not slowed.
#pragma once

#include <Eigen/Geometry>

#include <cstdint>

namespace dvx {

// The material's constants as the constraint kernel reads them (per substep of length h).
struct ElasticConstants {
  double inv_edge = 1.0;     // 1 / sim_size (the rest hexahedron's edge)
  double alpha_dev = 0.0;    // 1 / (2 mu h^2): shear compliance per unit volume
  double alpha_vol = 0.0;    // 1 / (lambda h^2): volume compliance per unit volume (lambda > 0)
  bool volume = true;        // lambda > 0 (nu > 0): the volume constraint acts
  double damping = 0.0;      // beta / h (XPBD constraint damping; beta: Rayleigh stiffness damping in s)
  double mu = 0.0, lame = 0.0;  // Lame's mu and lambda (Pa), for the global step (sim/pbd_global.h)
  double h = 0.0;               // the substep
  // The enhanced element's volume (pbd_elastic.h, incompatible modes): lambda_g = min(lambda,
  // kPointLameRatio mu) at the Gauss points, in C_g with weight volume_ratio = lambda_g / (2 mu); the
  // rest, lame_centre = lambda - lambda_g, at the centre (compliance alpha_vol_centre per unit volume).
  double volume_ratio = 0.0, lame_centre = 0.0, alpha_vol_centre = 0.0;
  // The shape-function gradients at the 8 Gauss points and the centre times inv_edge, per corner:
  // scaled once here, not in each of the kernel's 9 deformation gradients a piece per iteration.
  double grad[9][8][3] = {};
};

// The enhanced element's largest lambda / mu at the Gauss points (the rest of lambda at the centre).
// All of lambda at the Gauss points is C3D8I's element, but it locks as nu -> 0.5: a column hanging
// at nu 0.49 changed volume 40 % less than uniaxial stress says, and the hanging liver (nu 0.47) at sim
// 16 sagged 5.0 mm at its lobe tip against CalculiX's 12.0 (with 4 mu there: 5.0; 1 mu: 7.4; none:
// 9.1). All of it at the centre loses the volume's resistance to a strain that varies inside a piece:
// a beam one piece thick (nu 0.3) bent 1.27x Timoshenko (with mu: 1.007; 4 mu: 0.964). bench
// elastic (RMS against CalculiX, cantilever nu 0.45 / liver at sim 8 and 16): 0 -> 11 / 10 / 37 /
// 9.9 %, 1 -> 21 / 12 / 31 / 11 %, 4 -> 28 / 13 / 24 / 14 %; sim 32's cantilever 1.9-2.1 % with each.
constexpr double kPointLameRatio = 1.0;

// Lamé constants of (E, nu) and the kernel's constants for a substep h.
ElasticConstants elastic_constants(double youngs_modulus, double poisson_ratio, double beta, double sim_size, double h);

// One piece as the solver reads it: its corner particles (corner c = dx | dy<<1 | dz<<2), their inverse
// masses (copied once per model revision), and its material volume.
struct ElasticRow {
  uint32_t p[8];
  uint32_t piece;  // slot of the piece (its rotation's warm start)
  double w[8];
  double volume;     // material volume of the piece (m^3)
  double octant[8];  // its share at each Gauss point (V_g, sim/pbd.cpp refresh_blocks; point c lies in octant c)
};

// Shape-function gradients of the unit-edge hexahedron at its 8 Gauss points (point g at xi =
// +-1/sqrt(3), signs from g's bits like the corners) and at its centre (the 9th), per corner and axis.
extern const double (&kHexGradients)[9][8][3];

// s_m(g): the sign of xi_m at Gauss point g (its bit m, like the corners').
inline double mode_sign(int g, int m) { return ((g >> m) & 1) ? 1.0 : -1.0; }

// The incompatible modes' octant-weighted means over a row's Gauss points (see above): mean_m =
// sum_g V_g s_m(g) / sum_g V_g, zero in a full piece.
inline void enhanced_mode_means(const double (&octant)[8], double (&mean)[3]) {
  double total = 0.0;
  for (int m = 0; m < 3; ++m) mean[m] = 0.0;
  for (int g = 0; g < 8; ++g) {
    total += octant[g];
    for (int m = 0; m < 3; ++m) mean[m] += mode_sign(g, m) * octant[g];
  }
  for (int m = 0; m < 3; ++m) mean[m] = total > 0.0 ? mean[m] / total : 0.0;
}

// Number of constraints (multipliers) of a row: 8 shear, 1 volume.
constexpr int kElasticConstraints = 9;

// Solves rows [begin, end) in order, each one's 9 constraints in turn (Gauss-Seidel), with their
// multipliers (kElasticConstraints per row). x: positions (3 per particle); previous: positions at
// the substep's start (for the damping); rotation: per piece slot, warm start updated in place;
// enhancement: per piece slot the incompatible modes' amplitudes (9 each), null for none.
// The scalar path, defined in pbd_kernels.cpp as the lane code on one lane: solve_elastic_blocks
// (pbd_kernels.h) solves a colour's rows four or eight at once with the same bits.
void solve_elastic_rows(double* x, const double* previous, const ElasticRow* rows, double* lambda, uint32_t begin,
                        uint32_t end, const ElasticConstants& k, Eigen::Quaterniond* rotation,
                        const double* enhancement = nullptr);

// The deformation gradient of a hexahedron at local point xi in [-1,1]^3 (F row-major), from its 8
// corners (3 doubles each) and inv_edge: for tests and diagnostics.
void hex_deformation_gradient(const double* corners, const double xi[3], double inv_edge, double F[9]);

}  // namespace dvx
