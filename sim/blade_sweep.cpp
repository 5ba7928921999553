#include "sim/blade_sweep.h"

#include <algorithm>
#include <cmath>

// Exact scanline search of the lattice lines crossed by a triangle.
//
// Units: vertices are snapped to fixed point, F = 2^16 units per voxel, in lattice coordinates
// (node (i,j,k) is at (i,j,k) * F). Clamping to |coordinate| <= 2^23 voxels gives |V| <= 2^39, so
//   edge vectors             e  <= 2^40
//   normal  n = e1 x e2      n  <= 2^81
//   plane numerator X        X  <  2^123   (see below)
// and everything fits in __int128.
//
// For axis a with (b, c) = the other two axes (columns along b, rows along c, whichever order has
// fewer rows), +-n_a is the doubled signed area of the triangle's projection onto (b, c), and
// n_a = 0 means the triangle crosses no line along a. The line of lattice points (J, K) = (j, k) F
// along a meets the plane n . (P - V0) = 0 at
//   x* = X / (n_a F)  voxels,   X = V0_a n_a - n_b (J - V0_b) - n_c (K - V0_c),
// which is linear in j along a scanline (row k), so the quotient and remainder of X / (n_a F) are
// advanced by additions only. The j-range of a row is computed exactly from the three edge
// half-planes (inclusive) and from 0 <= x* <= lattice size, so the work per row is O(1) plus
// O(1) per line inside the triangle: the cost is O(rows + lines crossed), never the bounding box.

namespace dvx {
namespace {

using i128 = __int128;

constexpr int kFracBits = 16;
constexpr int64_t kOne = int64_t(1) << kFracBits;    // fixed-point units per voxel
constexpr double kCoordLimit = double(1 << 23);      // clamp window, lattice units
constexpr int64_t kAxisLimit = int64_t(1) << 24;     // bound on lattice size used in products

i128 floor_div(i128 a, i128 b) {  // b > 0
  i128 q = a / b;
  if (a % b != 0 && a < 0) --q;
  return q;
}
i128 ceil_div(i128 a, i128 b) {  // b > 0
  i128 q = a / b;
  if (a % b != 0 && a > 0) ++q;
  return q;
}

// Lattice coordinates of p, clamped and snapped; false for NaN.
bool snap(const Lattice& lattice, const Vec3d& p, int64_t out[3]) {
  for (int a = 0; a < 3; ++a) {
    double q = (p[a] - lattice.origin[a]) / lattice.voxel_size;
    if (std::isnan(q)) return false;
    q = std::clamp(q, -kCoordLimit, kCoordLimit);
    out[a] = std::llround(q * double(kOne));  // exact scaling (power of two), ties away from zero
  }
  return true;
}

// The lattice edges along axis a that the snapped triangle v crosses (n: its exact normal, n[a] != 0),
// found by scanlines over the triangle's projection across a: one exact crossing per lattice line.
void axis_hits(const Lattice& lattice, const int64_t v[3][3], const i128 n[3], int a, int on_plane_side,
               const Vec3f& normal, std::vector<EdgeHit>& out, SweepStats* stats) {
  const int64_t count[3] = {lattice.nx, lattice.ny, lattice.nz};
  const uint64_t stride[3] = {1, uint64_t(lattice.nx) + 1, (uint64_t(lattice.nx) + 1) * (uint64_t(lattice.ny) + 1)};
  // Orient the normal so that m_a > 0: nodes with larger a-coordinate are on the + side.
  const int s = n[a] > 0 ? 1 : -1;
  // An on-plane node joins the upper nodes of its line iff its perturbed side is sign(n_a).
  const bool on_plane_upper = on_plane_side == s;

  // Scanlines run along b (columns j) and step along c (rows k). Rows go along the axis with
  // fewer lattice lines in the projection's range, so a thin sliver lying along b or c (a blade
  // aligned with an axis) costs one row per crossed line and not one row per voxel of its length.
  int b = (a + 1) % 3, c = (a + 2) % 3;
  int s2 = s;  // sign of the projected triangle's area in (b, c) coordinates
  {
    auto span = [&](int axis) {
      const int64_t lo = std::min({v[0][axis], v[1][axis], v[2][axis]});
      const int64_t hi = std::max({v[0][axis], v[1][axis], v[2][axis]});
      return std::min<int64_t>(count[axis], int64_t(floor_div(hi, kOne))) -
             std::max<int64_t>(0, int64_t(ceil_div(lo, kOne)));
    };
    if (span(c) > span(b)) {
      std::swap(b, c);
      s2 = -s;
    }
  }
  const i128 ma = s * n[a], mb = s * n[b], mc = s * n[c];

  // Projected triangle and its edges in (b, c), the inside on the left when s2 > 0.
  int64_t pb[3], pc[3];
  for (int i = 0; i < 3; ++i) {
    pb[i] = v[i][b];
    pc[i] = v[i][c];
  }
  i128 alpha[3], eb[3], ec[3];
  for (int i = 0; i < 3; ++i) {
    const int i1 = (i + 1) % 3;
    eb[i] = i128(pb[i1]) - pb[i];
    ec[i] = i128(pc[i1]) - pc[i];
    // s2 * orient(P_i, P_i1, (J, K)) = alpha J + beta(K) >= 0 inside (inclusive).
    alpha[i] = -s2 * ec[i];
  }
  const int64_t min_b = std::min({pb[0], pb[1], pb[2]}), max_b = std::max({pb[0], pb[1], pb[2]});
  const int64_t min_c = std::min({pc[0], pc[1], pc[2]}), max_c = std::max({pc[0], pc[1], pc[2]});
  const int64_t row_lo = std::max<int64_t>(0, int64_t(ceil_div(min_c, kOne)));
  const int64_t row_hi = std::min<int64_t>(count[c], int64_t(floor_div(max_c, kOne)));
  const int64_t col_lo = std::max<int64_t>(0, int64_t(ceil_div(min_b, kOne)));
  const int64_t col_hi = std::min<int64_t>(count[b], int64_t(floor_div(max_b, kOne)));
  if (row_lo > row_hi || col_lo > col_hi) return;

  const i128 den = ma * kOne;                                   // x* = X / den voxels
  const i128 top = i128(std::min<int64_t>(count[a], kAxisLimit)) * den;  // X of the last node
  const i128 step = -mb * kOne;                                 // X(j + 1) - X(j)
  const i128 step_q = floor_div(step, den);
  const i128 step_r = step - step_q * den;                      // in [0, den)
  const double den_d = double(den);

  for (int64_t k = row_lo; k <= row_hi; ++k) {
    if (stats) ++stats->rows_scanned;
    const i128 kk = i128(k) * kOne;
    // Columns inside the projected triangle.
    i128 lo = col_lo, hi = col_hi;
    bool empty = false;
    for (int i = 0; i < 3; ++i) {
      const i128 beta = s2 * (eb[i] * (kk - pc[i]) + ec[i] * pb[i]);
      if (alpha[i] > 0) {
        lo = std::max(lo, ceil_div(-beta, alpha[i] * kOne));
      } else if (alpha[i] < 0) {
        hi = std::min(hi, floor_div(beta, -alpha[i] * kOne));
      } else if (beta < 0) {  // an edge along b: already implied by the row range, kept for clarity
        empty = true;
      }
    }
    if (empty || lo > hi) continue;
    // Columns whose crossing lies on the lattice: 0 <= X(j) <= top.
    const i128 x_lo = ma * v[0][a] - mb * (lo * kOne - pb[0]) - mc * (kk - pc[0]);
    i128 first = lo, last = hi;
    if (step == 0) {
      if (x_lo < 0 || x_lo > top) continue;
    } else if (step < 0) {
      last = std::min(last, lo + floor_div(x_lo, -step));
      first = std::max(first, lo + ceil_div(x_lo - top, -step));
    } else {
      first = std::max(first, lo + ceil_div(-x_lo, step));
      last = std::min(last, lo + floor_div(top - x_lo, step));
    }
    if (first > last) continue;

    const i128 x_first = x_lo + step * (first - lo);
    i128 q = floor_div(x_first, den);
    i128 r = x_first - q * den;
    const uint64_t row_base = uint64_t(k) * stride[c];
    for (int64_t j = int64_t(first); j <= int64_t(last); ++j) {
      if (stats) ++stats->lines_tested;
      int64_t i0;
      float t;
      if (r != 0) {
        i0 = int64_t(q);
        t = float(double(r) / den_d);
      } else if (on_plane_upper) {
        i0 = int64_t(q) - 1;
        t = 1.0f;
      } else {
        i0 = int64_t(q);
        t = 0.0f;
      }
      if (i0 >= 0 && i0 < count[a]) {
        const uint64_t node = uint64_t(i0) * stride[a] + uint64_t(j) * stride[b] + row_base;
        out.push_back(EdgeHit{Lattice::edge(uint32_t(node), a), t, normal});
      }
      q += step_q;
      r += step_r;
      if (r >= den) {
        r -= den;
        ++q;
      }
    }
  }
}

void snapped_triangle_hits(const Lattice& lattice, const int64_t v[3][3], std::vector<EdgeHit>& out,
                           SweepStats* stats) {
  i128 e1[3], e2[3];
  for (int a = 0; a < 3; ++a) {
    e1[a] = i128(v[1][a]) - v[0][a];
    e2[a] = i128(v[2][a]) - v[0][a];
  }
  const i128 n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                     e1[0] * e2[1] - e1[1] * e2[0]};
  if (n[0] == 0 && n[1] == 0 && n[2] == 0) return;  // degenerate after snapping

