// check_pbd_state (sim/pbd.h): the simulation pieces recomputed from scratch and compared with the
// model (pieces, corner particles, masses, constraints and colours, embedding).
#include "sim/pbd_internal.h"

#include <algorithm>
#include <string>

namespace dvx {
using namespace pbd_internal;

// ---- Consistency check ---------------------------------------------------------------------

namespace {

bool fail(std::string& error, const std::string& what) {
  error = what;
  return false;
}

// Pieces of every simulation voxel = material components of its block, recomputed from scratch.
bool check_pieces(const VoxelModel& model, const CutState& cut, const PbdModel& s, std::string& error) {
  const uint32_t nodes = block_nodes(s);
  std::vector<uint8_t> fresh(nodes);
  std::vector<uint32_t> parent;
  const uint32_t voxels = uint32_t(s.sx) * uint32_t(s.sy) * uint32_t(s.sz);
  for (uint32_t sv = 0; sv < voxels; ++sv) {
    const uint8_t count = label_block(model, cut, s, sv, parent, fresh.data());
    const std::string where = "simulation voxel " + std::to_string(sv);
    if (count != s.pieces_in_voxel[sv]) {
      return fail(error, where + ": " + std::to_string(s.pieces_in_voxel[sv]) + " pieces, material has " +
                             std::to_string(count) + " components");
    }
    if (count == 0) continue;
    if (count > 1 && s.voxel_divided[sv] == kDeadIndex) return fail(error, where + ": several pieces but no labels");
    // Stored labels and fresh labels correspond one to one.
    uint8_t to_fresh[256], to_stored[256];
    std::fill(to_fresh, to_fresh + 256, kNoPiece);
    std::fill(to_stored, to_stored + 256, kNoPiece);
    int32_t c[3];
    sim_voxel_coords(s, sv, c);
    for (int32_t z = 0; z <= s.ratio; ++z) {
      for (int32_t y = 0; y <= s.ratio; ++y) {
        for (int32_t x = 0; x <= s.ratio; ++x) {
          const uint32_t b = block_index(s, x, y, z);
          const uint8_t stored = label_at(model, s, sv, c, b, c[0] * s.ratio + x, c[1] * s.ratio + y, c[2] * s.ratio + z);
          const uint8_t f = fresh[b];
          if ((stored == kNoPiece) != (f == kNoPiece)) return fail(error, where + ": label of an outside node");
          if (f == kNoPiece) continue;
          if (to_fresh[stored] == kNoPiece && to_stored[f] == kNoPiece) {
            to_fresh[stored] = f;
            to_stored[f] = stored;
          }
          if (to_fresh[stored] != f || to_stored[f] != stored) return fail(error, where + ": pieces differ from material components");
        }
      }
    }
    // Each label's piece slot is live, names this voxel and label, and holds the label's volume.
    uint64_t eighths[256];
    label_eighths(model, s, sv, fresh.data(), eighths);
    for (uint8_t p = 0; p < count; ++p) {
      const uint32_t slot = slot_of_label(s, sv, p);
      if (slot >= s.pieces.size() || s.pieces[slot].sim_voxel != sv || s.pieces[slot].piece != p) {
        return fail(error, where + ": label " + std::to_string(p) + " has no live piece");
      }
      if (s.pieces[slot].eighths != eighths[to_fresh[p]]) return fail(error, where + ": piece volume is not its material's");
    }
  }
  return true;
}

// Particle sharing = material adjacency at every coarse corner.
bool check_corners(const VoxelModel& model, const PbdModel& s, std::string& error) {
  CornerMembers m;
  FaceCache cache;
  for (int32_t K = 0; K <= s.sz; ++K) {
    for (int32_t J = 0; J <= s.sy; ++J) {
      for (int32_t I = 0; I <= s.sx; ++I) {
        corner_groups(model, s, I, J, K, m, cache);
        for (int a = 0; a < m.count; ++a) {
          const uint32_t pa = s.pieces[m.slot[a]].particles[m.corner[a]];
          for (int b = a + 1; b < m.count; ++b) {
            const uint32_t pb = s.pieces[m.slot[b]].particles[m.corner[b]];
            if ((m.find(a) == m.find(b)) != (pa == pb)) {
              return fail(error, "corner (" + std::to_string(I) + "," + std::to_string(J) + "," + std::to_string(K) +
                                     "): particle sharing differs from material adjacency");
            }
          }
        }
      }
    }
  }
  return true;
}

// Masses, references and free lists of particles and pieces.
bool check_particles(const PbdModel& s, const PbdData& data, std::string& error) {
  const size_t n = s.rest.size();
  std::vector<uint64_t> eighths(n, 0);
  std::vector<uint32_t> refs(n, 0);
  for (const SimPiece& piece : s.pieces) {
    if (piece.sim_voxel == kDeadIndex) continue;
    for (uint32_t p : piece.particles) {
      if (p >= n) return fail(error, "a piece names a particle out of range");
      eighths[p] += piece.eighths;
      ++refs[p];
    }
  }
  std::vector<uint8_t> free_slot(n, 0);
  for (uint32_t p : s.free_particles) {
    if (p >= n || free_slot[p]) return fail(error, "free particle list holds a bad or repeated slot");
    free_slot[p] = 1;
  }
  const double h = s.fine_size;
  for (size_t p = 0; p < n; ++p) {
    const std::string where = "particle " + std::to_string(p);
    if (refs[p] != s.refs[p]) return fail(error, where + ": reference count is not its piece corners");
    if ((refs[p] == 0) != (free_slot[p] != 0)) return fail(error, where + ": free list disagrees with its use");
    if (refs[p] == 0) continue;
    if (eighths[p] != s.mass_eighths[p]) return fail(error, where + ": mass is not its pieces' volume");
    if (s.mass[p] != s.params.density * (double(eighths[p]) * (h * h * h / 64.0))) return fail(error, where + ": mass is not density x volume");
    if (!data.position[p].allFinite()) return fail(error, where + ": position is not finite");
  }
  std::vector<uint8_t> free_piece_slot(s.pieces.size(), 0);
  for (uint32_t slot : s.free_pieces) {
    if (slot >= s.pieces.size() || free_piece_slot[slot] || s.pieces[slot].sim_voxel != kDeadIndex) {
      return fail(error, "free piece list holds a live, bad or repeated slot");
    }
    free_piece_slot[slot] = 1;
  }
  for (size_t slot = 0; slot < s.pieces.size(); ++slot) {
    if (s.pieces[slot].sim_voxel == kDeadIndex && !free_piece_slot[slot]) return fail(error, "a dead piece slot is not free");
  }
  return true;
}

// Stretch constraints = unique particle pairs along piece edges; colour groups race-free.
bool check_constraints(const PbdModel& s, const PbdData& data, std::string& error) {
  FlatMap expected;
  for (const SimPiece& piece : s.pieces) {
    if (piece.sim_voxel == kDeadIndex) continue;
    for (const VoxelEdge& e : kVoxelEdges) {
      const uint64_t key = pair_key(std::min(piece.particles[e.c0], piece.particles[e.c1]),
                                    std::max(piece.particles[e.c0], piece.particles[e.c1]));
      expected.set(key, expected.get(key, 0) + 1);
    }
  }
  const size_t n = s.rest.size();
  std::vector<uint64_t> stretch_busy(n, 0), shape_busy(n, 0);
  uint32_t count = 0;
  for (int c = 0; c < kColourGroups; ++c) {
    if (data.stretch_lambda[c].size() != s.stretch_groups[c].size()) return fail(error, "lambdas out of step with constraints");
    for (uint32_t i = 0; i < s.stretch_groups[c].size(); ++i) {
      const StretchConstraint& k = s.stretch_groups[c][i];
      const StretchHandle& h = s.stretch_handles[k.handle];
      if (h.colour != c || h.index != i) return fail(error, "a stretch handle does not point at its constraint");
      if (h.refs != expected.get(pair_key(k.a, k.b), 0)) return fail(error, "a stretch constraint's uses differ from the piece edges");
      if (s.stretch_of.get(pair_key(k.a, k.b)) != k.handle) return fail(error, "stretch map out of step");
      const uint64_t bit = colour_bit(uint8_t(c));
      if ((stretch_busy[k.a] | stretch_busy[k.b]) & bit) return fail(error, "two stretch constraints of one colour share a particle");
      stretch_busy[k.a] |= bit;
      stretch_busy[k.b] |= bit;
      ++count;
    }
    for (uint32_t i = 0; i < s.piece_groups[c].size(); ++i) {
      const SimPiece& piece = s.pieces[s.piece_groups[c][i]];
      if (piece.sim_voxel == kDeadIndex || piece.colour != c || piece.colour_slot != i) return fail(error, "a shape group holds a stale piece");
      const uint64_t bit = colour_bit(uint8_t(c));
      for (uint32_t p : piece.particles) {
        if (shape_busy[p] & bit) return fail(error, "two shape constraints of one colour share a particle");
        shape_busy[p] |= bit;
      }
    }
  }
  if (count != expected.size()) return fail(error, "stretch constraints missing for some piece edges");
  for (size_t p = 0; p < n; ++p) {
    if (s.refs[p] && (stretch_busy[p] != s.stretch_busy[p] || shape_busy[p] != s.shape_busy[p])) {
      return fail(error, "colour masks out of step with the groups");
    }
  }
  uint32_t grouped = 0;
  for (const auto& group : s.piece_groups) grouped += uint32_t(group.size());
  if (grouped != live_pieces(s)) return fail(error, "a live piece is in no shape group");
  return true;
}

}  // namespace

bool check_pbd_state(const VoxelModel& model, const CutState& cut, const PbdModel& s, const PbdData& data,
                     std::string& error) {
  if (!check_pieces(model, cut, s, error) || !check_corners(model, s, error) || !check_particles(s, data, error) ||
      !check_constraints(s, data, error)) {
    return false;
  }
  // Every live vertex slot is embedded in a live piece.
  for (uint32_t slot = 0; slot < cut.surface.positions.size(); ++slot) {
    if (cut.surface.vertex_piece[slot] == CutSurface::kFreeKey) continue;
    if (slot >= s.embedding.size()) return fail(error, "vertex slot " + std::to_string(slot) + " has no embedding");
    const uint32_t piece = embedded_piece(s, s.embedding[slot]);
    if (piece == kDeadIndex || s.pieces[piece].sim_voxel == kDeadIndex) {
      return fail(error, "vertex slot " + std::to_string(slot) + " is embedded in no live piece");
    }
  }
  return true;
}

}  // namespace dvx
