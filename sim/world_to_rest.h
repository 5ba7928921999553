// World space -> rest space through the deformed simulation pieces (DESIGN §3 "Deformation").
//
// Cuts are made in rest space (the voxel model never moves); the blade moves in world space. A
// point in world space is in material where some piece's deformed hexahedron contains it *and* the
// rest position found by inverting that piece's trilinear map lies in that piece's material. So a
// blade through air cuts nothing, a bent or rotated piece is cut where the blade passes it, and two
// overlapping pieces (a flap folded onto the body) are each cut where the blade passes them.
//
// The pieces are found through a uniform grid over their deformed bounds (PieceGrid, rebuilt per use
// over the region of interest: one pass over the pieces, no sort); the map is inverted by Newton's
// method on the trilinear map (invert_trilinear), warm along the sweep: each candidate piece's map in
// monomial form, and chord steps with the inverse Jacobian of the piece's last inversion, Newton only
// when they stop contracting (invert_trilinear_warm).
//
// The blade's sweep between two steps is sampled at fine-voxel spacing, along the blade and along
// its motion. The sweep starts where the blade's previous samples are *now*: each sample that was in
// material is carried with the material (its rest point mapped forward through the current
// deformation), so a still blade cuts tissue moving into it, and a blade moving with the tissue cuts
// nothing new; a sample in no piece is carried through its nearest neighbour's piece (extrapolated),
// and each piece's quads of a step start from the rest points that piece's quads of the last step
// ended on (SweepMapper::ended): the cut sheet is continuous in rest space from step to step
// (docs/cutting.md; a sweep whose world surface spans a moving body's cross-section severs it). Each cell of the sampled sweep becomes one rest-space quad per piece that holds one of
// its corners (the other corners mapped through the same piece, extrapolating its map a little);
// the quads that continue one flat, straight strip are merged before cutting — along the blade (each
// piece's strip, also where a piece boundary runs along the sweep) and across the sweep's rows — so
// the divide and the cut front run once per strip, not once per cell row.
#pragma once

#include "sim/cut.h"
#include "sim/pbd.h"

#include <cstdint>
#include <vector>

