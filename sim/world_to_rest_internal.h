// Internals of the mapping to rest space shared by its files (rest_map.cpp: the trilinear map, the
// grid over the deformed pieces and the points; sweep_map.cpp: the blade's sweep). Not for engine/,
// bench/ or ui/ (tests/layers_test.sh): they use sim/world_to_rest.h and sim/world.h.
#pragma once

#include "sim/world_to_rest.h"

namespace dvx {
namespace world_to_rest_internal {

// Inverts a piece's map at `world` (a candidate of the grid): local coordinates u (from `start`),
// false when Newton fails. Warm: chord steps with the inverse Jacobian of the piece's last inversion.
inline bool piece_local(const PbdModel& pbd, PieceGrid& grid, uint32_t piece, const Vec3d& world, const Vec3d& start,
                        Vec3d& u) {
  u = start;
  bool have = grid.jinv_valid[piece] != 0;
  const bool ok = invert_trilinear_warm(grid.piece_map[piece], world, u, 1e-7 * pbd.sim_size, grid.piece_jinv[piece], have);
  grid.jinv_valid[piece] = have;
  return ok;
}

// Whether `world` lies within a piece's deformed corner bounds grown by `slack`. The hexahedron lies
// in its corners' bounds (trilinear weights are a convex combination): a point farther out is not in
// the piece, and needs no Newton inversion (which converges to within 1e-7 sim_size, below any slack
// used here, so skipping it never changes a result).
// The bounds are the grid's (build_piece_grid keeps them for its candidates, the only slots a query
// returns).
inline bool in_piece_bounds(const PieceGrid& grid, uint32_t slot, const Vec3d& world, double slack) {
  const Vec3d& lo = grid.piece_lo[slot];
  const Vec3d& hi = grid.piece_hi[slot];
  return !((world.array() < lo.array() - slack).any() || (world.array() > hi.array() + slack).any());
}

}  // namespace world_to_rest_internal
}  // namespace dvx
