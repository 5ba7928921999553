// World space -> rest space (sim/world_to_rest.h): the pieces' trilinear maps and their inversion,
// the grid over the deformed pieces, and the rest positions of a world point (world_to_rest).
#include "sim/world_to_rest.h"
#include "sim/world_to_rest_internal.h"

#include <Eigen/LU>

#include <algorithm>
#include <cmath>
#include <limits>

namespace dvx {

using namespace world_to_rest_internal;

// ---- Trilinear map -------------------------------------------------------------------------

Vec3d trilinear(const Vec3d corners[8], const Vec3d& u) {
  Vec3d x = Vec3d::Zero();
  for (int c = 0; c < 8; ++c) {
    const double w = ((c & 1) ? u.x() : 1.0 - u.x()) * (((c >> 1) & 1) ? u.y() : 1.0 - u.y()) *
                     (((c >> 2) & 1) ? u.z() : 1.0 - u.z());
    x += w * corners[c];
  }
  return x;
}

TrilinearMap trilinear_map(const Vec3d x[8]) {
  TrilinearMap m;
  m.c[0] = x[0];
  m.c[1] = x[1] - x[0];
  m.c[2] = x[2] - x[0];
  m.c[3] = x[4] - x[0];
  m.c[4] = (x[3] - x[2]) - m.c[1];
  m.c[5] = (x[5] - x[4]) - m.c[1];
  m.c[6] = (x[6] - x[4]) - m.c[2];
  m.c[7] = ((x[7] - x[6]) - (x[5] - x[4])) - m.c[4];
  return m;
}

namespace {

Vec3d map_point(const TrilinearMap& m, const Vec3d& u) {
  return m.c[0] + u.x() * m.c[1] + u.y() * (m.c[2] + u.x() * m.c[4]) + u.z() * (m.c[3] + u.x() * m.c[5] + u.y() * (m.c[6] + u.x() * m.c[7]));
}

Eigen::Matrix3d map_jacobian(const TrilinearMap& m, const Vec3d& u) {
  Eigen::Matrix3d j;
  j.col(0) = m.c[1] + u.y() * m.c[4] + u.z() * (m.c[5] + u.y() * m.c[7]);
  j.col(1) = m.c[2] + u.x() * m.c[4] + u.z() * (m.c[6] + u.x() * m.c[7]);
  j.col(2) = m.c[3] + u.x() * m.c[5] + u.y() * (m.c[6] + u.x() * m.c[7]);
  return j;
}

// Whether Newton's step may be taken with Jacobian j (not flat or inverted), and its inverse then.
bool invertible(const Eigen::Matrix3d& j, Eigen::Matrix3d& inverse) {
  const double scale = j.cwiseAbs().maxCoeff();
  const double det = j.determinant();
  if (!(scale > 0.0) || !(std::abs(det) > 1e-9 * scale * scale * scale)) return false;
  inverse = j.inverse();
  return true;
}

// u += step, at most one cell per axis; false when u leaves the search range (|u - 0.5| > 2).
bool take_step(Vec3d step, Vec3d& u) {
  const double longest = step.cwiseAbs().maxCoeff();
  if (!(longest < std::numeric_limits<double>::infinity())) return false;
  if (longest > 1.0) step /= longest;
  u += step;
  return (u.array() - 0.5).abs().maxCoeff() <= 2.0;
}

}  // namespace

bool invert_trilinear_warm(const TrilinearMap& map, const Vec3d& target, Vec3d& u, double tolerance,
                           Eigen::Matrix3d& jinv, bool& have_jinv, int max_iterations) {
  // Chord steps while they contract (each at least halves the residual); the best point is kept.
  Vec3d best = u;
  double best_norm = std::numeric_limits<double>::infinity();
  if (have_jinv) {
    for (int it = 0; it < 6; ++it) {
      const Vec3d residual = target - map_point(map, u);
      if (!residual.allFinite()) return false;
      const double norm = residual.norm();
      if (norm <= tolerance) return true;
      if (!(norm < 0.5 * best_norm)) break;
      best = u;
      best_norm = norm;
      if (!take_step(jinv * residual, u)) break;
    }
    u = best;
  }
  // Newton's method (as invert_trilinear), keeping its last Jacobian's inverse.
  for (int it = 0; it <= max_iterations; ++it) {
    const Vec3d residual = target - map_point(map, u);
    if (!residual.allFinite()) return false;
    if (residual.norm() <= tolerance) return true;
    if (it == max_iterations) break;
    Eigen::Matrix3d inverse;
    if (!invertible(map_jacobian(map, u), inverse)) return false;
    jinv = inverse;
    have_jinv = true;
    if (!take_step(inverse * residual, u)) return false;
  }
  return false;
}

bool invert_trilinear(const Vec3d corners[8], const Vec3d& target, Vec3d& u, double tolerance, int max_iterations) {
  Eigen::Matrix3d jinv;
  bool have_jinv = false;
  return invert_trilinear_warm(trilinear_map(corners), target, u, tolerance, jinv, have_jinv, max_iterations);
}

// ---- Grid over deformed pieces ---------------------------------------------------------------

void build_piece_grid(const PbdModel& pbd, const PbdData& data, const Aabb& region, double cell, double margin,
                      PieceGrid& grid) {
  grid.candidates.clear();
  grid.ranges.clear();
  grid.everywhere.clear();
  grid.items.clear();
  grid.cell_begin.clear();
  if (region.empty()) return;
  // Pieces whose grown bounds overlap the region (one pass over the pieces).
  const Vec3d lo_region = region.min, hi_region = region.max;
  Vec3d lo_all = Vec3d::Constant(std::numeric_limits<double>::infinity()), hi_all = -lo_all;
  grid.box_lo.clear();
  grid.box_hi.clear();
  grid.piece_lo.resize(pbd.pieces.size());
  grid.piece_hi.resize(pbd.pieces.size());
  grid.piece_map.resize(pbd.pieces.size());
  grid.piece_origin.resize(pbd.pieces.size());
  grid.piece_jinv.resize(pbd.pieces.size());
  grid.jinv_valid.resize(pbd.pieces.size());
  for (uint32_t slot = 0; slot < pbd.pieces.size(); ++slot) {
    if (pbd.pieces[slot].sim_voxel == kDeadIndex) continue;
    Vec3d lo = data.position[pbd.pieces[slot].particles[0]], hi = lo;
    for (int c = 1; c < 8; ++c) {
      lo = lo.cwiseMin(data.position[pbd.pieces[slot].particles[c]]);
      hi = hi.cwiseMax(data.position[pbd.pieces[slot].particles[c]]);
    }
    grid.piece_lo[slot] = lo;
    grid.piece_hi[slot] = hi;
    lo.array() -= margin;
    hi.array() += margin;
    if ((hi.array() < lo_region.array()).any() || (lo.array() > hi_region.array()).any() || !lo.allFinite() ||
        !hi.allFinite()) {
      continue;
    }
    grid.candidates.push_back(slot);
    Vec3d corners[8];
    piece_corners(pbd, data, slot, corners);
    grid.piece_map[slot] = trilinear_map(corners);
    grid.piece_origin[slot] = piece_rest_origin(pbd, slot);
    grid.jinv_valid[slot] = 0;
    grid.box_lo.push_back(lo.cwiseMax(lo_region));
    grid.box_hi.push_back(hi.cwiseMin(hi_region));
    lo_all = lo_all.cwiseMin(grid.box_lo.back());
    hi_all = hi_all.cwiseMax(grid.box_hi.back());
  }
  if (grid.candidates.empty()) return;
  // Cells: about `cell` wide, at most 64 per axis and about two per candidate.
  const Vec3d extent = (hi_all - lo_all).cwiseMax(Vec3d::Constant(1e-12));
  double size = std::max(cell, extent.maxCoeff() / 64.0);
  const double limit = std::max(64.0, 2.0 * double(grid.candidates.size()));
  for (int pass = 0; pass < 8; ++pass) {
    const double cells = std::ceil(extent.x() / size) * std::ceil(extent.y() / size) * std::ceil(extent.z() / size);
    if (cells <= limit) break;
    size *= std::cbrt(cells / limit) * 1.0001;
  }
  grid.origin = lo_all;
  grid.cell = size;
  for (int a = 0; a < 3; ++a) grid.n[a] = std::max(1, std::min(64, int32_t(std::ceil(extent[a] / size))));
  const uint32_t cells = uint32_t(grid.n[0]) * uint32_t(grid.n[1]) * uint32_t(grid.n[2]);
  // Counting sort of the candidates into their cells (pieces covering many cells are tested always).
  const auto cell_range = [&](size_t i, int32_t r[6]) {
    for (int a = 0; a < 3; ++a) {
      r[a] = std::clamp(int32_t((grid.box_lo[i][a] - grid.origin[a]) / size), 0, grid.n[a] - 1);
      r[3 + a] = std::clamp(int32_t((grid.box_hi[i][a] - grid.origin[a]) / size), 0, grid.n[a] - 1);
    }
  };
  grid.cell_begin.assign(size_t(cells) + 1, 0);
  const auto for_cells = [&](const int32_t r[6], auto&& f) {
    for (int32_t z = r[2]; z <= r[5]; ++z) {
      for (int32_t y = r[1]; y <= r[4]; ++y) {
        for (int32_t x = r[0]; x <= r[3]; ++x) f(uint32_t(x) + uint32_t(grid.n[0]) * (uint32_t(y) + uint32_t(grid.n[1]) * uint32_t(z)));
      }
    }
  };
  grid.ranges.resize(grid.candidates.size() * 6);
  for (size_t i = 0; i < grid.candidates.size(); ++i) {
    int32_t* r = grid.ranges.data() + 6 * i;
    cell_range(i, r);
    const int64_t covered = int64_t(r[3] - r[0] + 1) * (r[4] - r[1] + 1) * (r[5] - r[2] + 1);
    if (covered > 64) {
      grid.everywhere.push_back(grid.candidates[i]);
      r[0] = 1;  // empty range
      r[3] = 0;
      continue;
    }
    for_cells(r, [&](uint32_t id) { ++grid.cell_begin[id + 1]; });
  }
  for (uint32_t c = 0; c < cells; ++c) grid.cell_begin[c + 1] += grid.cell_begin[c];
  grid.items.resize(grid.cell_begin[cells]);
  grid.cursor.assign(grid.cell_begin.begin(), grid.cell_begin.end() - 1);
  for (size_t i = 0; i < grid.candidates.size(); ++i) {
    const int32_t* r = grid.ranges.data() + 6 * i;
    for_cells(r, [&](uint32_t id) { grid.items[grid.cursor[id]++] = grid.candidates[i]; });
  }
}

// ---- Points --------------------------------------------------------------------------------

uint32_t world_to_rest(const VoxelModel& model, const PbdModel& pbd, PieceGrid& grid, const Vec3d& world,
                       std::vector<RestHit>& out, uint32_t* tests, uint32_t near_begin, uint32_t near_end) {
  const size_t before = out.size();
  constexpr double kInside = 1e-6;  // local-coordinate slack on the hexahedron's faces
  const double slack = 1e-5 * pbd.sim_size;
  query_piece_grid(grid, world, [&](uint32_t slot) {
    if (!in_piece_bounds(grid, slot, world, slack)) return;
    if (tests) ++*tests;
    // A neighbour's hit in this piece is a close start (about one Newton step fewer than the centre).
    Vec3d start = Vec3d::Constant(0.5);
    for (uint32_t h = near_begin; h < near_end; ++h) {
      if (out[h].piece != slot) continue;
      start = (out[h].rest - grid.piece_origin[slot]) / pbd.sim_size;
      break;
    }
    Vec3d u;
    if (!piece_local(pbd, grid, slot, world, start, u)) return;
    if (u.minCoeff() < -kInside || u.maxCoeff() > 1.0 + kInside) return;
    if (!piece_holds(model, pbd, slot, u)) return;
    out.push_back({slot, grid.piece_origin[slot] + pbd.sim_size * u});
  });
  return uint32_t(out.size() - before);
}

}  // namespace dvx