namespace dvx {

// Trilinear map of a hexahedron (corners c = dx | dy<<1 | dz<<2) at local coordinates u.
Vec3d trilinear(const Vec3d corners[8], const Vec3d& u);

// Finds u with trilinear(corners, u) = target by Newton's method from `u` (in/out; start e.g. at
// 0.5^3), to within `tolerance` (world units). Returns false when it does not converge (degenerate or
// inverted hexahedron, or a target far outside: |u - 0.5| > 2 on an axis).
bool invert_trilinear(const Vec3d corners[8], const Vec3d& target, Vec3d& u, double tolerance, int max_iterations = 16);

// A hexahedron's trilinear map in monomial form, x(u) = c[0] + c[1] u + c[2] v + c[3] w + c[4] uv +
// c[5] uw + c[6] vw + c[7] uvw: a map and its Jacobian cost a third of the corner form's products,
// and the mapping of a sweep evaluates one piece's map many times.
struct TrilinearMap {
  Vec3d c[8];
};
TrilinearMap trilinear_map(const Vec3d corners[8]);

// The inversion of a piece's map, warm: `jinv` is an inverse Jacobian of the same map near the
// answer (`have_jinv` false: none yet). Chord steps u += jinv (target - x(u)) need one map evaluation
// each; when they stop contracting (or without jinv) Newton's method takes over from the best point,
// and jinv becomes the inverse of its last Jacobian. Converges to the same tolerance as
// invert_trilinear (the answer differs from its answer within it); false when Newton fails.
bool invert_trilinear_warm(const TrilinearMap& map, const Vec3d& target, Vec3d& u, double tolerance,
                           Eigen::Matrix3d& jinv, bool& have_jinv, int max_iterations = 16);

// A uniform grid over the deformed bounds of the pieces that overlap a region.
struct PieceGrid {
  Vec3d origin = Vec3d::Zero();
  double cell = 1.0;
  int32_t n[3] = {0, 0, 0};
  std::vector<uint32_t> cell_begin;  // (cells + 1) offsets into items
  std::vector<uint32_t> items;       // piece slots per cell
  std::vector<uint32_t> everywhere;  // pieces too large for the grid: tested by every query
  std::vector<Vec3d> piece_lo, piece_hi;  // (piece slots) deformed corner bounds, valid for the candidates
  // (piece slots, valid for the candidates) each piece's map and rest origin, and an inverse Jacobian of it from an
  // earlier inversion (jinv_valid), so a sweep's many points in one piece mostly need chord steps.
  std::vector<TrilinearMap> piece_map;
  std::vector<Vec3d> piece_origin;  // rest position of the piece's corner 0 (piece_rest_origin)
  std::vector<Eigen::Matrix3d> piece_jinv;
  std::vector<uint8_t> jinv_valid;
  // Scratch.
  std::vector<uint32_t> candidates;
  std::vector<int32_t> ranges;  // (candidates x 6) cell ranges
  std::vector<Vec3d> box_lo, box_hi;  // (candidates) grown bounds clipped to the region
  std::vector<uint32_t> cursor;       // (cells) fill positions
};

// Builds the grid over the live pieces whose deformed bounds, grown by `margin`, overlap `region`.
// Cells of about `cell` (at most 64 per axis).
void build_piece_grid(const PbdModel& pbd, const PbdData& data, const Aabb& region, double cell, double margin,
                      PieceGrid& grid);

// Calls f(piece slot) for each piece whose grown bounds may contain `point` (each at most once).
template <typename F>
void query_piece_grid(const PieceGrid& grid, const Vec3d& point, F&& f) {
  for (uint32_t slot : grid.everywhere) f(slot);
  if (grid.cell_begin.empty()) return;
  int32_t c[3];
  for (int a = 0; a < 3; ++a) {
    const double x = (point[a] - grid.origin[a]) / grid.cell;
    if (!(x >= 0.0) || x >= double(grid.n[a])) return;
    c[a] = int32_t(x);
  }
  const uint32_t id = uint32_t(c[0]) + uint32_t(grid.n[0]) * (uint32_t(c[1]) + uint32_t(grid.n[1]) * uint32_t(c[2]));
  for (uint32_t i = grid.cell_begin[id]; i < grid.cell_begin[id + 1]; ++i) f(grid.items[i]);
}

// The rest positions of a world point: every (piece, rest point) whose piece holds the point's
// preimage in its material. Appends to `out`; returns how many it appended.
struct RestHit {
  uint32_t piece;
  Vec3d rest;
};
// `tests` (optional) counts the Newton inversions. out[near_begin, near_end) (optional): hits of a
// neighbouring point; Newton starts from their local coordinates in the same piece (else the centre).
uint32_t world_to_rest(const VoxelModel& model, const PbdModel& pbd, PieceGrid& grid, const Vec3d& world,
                       std::vector<RestHit>& out, uint32_t* tests = nullptr, uint32_t near_begin = 0, uint32_t near_end = 0);

// A rest-space quad to cut: the sweep from one blade segment to another.
struct RestQuad {
  BladePose from, to;
};

// The blade's state between steps and the scratch of the mapping (no allocation in steady state).
struct SweepMapper {
  // (blade samples) rest point of each sample at the last pose, relative to the piece whose material
  // (or, in a slit or a gap, whose hexahedron) held it; NaN: in no piece.
  std::vector<Vec3d> carried;
  std::vector<uint32_t> carried_piece;
  // The rest points the last step's final row of quads ended on, per blade sample and piece
  // (ended[ended_begin[i], ended_begin[i + 1]) for sample i): the next step's first row starts from
  // exactly these through the same piece, so its strip meets the last one in rest space even where
  // two pieces around a sample no longer agree (the sides of a cut move apart).
  std::vector<RestHit> ended, ending;
  std::vector<uint32_t> ended_begin, ending_sample, ended_fill;
  // (blade samples) 1: in no piece, carried through the piece of sample carried_near (extrapolated).
  std::vector<uint8_t> carried_outside;
  std::vector<uint32_t> carried_near;
  PieceGrid grid;
  std::vector<Vec3d> from_world, to_world, points;
  std::vector<uint32_t> hit_begin;
  std::vector<RestHit> hits;
  std::vector<RestQuad> quads;
  // Scratch of the merge across rows of the sweep: the quads the next row may continue, the rungs
  // (inner row edges) of each merged quad, and the quads merged away.
  struct Rung {
    uint32_t quad;
    Vec3d a, b;
  };
  // Along the blade: the quads each cell went to (cells of a row in order) and the junctions of
  // each quad merged along the blade (a list per quad through joint_head / next).
  struct Joint {
    Vec3d a, b;
    uint32_t next;
  };
  std::vector<uint32_t> cell_quads, joint_head;
  std::vector<Joint> joints;
  // (quads x 2) upper bounds of the distances of a quad's junctions from its blade edges (from, to):
  // a strip that stays straight is extended without measuring each junction again.
  std::vector<double> joint_bound;
  std::vector<uint32_t> open, next_open;
  std::vector<Rung> rungs;
  std::vector<uint8_t> merged_away;
};

// What one mapping did.
struct SweepMapStats {
  uint32_t samples = 0;      // world points mapped
  uint32_t piece_tests = 0;  // (point, piece) Newton inversions
  uint32_t hits = 0;         // accepted (point, piece) pairs
  uint32_t quads = 0;        // rest quads cut
};

// Forgets the carried blade (a new cut starts where the blade is).
void reset_sweep(SweepMapper& mapper);

// Maps the sweep from world pose `from` to world pose `to` into rest-space quads (mapper.quads) and
// records the rest points of `to` for the next step.
void map_sweep(const VoxelModel& model, const PbdModel& pbd, const PbdData& data, const BladePose& from,
               const BladePose& to, SweepMapper& mapper, SweepMapStats* stats = nullptr);

}  // namespace dvx