  const Vec3d nd{double(n[0]), double(n[1]), double(n[2])};
  const Vec3f normal = (nd / nd.norm()).cast<float>();

  // Side of a node exactly on the plane under the perturbation eps * (1, eps, eps^2).
  const int on_plane_side = n[0] != 0 ? (n[0] > 0 ? 1 : -1) : n[1] != 0 ? (n[1] > 0 ? 1 : -1) : (n[2] > 0 ? 1 : -1);

  for (int a = 0; a < 3; ++a) {
    // A projection onto the plane perpendicular to a with no area crosses no edge along a.
    if (n[a] != 0) axis_hits(lattice, v, n, a, on_plane_side, normal, out, stats);
  }
}

bool usable(const Lattice& lattice) {
  return lattice.nx >= 0 && lattice.ny >= 0 && lattice.nz >= 0 && lattice.node_count() <= kMaxLatticeNodes &&
         lattice.voxel_size > 0.0 && std::isfinite(lattice.voxel_size);
}

}  // namespace

void triangle_edge_hits(const Lattice& lattice, const Vec3d& p0, const Vec3d& p1, const Vec3d& p2,
                        std::vector<EdgeHit>& out, SweepStats* stats) {
  if (!usable(lattice)) return;
  int64_t v[3][3];
  if (!snap(lattice, p0, v[0]) || !snap(lattice, p1, v[1]) || !snap(lattice, p2, v[2])) return;
  snapped_triangle_hits(lattice, v, out, stats);
}

void sweep_edge_hits(const Lattice& lattice, const BladePose& from, const BladePose& to, std::vector<EdgeHit>& out,
                     SweepStats* stats) {
  triangle_edge_hits(lattice, from.a, from.b, to.b, out, stats);
  triangle_edge_hits(lattice, from.a, to.b, to.a, out, stats);
}

}  // namespace dvx
