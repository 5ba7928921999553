#include "sim/pbd.h"

#include "sim/pbd_kernels.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace dvx {
namespace {

constexpr uint8_t kMaxSimPieces = 250;  // labels are uint8; more components than this merge into the last
constexpr uint32_t kLabelSlots = 256;   // piece slots per divided simulation voxel

constexpr int kCubeEdges[12][2] = {{0, 1}, {2, 3}, {4, 5}, {6, 7}, {0, 2}, {1, 3},
                                   {4, 6}, {5, 7}, {0, 4}, {1, 5}, {2, 6}, {3, 7}};

// ---- Fine lattice access -------------------------------------------------------------------

bool fine_inside(const VoxelModel& model, int32_t i, int32_t j, int32_t k) {
  const Lattice& l = model.lattice;
  if (i < 0 || j < 0 || k < 0 || i > l.nx || j > l.ny || k > l.nz) return false;
  return model.is_inside(l.node(i, j, k));
}

// ---- Simulation grid -----------------------------------------------------------------------

uint32_t sim_voxel_id(const PbdModel& s, int32_t I, int32_t J, int32_t K) {
  return uint32_t(I) + uint32_t(s.sx) * (uint32_t(J) + uint32_t(s.sy) * uint32_t(K));
}

void sim_voxel_coords(const PbdModel& s, uint32_t v, int32_t c[3]) {
  c[0] = int32_t(v % uint32_t(s.sx));
  v /= uint32_t(s.sx);
  c[1] = int32_t(v % uint32_t(s.sy));
  c[2] = int32_t(v / uint32_t(s.sy));
}

bool sim_in_range(const PbdModel& s, int32_t I, int32_t J, int32_t K) {
  return I >= 0 && J >= 0 && K >= 0 && I < s.sx && J < s.sy && K < s.sz;
}

// Index of a fine node inside a simulation voxel's block ((ratio+1)^3 nodes).
uint32_t block_index(const PbdModel& s, int32_t a, int32_t b, int32_t c) {
  const uint32_t n = uint32_t(s.ratio + 1);
  return uint32_t(a) + n * (uint32_t(b) + n * uint32_t(c));
}

uint32_t block_nodes(const PbdModel& s) { return uint32_t((s.ratio + 1) * (s.ratio + 1) * (s.ratio + 1)); }

Vec3d corner_rest(const PbdModel& s, int32_t I, int32_t J, int32_t K) {
  return s.origin + s.sim_size * Vec3d(I, J, K);
}

bool has_pieces(const PbdModel& s, uint32_t sv) { return s.pieces_in_voxel[sv] != 0; }

// Label of a fine node given by its block index in simulation voxel sv (kNoPiece: no material).
uint8_t label_at(const VoxelModel& model, const PbdModel& s, uint32_t sv, const int32_t svc[3], uint32_t b,
                 int32_t i, int32_t j, int32_t k) {
  if (!has_pieces(s, sv)) return kNoPiece;
  const uint32_t d = s.voxel_divided[sv];
  if (d == kDeadIndex) return fine_inside(model, i, j, k) ? 0 : kNoPiece;
  (void)svc;
  return s.labels[s.divided[d].first_label + b];
}

// Label of a fine node (global fine coordinates) in simulation voxel sv.
uint8_t node_label(const VoxelModel& model, const PbdModel& s, uint32_t sv, const int32_t svc[3], int32_t i,
                   int32_t j, int32_t k) {
  const uint32_t b = block_index(s, i - svc[0] * s.ratio, j - svc[1] * s.ratio, k - svc[2] * s.ratio);
  return label_at(model, s, sv, svc, b, i, j, k);
}

uint32_t slot_of_label(const PbdModel& s, uint32_t sv, uint8_t label) {
  if (label == kNoPiece || label >= s.pieces_in_voxel[sv]) return kDeadIndex;
  const uint32_t d = s.voxel_divided[sv];
  if (d == kDeadIndex) return label == 0 ? s.voxel_piece[sv] : kDeadIndex;
  return s.label_slots[s.divided[d].first_slot + label];
}

// ---- Labelling -----------------------------------------------------------------------------

// Labels the fine nodes of a simulation voxel's block by material component: nodes are joined when a
// fine voxel of the block puts them in one piece (voxel_pieces: the fine level decides what material
// joins). Components are numbered in node order. Returns the count (0: no material).
uint8_t label_block(const VoxelModel& model, const CutState& cut, const PbdModel& s, uint32_t sv,
                    std::vector<uint32_t>& parent, uint8_t* labels) {
  int32_t c[3];
  sim_voxel_coords(s, sv, c);
  const Lattice& l = model.lattice;
  const int32_t r = s.ratio, n = r + 1;
  const uint32_t count = block_nodes(s);
  parent.resize(count);
  for (uint32_t i = 0; i < count; ++i) parent[i] = i;
  const auto find = [&](uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  for (int32_t z = 0; z < r && c[2] * r + z < l.nz; ++z) {
    for (int32_t y = 0; y < r && c[1] * r + y < l.ny; ++y) {
      for (int32_t x = 0; x < r && c[0] * r + x < l.nx; ++x) {
        const uint32_t voxel = l.voxel(c[0] * r + x, c[1] * r + y, c[2] * r + z);
        uint8_t corner_piece[8], pieces = 0;
        voxel_pieces(model, cut, voxel, corner_piece, pieces);
        if (pieces == 0) continue;
        // Join each inside corner to the first corner of its piece.
        uint32_t first[8] = {kDeadIndex, kDeadIndex, kDeadIndex, kDeadIndex, kDeadIndex, kDeadIndex, kDeadIndex, kDeadIndex};
        for (int q = 0; q < 8; ++q) {
          const uint8_t p = corner_piece[q];
          if (p == kNoPiece || p >= 8) continue;
          const uint32_t b = find(block_index(s, x + (q & 1), y + ((q >> 1) & 1), z + ((q >> 2) & 1)));
          if (first[p] == kDeadIndex) {
            first[p] = b;
            continue;
          }
          const uint32_t f = find(first[p]);
          if (b != f) parent[std::max(b, f)] = std::min(b, f);
          first[p] = std::min(b, f);
        }
      }
    }
  }
  // Number the components in node order (parent[] of a root becomes its label + count).
  uint8_t pieces = 0;
  for (int32_t z = 0; z < n; ++z) {
    for (int32_t y = 0; y < n; ++y) {
      for (int32_t x = 0; x < n; ++x) {
        const uint32_t b = block_index(s, x, y, z);
        if (!fine_inside(model, c[0] * r + x, c[1] * r + y, c[2] * r + z)) {
          labels[b] = kNoPiece;
          continue;
        }
        const uint32_t root = find(b);
        if (root == b) {
          labels[b] = pieces < kMaxSimPieces ? pieces++ : uint8_t(kMaxSimPieces - 1);
        } else {
          labels[b] = labels[root];  // roots come first in node order (union keeps the smaller index)
        }
      }
    }
  }
  return pieces;
}

// Material volume of each label of a block, in eighths of a fine voxel: each inside node adds one
// eighth for each of the block's fine voxels around it (1, 2, 4 or 8), so volumes partition exactly.
void label_eighths(const VoxelModel& model, const PbdModel& s, uint32_t sv, const uint8_t* labels, uint64_t eighths[256]) {
  int32_t c[3];
  sim_voxel_coords(s, sv, c);
  const Lattice& l = model.lattice;
  std::fill(eighths, eighths + 256, uint64_t(0));
  const auto around = [&](int32_t x, int32_t first, int32_t n) {
    return uint64_t((x > 0 && first + x - 1 < n) + (x < s.ratio && first + x < n));
  };
  for (int32_t z = 0; z <= s.ratio; ++z) {
    const uint64_t wz = around(z, c[2] * s.ratio, l.nz);
    for (int32_t y = 0; y <= s.ratio; ++y) {
      const uint64_t wyz = wz * around(y, c[1] * s.ratio, l.ny);
      if (wyz == 0) continue;
      for (int32_t x = 0; x <= s.ratio; ++x) {
        const uint64_t w = wyz * around(x, c[0] * s.ratio, l.nx);
        const uint8_t p = labels[block_index(s, x, y, z)];
        if (w != 0 && p != kNoPiece) eighths[p] += w;
      }
    }
  }
}

// ---- Slots ---------------------------------------------------------------------------------

// Arguments by value: they may point into the arrays this grows.
uint32_t new_particle(PbdState& s, const Vec3d rest, const Vec3d position, const Vec3d velocity) {
  uint32_t p;
  if (!s.free_particles.empty()) {
    p = s.free_particles.back();
    s.free_particles.pop_back();
  } else {
    p = uint32_t(s.rest.size());
    s.position.emplace_back();
    s.velocity.emplace_back();
    s.previous.emplace_back();
    s.rest.emplace_back();
    s.mass_eighths.push_back(0);
    s.mass.push_back(0.0);
    s.inv_mass.push_back(0.0);
    s.refs.push_back(0);
    s.anchored.push_back(0);
    s.stretch_busy.push_back(0);
    s.shape_busy.push_back(0);
  }
  s.rest[p] = rest;
  s.position[p] = position;
  s.previous[p] = position;
  s.velocity[p] = velocity;
  s.mass_eighths[p] = 0;
  s.refs[p] = 0;
  bool anchored = false;
  for (const Aabb& box : s.params.fixed) {
    anchored = anchored || ((rest.array() >= box.min.array()).all() && (rest.array() <= box.max.array()).all());
  }
  s.anchored[p] = anchored;
  return p;
}

uint32_t new_piece(PbdState& s, uint32_t sv, uint8_t label) {
  uint32_t slot;
  if (!s.free_pieces.empty()) {
    slot = s.free_pieces.back();
    s.free_pieces.pop_back();
  } else {
    slot = uint32_t(s.pieces.size());
    s.pieces.emplace_back();
    s.rotation.push_back(Eigen::Quaterniond::Identity());
  }
  SimPiece& piece = s.pieces[slot];
  piece.sim_voxel = sv;
  piece.piece = label;
  piece.colour = kOverflowColour;
  piece.colour_slot = kDeadIndex;
  std::fill(piece.particles, piece.particles + 8, kDeadIndex);
  piece.eighths = 0;
  s.rotation[slot] = Eigen::Quaterniond::Identity();
  return slot;
}

void free_piece(PbdState& s, uint32_t slot) {
  s.pieces[slot].sim_voxel = kDeadIndex;
  s.free_pieces.push_back(slot);
}

// Mass of a particle from its eighths (exact: one rounding of an integer product).
void update_mass(PbdState& s, uint32_t p) {
  const double h = s.fine_size;
  s.mass[p] = s.params.density * (double(s.mass_eighths[p]) * (h * h * h / 64.0));
  s.inv_mass[p] = s.anchored[p] || s.mass[p] <= 0.0 ? 0.0 : 1.0 / s.mass[p];
}

// ---- Colour groups -------------------------------------------------------------------------

// First colour not in `taken` (bits 0..62), else the overflow colour.
uint8_t first_free_colour(uint64_t taken) {
  const uint64_t free_bits = ~taken & ((uint64_t(1) << kOverflowColour) - 1);
  return free_bits == 0 ? kOverflowColour : uint8_t(__builtin_ctzll(free_bits));
}

uint64_t colour_bit(uint8_t colour) { return colour == kOverflowColour ? 0 : uint64_t(1) << colour; }

uint64_t pair_key(uint32_t a, uint32_t b) { return (uint64_t(a) << 32) | b; }

// One more piece edge uses particle pair (a, b): the constraint is created (and coloured) on first use.
void add_stretch(PbdState& s, uint32_t a, uint32_t b) {
  if (a > b) std::swap(a, b);
  const uint64_t key = pair_key(a, b);
  const uint32_t existing = s.stretch_of.get(key);
  if (existing != kDeadIndex) {
    ++s.stretch_handles[existing].refs;
    return;
  }
  uint32_t handle;
  if (!s.free_stretch_handles.empty()) {
    handle = s.free_stretch_handles.back();
    s.free_stretch_handles.pop_back();
  } else {
    handle = uint32_t(s.stretch_handles.size());
    s.stretch_handles.emplace_back();
  }
  const uint8_t colour = first_free_colour(s.stretch_busy[a] | s.stretch_busy[b]);
  s.stretch_busy[a] |= colour_bit(colour);
  s.stretch_busy[b] |= colour_bit(colour);
  std::vector<StretchConstraint>& group = s.stretch_groups[colour];
  s.stretch_handles[handle] = {colour, uint32_t(group.size()), 1};
  group.push_back({a, b, (s.rest[a] - s.rest[b]).norm(), handle});
  s.stretch_lambda[colour].push_back(0.0);
  s.stretch_of.set(key, handle);
}

// One piece edge fewer uses (a, b): the last use removes the constraint by swap-with-last in its group.
void remove_stretch(PbdState& s, uint32_t a, uint32_t b) {
  if (a > b) std::swap(a, b);
  const uint64_t key = pair_key(a, b);
  const uint32_t handle = s.stretch_of.get(key);
  if (handle == kDeadIndex) return;
  StretchHandle& h = s.stretch_handles[handle];
  if (--h.refs > 0) return;
  std::vector<StretchConstraint>& group = s.stretch_groups[h.colour];
  std::vector<double>& lambda = s.stretch_lambda[h.colour];
  s.stretch_busy[a] &= ~colour_bit(h.colour);
  s.stretch_busy[b] &= ~colour_bit(h.colour);
  const uint32_t last = uint32_t(group.size() - 1);
  if (h.index != last) {
    group[h.index] = group[last];
    lambda[h.index] = lambda[last];
    s.stretch_handles[group[h.index].handle].index = h.index;
  }
  group.pop_back();
  lambda.pop_back();
  h.refs = kDeadIndex;
  s.free_stretch_handles.push_back(handle);
  s.stretch_of.erase(key);
}

// A piece joins the dynamics: masses, constraint references, shape-matching colour.
void attach_piece(PbdState& s, uint32_t slot) {
  SimPiece& piece = s.pieces[slot];
  uint64_t taken = 0;
  for (uint32_t p : piece.particles) {
    ++s.refs[p];
    s.mass_eighths[p] += piece.eighths;
    taken |= s.shape_busy[p];
  }
  for (const auto& e : kCubeEdges) add_stretch(s, piece.particles[e[0]], piece.particles[e[1]]);
  piece.colour = first_free_colour(taken);
  for (uint32_t p : piece.particles) s.shape_busy[p] |= colour_bit(piece.colour);
  piece.colour_slot = uint32_t(s.piece_groups[piece.colour].size());
  s.piece_groups[piece.colour].push_back(slot);
}

// The reverse of attach_piece.
void detach_piece(PbdState& s, uint32_t slot) {
  SimPiece& piece = s.pieces[slot];
  for (uint32_t p : piece.particles) {
    --s.refs[p];
    s.mass_eighths[p] -= piece.eighths;
    s.shape_busy[p] &= ~colour_bit(piece.colour);
  }
  for (const auto& e : kCubeEdges) remove_stretch(s, piece.particles[e[0]], piece.particles[e[1]]);
  std::vector<uint32_t>& group = s.piece_groups[piece.colour];
  const uint32_t last = uint32_t(group.size() - 1);
  if (piece.colour_slot != last) {
    group[piece.colour_slot] = group[last];
    s.pieces[group[piece.colour_slot]].colour_slot = piece.colour_slot;
  }
  group.pop_back();
  piece.colour_slot = kDeadIndex;
}

// Runs f(slot) for each piece of simulation voxel sv.
template <typename F>
void for_pieces(const PbdModel& s, uint32_t sv, F&& f) {
  for (uint8_t p = 0; p < s.pieces_in_voxel[sv]; ++p) f(slot_of_label(s, sv, p));
}

// ---- Corner particles ----------------------------------------------------------------------

// The pieces around a coarse corner and the groups that material joins them into.
struct CornerMembers {
  static constexpr int kMax = 8 * 256;
  uint32_t slot[kMax];  // piece slots
  uint8_t corner[kMax];  // the coarse corner's number in that piece's voxel
  int parent[kMax];
  int base[8];          // first member of the voxel around the corner in octant q (-1: none)
  int count = 0;
  int find(int x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  }
};

// Fills the members around corner (I,J,K) and unites those joined by a fine node on their common
// boundary (the three planes through the corner); stops as soon as everything is one group.
void corner_groups(const VoxelModel& model, const PbdModel& s, int32_t I, int32_t J, int32_t K, CornerMembers& m) {
  m.count = 0;
  uint32_t voxels[8];
  int32_t vcs[8][3];
  int groups = 0;
  for (int q = 0; q < 8; ++q) {
    const int32_t c[3] = {I - 1 + (q & 1), J - 1 + ((q >> 1) & 1), K - 1 + ((q >> 2) & 1)};
    voxels[q] = kDeadIndex;
    m.base[q] = -1;
    if (!sim_in_range(s, c[0], c[1], c[2])) continue;
    const uint32_t sv = sim_voxel_id(s, c[0], c[1], c[2]);
    if (!has_pieces(s, sv)) continue;
    voxels[q] = sv;
    std::copy(c, c + 3, vcs[q]);
    m.base[q] = m.count;
    const uint8_t corner = uint8_t((1 - (q & 1)) | ((1 - ((q >> 1) & 1)) << 1) | ((1 - ((q >> 2) & 1)) << 2));
    for (uint8_t p = 0; p < s.pieces_in_voxel[sv]; ++p) {
      m.slot[m.count] = slot_of_label(s, sv, p);
      m.corner[m.count] = corner;
      m.parent[m.count] = m.count;
      ++m.count;
      ++groups;
    }
  }
  const int32_t r = s.ratio;
  const int32_t ci = I * r, cj = J * r, ck = K * r;
  for (int32_t c = -r; c <= r && groups > 1; ++c) {
    for (int32_t b = -r; b <= r && groups > 1; ++b) {
      // Only nodes shared by several voxels: on one of the three planes through the corner.
      const bool line_only = b != 0 && c != 0;
      for (int32_t a = line_only ? 0 : -r; a <= (line_only ? 0 : r) && groups > 1; ++a) {
        const int32_t i = ci + a, j = cj + b, k = ck + c;
        if (!fine_inside(model, i, j, k)) continue;
        int first = -1;
        for (int q = 0; q < 8; ++q) {
          if (voxels[q] == kDeadIndex) continue;
          const int dx = q & 1, dy = (q >> 1) & 1, dz = (q >> 2) & 1;
          if ((dx == 0 ? a > 0 : a < 0) || (dy == 0 ? b > 0 : b < 0) || (dz == 0 ? c > 0 : c < 0)) continue;
          const uint8_t label = node_label(model, s, voxels[q], vcs[q], i, j, k);
          if (label == kNoPiece) continue;
          const int x = m.find(m.base[q] + label);
          if (first < 0) {
            first = x;
          } else if (x != first) {
            m.parent[std::max(x, first)] = std::min(x, first);
            first = std::min(x, first);
            --groups;
          }
        }
      }
    }
  }
}

// Assigns particles at coarse corner (I,J,K): one per material group of the pieces around it.
// Existing particles are kept where possible (the smallest not yet claimed by another group).
void assign_corner(const VoxelModel& model, PbdState& s, int32_t I, int32_t J, int32_t K, CornerMembers& m) {
  corner_groups(model, s, I, J, K, m);
  uint32_t claimed[CornerMembers::kMax];
  int claimed_count = 0;
  for (int g = 0; g < m.count; ++g) {
    if (m.find(g) != g) continue;
    uint32_t best = kDeadIndex;
    for (int n = g; n < m.count; ++n) {
      if (m.find(n) != g) continue;
      const uint32_t p = s.pieces[m.slot[n]].particles[m.corner[n]];
      if (p == kDeadIndex || p >= best || std::find(claimed, claimed + claimed_count, p) != claimed + claimed_count) continue;
      best = p;
    }
    if (best == kDeadIndex) {
      // A new particle, starting where the group's previous particle was.
      const uint32_t from = s.pieces[m.slot[g]].particles[m.corner[g]];
      const Vec3d rest = corner_rest(s, I, J, K);
      best = from == kDeadIndex ? new_particle(s, rest, rest, Vec3d::Zero())
                                : new_particle(s, rest, s.position[from], s.velocity[from]);
    }
    claimed[claimed_count++] = best;
    for (int n = g; n < m.count; ++n) {
      if (m.find(n) == g) s.pieces[m.slot[n]].particles[m.corner[n]] = best;
    }
  }
}

// ---- Relabelling ---------------------------------------------------------------------------

// Gives simulation voxel sv the pieces of `labels` (count components): storage as one piece or as a
// divided voxel, new piece slots inheriting particles and rotation from the old piece that held the
// same fine node (old labels in `old`, old slots in `old_slots`; `old_count` 0: no pieces before).
// Old slots nobody inherits are freed.
void set_voxel_pieces(const VoxelModel& model, PbdState& s, uint32_t sv, const uint8_t* labels, uint8_t count,
                      const uint8_t* old, const uint32_t* old_slots, uint8_t old_count) {
  const uint32_t nodes = block_nodes(s);
  // Storage of the labels.
  uint32_t d = s.voxel_divided[sv];
  if (count > 1 && d == kDeadIndex) {
    d = uint32_t(s.divided.size());
    s.voxel_divided[sv] = d;
    s.divided.push_back({sv, uint32_t(s.labels.size()), uint32_t(s.label_slots.size()), 0});
    s.labels.resize(s.labels.size() + nodes, kNoPiece);
    s.label_slots.resize(s.label_slots.size() + kLabelSlots, kDeadIndex);
  }
  if (d != kDeadIndex) {
    std::copy(labels, labels + nodes, s.labels.begin() + s.divided[d].first_label);
    s.divided[d].piece_count = count;
  }
  s.pieces_in_voxel[sv] = count;
  // New pieces: the first label meeting an old piece reuses its slot.
  bool reused[256] = {};
  uint64_t eighths[256];
  label_eighths(model, s, sv, labels, eighths);
  // The old label at each new label's first node (one pass over the block).
  uint8_t inherit[256];
  bool seen[256] = {};
  for (uint32_t b = 0; b < nodes; ++b) {
    const uint8_t p = labels[b];
    if (p == kNoPiece || seen[p]) continue;
    seen[p] = true;
    inherit[p] = old_count ? old[b] : uint8_t(kNoPiece);
  }
  for (uint8_t p = 0; p < count; ++p) {
    const uint8_t was = seen[p] ? inherit[p] : uint8_t(kNoPiece);
    uint32_t slot;
    if (was != kNoPiece && was < old_count && !reused[was]) {
      slot = old_slots[was];
      reused[was] = true;
      s.pieces[slot].piece = p;
    } else {
      slot = new_piece(s, sv, p);
      if (was != kNoPiece && was < old_count) {
        std::copy(s.pieces[old_slots[was]].particles, s.pieces[old_slots[was]].particles + 8, s.pieces[slot].particles);
        s.rotation[slot] = s.rotation[old_slots[was]];
      }
    }
    s.pieces[slot].eighths = eighths[p];
    if (d != kDeadIndex) {
      s.label_slots[s.divided[d].first_slot + p] = slot;
    } else {
      s.voxel_piece[sv] = slot;
    }
  }
  for (uint8_t p = 0; p < old_count; ++p) {
    if (!reused[p]) free_piece(s, old_slots[p]);
  }
  if (count == 0) s.voxel_piece[sv] = kDeadIndex;
}

// ---- Embedding -----------------------------------------------------------------------------

// Embeds a live surface vertex slot: its fine piece's simulation voxel, one node of the fine piece,
// and its local position.
void embed_vertex(const VoxelModel& model, const CutState& cut, PbdState& s, uint32_t slot) {
  const CutSurface& surface = cut.surface;
  VertexEmbedding& e = s.embedding[slot];
  e.sim_voxel = kDeadIndex;
  const uint64_t key = surface.vertex_piece[slot];
  if (key == CutSurface::kFreeKey) return;
  const uint32_t voxel = uint32_t(key / 8);
  const uint8_t fine_piece = uint8_t(key % 8);
  int32_t vc[3];
  model.lattice.voxel_coords(voxel, vc);
  const int32_t svc[3] = {vc[0] / s.ratio, vc[1] / s.ratio, vc[2] / s.ratio};
  const uint32_t sv = sim_voxel_id(s, svc[0], svc[1], svc[2]);
  uint8_t corner_piece[8], count = 0;
  voxel_pieces(model, cut, voxel, corner_piece, count);
  for (int c = 0; c < 8; ++c) {
    if (corner_piece[c] != fine_piece) continue;
    const int32_t i = vc[0] + (c & 1), j = vc[1] + ((c >> 1) & 1), k = vc[2] + ((c >> 2) & 1);
    if (node_label(model, s, sv, svc, i, j, k) == kNoPiece) continue;
    e.sim_voxel = sv;
    e.node = block_index(s, i - svc[0] * s.ratio, j - svc[1] * s.ratio, k - svc[2] * s.ratio);
    const Vec3d local = (surface.positions[slot].cast<double>() - corner_rest(s, svc[0], svc[1], svc[2])) / s.sim_size;
    e.local = local.cast<float>();
    return;
  }
}

// The piece slot an embedding names (kDeadIndex: none).
uint32_t embedded_piece(const PbdModel& s, const VertexEmbedding& e) {
  if (e.sim_voxel == kDeadIndex || !has_pieces(s, e.sim_voxel)) return kDeadIndex;
  const uint32_t d = s.voxel_divided[e.sim_voxel];
  if (d == kDeadIndex) return s.voxel_piece[e.sim_voxel];
  const uint8_t label = s.labels[s.divided[d].first_label + e.node];
  return label == kNoPiece ? kDeadIndex : s.label_slots[s.divided[d].first_slot + label];
}

void grow_embedding(const CutState& cut, PbdState& s) {
  if (s.embedding.size() < cut.surface.positions.size()) {
    s.embedding.resize(cut.surface.positions.size(), VertexEmbedding{kDeadIndex, 0, Vec3f::Zero()});
    s.deformed.resize(cut.surface.positions.size(), Vec3f::Zero());
  }
}

// Runs f(i) for i in [0, count) through the task runner (chunks of `grain`).
template <typename F>
void parallel(const TaskRunner& tasks, uint32_t count, uint32_t grain, F&& f) {
  if (count == 0) return;
  if (tasks.parallel_for == nullptr) {
    for (uint32_t i = 0; i < count; ++i) f(i);
    return;
  }
  tasks.parallel_for(
      tasks.context, count, grain,
      [](uint32_t begin, uint32_t end, void* user) {
        F& fn = *static_cast<F*>(user);
        for (uint32_t i = begin; i < end; ++i) fn(i);
      },
      &f);
}

// Coarse corner id (I,J,K) packed for sorting.
uint64_t corner_id(const PbdModel& s, int32_t I, int32_t J, int32_t K) {
  return uint64_t(I) + uint64_t(s.sx + 1) * (uint64_t(J) + uint64_t(s.sy + 1) * uint64_t(K));
}

void corner_coords(const PbdModel& s, uint64_t id, int32_t& I, int32_t& J, int32_t& K) {
  I = int32_t(id % uint64_t(s.sx + 1));
  J = int32_t((id / uint64_t(s.sx + 1)) % uint64_t(s.sy + 1));
  K = int32_t(id / (uint64_t(s.sx + 1) * uint64_t(s.sy + 1)));
}

template <typename T>
void sorted_unique(std::vector<T>& v) {
  std::sort(v.begin(), v.end());
  v.erase(std::unique(v.begin(), v.end()), v.end());
}

// ---- Contact hook (sim/contact.h) ----------------------------------------------------------

// The deformed position of a live embedded vertex slot, its piece, and its trilinear weights.
uint32_t embedded_point(const PbdState& s, uint32_t slot, Vec3d& point, double weights[8]) {
  const VertexEmbedding& e = s.embedding[slot];
  const uint32_t piece = embedded_piece(s, e);
  if (piece == kDeadIndex) return kDeadIndex;
  const double u = e.local.x(), v = e.local.y(), w = e.local.z();
  point.setZero();
  for (int c = 0; c < 8; ++c) {
    weights[c] = ((c & 1) ? u : 1.0 - u) * (((c >> 1) & 1) ? v : 1.0 - v) * (((c >> 2) & 1) ? w : 1.0 - w);
    point += weights[c] * s.position[s.pieces[piece].particles[c]];
  }
  return piece;
}

// Gathers this step's contact points: the surface vertices that may reach a plane within the step,
// grouped by piece. A piece is skipped when even its lowest corner particle (every embedded point is a
// convex combination of the corners) stays out of reach.
void gather_plane_contacts(const CutState& cut, PbdState& s) {
  ContactSet& set = s.contacts;
  contacts_clear(set);
  const std::vector<ContactPlane>& planes = s.params.planes;
  if (planes.empty()) return;
  double speed = 0.0;
  for (size_t p = 0; p < s.position.size(); ++p) {
    if (s.inv_mass[p] > 0.0) speed = std::max(speed, s.velocity[p].norm());
  }
  const double dt = s.params.dt;
  const double reach = 2.0 * (speed * dt + s.params.gravity.norm() * dt * dt) + 2.0 * s.sim_size / s.ratio;
  const uint32_t plane_count = uint32_t(std::min<size_t>(planes.size(), 32));
  std::vector<uint32_t>& near = set.group_mask;  // per piece: bit k = may reach plane k
  near.assign(s.pieces.size(), 0);
  for (size_t i = 0; i < s.pieces.size(); ++i) {
    if (s.pieces[i].sim_voxel == kDeadIndex) continue;  // free slot
    bool moves = false;  // a piece pinned at every corner cannot be pushed
    for (uint32_t p : s.pieces[i].particles) moves = moves || s.inv_mass[p] > 0.0;
    for (uint32_t k = 0; moves && k < plane_count; ++k) {
      double lowest = 1e300;
      for (uint32_t p : s.pieces[i].particles) lowest = std::min(lowest, plane_distance(planes[k], s.position[p]));
      if (lowest < reach) near[i] |= 1u << k;
    }
  }
  const uint32_t count = uint32_t(std::min(s.embedding.size(), cut.surface.positions.size()));
  for (uint32_t slot = 0; slot < count; ++slot) {
    const uint32_t piece = embedded_piece(s, s.embedding[slot]);
    if (piece == kDeadIndex || near[piece] == 0) continue;
    const uint32_t* particles = s.pieces[piece].particles;
    double weights[8], mobility = 0.0;
    Vec3d point;
    embedded_point(s, slot, point, weights);
    for (int c = 0; c < 8; ++c) mobility += weights[c] * weights[c] * s.inv_mass[particles[c]];
    if (mobility == 0.0) continue;  // interpolates anchored particles only
    for (uint32_t k = 0; k < plane_count; ++k) {
      if (((near[piece] >> k) & 1u) && plane_distance(planes[k], point) < reach) {
        contacts_add(set, s.pieces[piece].colour, piece, plane_contact(planes[k], particles, weights));
      }
    }
  }
  contacts_finish(set);
}

// One pass over a contact set: batch by batch (the groups of a batch share no particle), the overflow
// batch serially; everything serially when there are few points.
void solve_contacts(PbdState& s, ContactSet& set, const TaskRunner& tasks) {
  static_assert(kContactOverflow == kOverflowColour, "one overflow batch for both contact sets");
  if (set.points.empty()) return;
  double* x = s.position[0].data();
  const double* previous = s.previous[0].data();
  const double* w = s.inv_mass.data();
  const TaskRunner serial{};
  for (uint32_t b = 0; b < contact_batches(set); ++b) {
    const uint32_t begin = set.batch_begin[b], end = set.batch_begin[b + 1];
    const bool run_serially = b == kOverflowColour || set.points.size() < 256;
    parallel(run_serially ? serial : tasks, end - begin, 16,
             [&](uint32_t g) { solve_contact_group(x, previous, w, set, begin + g); });
  }
}

// Marks the vertex slots a cut made or moved since the last step as fresh (allowance = infinity).
void refresh_allowances(const CutState& cut, PieceContacts& pc) {
  const size_t slots = cut.surface.positions.size();
  if (pc.seen.empty()) {  // the first step: the surface as built is not fresh
    pc.seen = cut.surface.positions;
    pc.allowance.assign(slots, 0.0f);
  }
  pc.allowance.resize(slots, 0.0f);
  pc.seen.resize(slots, Vec3f::Constant(std::numeric_limits<float>::quiet_NaN()));
  for (size_t v = 0; v < slots; ++v) {
    if (pc.seen[v] == cut.surface.positions[v]) continue;  // NaN never compares equal: new slots too
    pc.seen[v] = cut.surface.positions[v];
    pc.allowance[v] = std::numeric_limits<float>::infinity();
  }
}

// Gathers this step's piece-piece contacts (sim/contact.h): bodies, exposed pieces, their surface
// vertices with deformed normals, the nearest facing vertex of another body.
void collect_piece_contacts(const CutState& cut, PbdState& s) {
  PieceContacts& pc = s.piece_contacts;
  contacts_clear(pc.set);
  pc.exposed_pieces = 0;
  const uint32_t pieces = uint32_t(s.pieces.size()), particles = uint32_t(s.position.size());
  if (!s.params.piece_contact || pieces == 0) return;
  refresh_allowances(cut, pc);  // every step, so a cut is fresh when its sides first touch
  pc.corners.resize(size_t(pieces) * 8);
  pc.live.assign(pieces, 0);
  pc.lo.resize(pieces);
  pc.hi.resize(pieces);
  uint32_t first = kDeadIndex;
  for (uint32_t i = 0; i < pieces; ++i) {
    if (s.pieces[i].sim_voxel == kDeadIndex) continue;  // free slot
    pc.live[i] = 1;
    first = std::min(first, i);
    std::copy(s.pieces[i].particles, s.pieces[i].particles + 8, pc.corners.begin() + 8 * size_t(i));
    pc.lo[i] = pc.hi[i] = s.position[s.pieces[i].particles[0]];
    for (uint32_t p : s.pieces[i].particles) {
      pc.lo[i] = pc.lo[i].cwiseMin(s.position[p]);
      pc.hi[i] = pc.hi[i].cwiseMax(s.position[p]);
    }
  }
  find_bodies(pc.corners.data(), pc.live.data(), pieces, particles, pc.body, pc.scratch);
  if (first == kDeadIndex) return;
  bool several = false;
  for (uint32_t i = first + 1; i < pieces && !several; ++i) several = pc.live[i] && pc.body[i] != pc.body[first];
  if (!several) return;  // one body: nothing to collide with
  // Reach: two fine voxels (the two faces of a cut can sit a voxel apart at its rim), plus twice what
  // any particle moves in a step (capped at a simulation voxel).
  double speed = 0.0;
  for (uint32_t p = 0; p < particles; ++p) {
    if (s.inv_mass[p] > 0.0) speed = std::max(speed, s.velocity[p].norm());
  }
  const double fine = s.sim_size / s.ratio;
  const double reach = std::min(s.sim_size, 2.0 * fine + 2.0 * (speed + s.params.gravity.norm() * s.params.dt) * s.params.dt);
  pc.exposed_pieces = find_exposed_pieces(pc.lo.data(), pc.hi.data(), pc.live.data(), pc.body.data(), pieces, reach,
                                          pc.exposed, pc.scratch);
  if (pc.exposed_pieces == 0) return;
  // Surface vertices of exposed pieces, with their allowances (sim/contact.h): a vertex whose rest
  // position changed since the last step was made by a cut and is fresh.
  const uint32_t slots = uint32_t(std::min(s.embedding.size(), cut.surface.positions.size()));
  pc.points.clear();
  pc.point_of_slot.assign(slots, ~0u);
  for (uint32_t slot = 0; slot < slots; ++slot) {
    SurfacePoint sp;
    sp.allowance = pc.allowance[slot];
    sp.slot = slot;
    const uint32_t piece = embedded_point(s, slot, sp.position, sp.weights);
    if (piece == kDeadIndex || !pc.exposed[piece]) continue;
    std::copy(s.pieces[piece].particles, s.pieces[piece].particles + 8, sp.particles);
    sp.body = pc.body[piece];
    sp.normal.setZero();
    pc.point_of_slot[slot] = uint32_t(pc.points.size());
    pc.points.push_back(sp);
  }
  // Their deformed normals: area-weighted sums over the live triangles using them.
  const CutSurface& surface = cut.surface;
  for (uint32_t t = 0; t < surface.triangles.size(); ++t) {
    if (surface.quad_half_edge[t / 2] == CutSurface::kFreeKey) continue;
    const Tri& tri = surface.triangles[t];
    if (tri[0] >= slots || tri[1] >= slots || tri[2] >= slots) continue;
    if (pc.point_of_slot[tri[0]] == ~0u && pc.point_of_slot[tri[1]] == ~0u && pc.point_of_slot[tri[2]] == ~0u) continue;
    Vec3d corner[3];
    double unused[8];
    bool ok = true;
    for (int k = 0; k < 3; ++k) {
      const uint32_t i = pc.point_of_slot[tri[k]];
      if (i != ~0u) {
        corner[k] = pc.points[i].position;
      } else {
        ok = ok && embedded_point(s, tri[k], corner[k], unused) != kDeadIndex;
      }
    }
    if (!ok) continue;
    const Vec3d n = (corner[1] - corner[0]).cross(corner[2] - corner[0]);
    for (int k = 0; k < 3; ++k) {
      if (pc.point_of_slot[tri[k]] != ~0u) pc.points[pc.point_of_slot[tri[k]]].normal += n;
    }
  }
  uint32_t kept = 0;
  for (const SurfacePoint& sp : pc.points) {
    const double length = sp.normal.norm();
    if (!(length > 0.0)) continue;
    pc.points[kept] = sp;
    pc.points[kept++].normal /= length;
  }
  pc.points.resize(kept);
  gather_piece_contacts(pc.points.data(), kept, s.position[0].data(), particles, reach, s.params.piece_friction,
                        pc.set, pc.scratch);
  contacts_finish(pc.set);
  for (uint32_t slot = 0; slot < slots; ++slot) {
    if (pc.point_of_slot[slot] != ~0u) pc.allowance[slot] = 0.0f;  // dropped below (no normal): none
  }
  for (const SurfacePoint& sp : pc.points) pc.allowance[sp.slot] = sp.allowance;
}

// The particles' frictionless backstop one simulation voxel below the planes.
void plane_backstop(PbdState& s, uint32_t p) {
  if (!s.params.planes.empty()) {
    project_particles_to_planes(s.position[0].data(), s.inv_mass.data(), p, p + 1, s.params.planes.data(),
                                uint32_t(s.params.planes.size()), s.sim_size);
  }
}

}  // namespace

// ---- Public API ----------------------------------------------------------------------------

bool init_pbd(const VoxelModel& model, const CutState& cut, const PbdParams& params, PbdState& s, std::string& error) {
  if (params.sim_resolution < 1 || params.resolution < params.sim_resolution ||
      params.resolution % params.sim_resolution != 0 ||
      ((params.resolution / params.sim_resolution) & (params.resolution / params.sim_resolution - 1)) != 0) {
    error = "resolution / sim_resolution must be a power of two (" + std::to_string(params.resolution) + " / " +
            std::to_string(params.sim_resolution) + ")";
    return false;
  }
  s = PbdState{};
  s.params = params;
  const Lattice& l = model.lattice;
  s.ratio = params.resolution / params.sim_resolution;
  s.sx = (l.nx + s.ratio - 1) / s.ratio;
  s.sy = (l.ny + s.ratio - 1) / s.ratio;
  s.sz = (l.nz + s.ratio - 1) / s.ratio;
  s.sim_size = l.voxel_size * s.ratio;
  s.fine_size = l.voxel_size;
  s.origin = l.origin;
  const uint32_t voxels = uint32_t(s.sx) * uint32_t(s.sy) * uint32_t(s.sz);
  s.voxel_piece.assign(voxels, kDeadIndex);
  s.voxel_divided.assign(voxels, kDeadIndex);
  s.pieces_in_voxel.assign(voxels, 0);

  // Pieces: the material components of every block (cuts made before init included).
  s.scratch_labels.resize(block_nodes(s));
  for (uint32_t sv = 0; sv < voxels; ++sv) {
    const uint8_t count = label_block(model, cut, s, sv, s.scratch_parent, s.scratch_labels.data());
    if (count > 0) set_voxel_pieces(model, s, sv, s.scratch_labels.data(), count, nullptr, nullptr, 0);
  }
  // Particles: one per material group at every coarse corner.
  CornerMembers members;
  for (int32_t K = 0; K <= s.sz; ++K) {
    for (int32_t J = 0; J <= s.sy; ++J) {
      for (int32_t I = 0; I <= s.sx; ++I) assign_corner(model, s, I, J, K, members);
    }
  }
  // Constraints, colours and masses.
  for (uint32_t slot = 0; slot < s.pieces.size(); ++slot) {
    if (s.pieces[slot].sim_voxel != kDeadIndex) attach_piece(s, slot);
  }
  for (uint32_t p = 0; p < s.rest.size(); ++p) update_mass(s, p);
  // The embedding of every live vertex.
  grow_embedding(cut, s);
  for (uint32_t slot = 0; slot < cut.surface.positions.size(); ++slot) embed_vertex(model, cut, s, slot);
  pbd_embed(cut, s);
  return true;
}

uint32_t pbd_apply_cut(const VoxelModel& model, const CutState& cut, PbdState& s) {
  // Simulation voxels holding changed fine voxels.
  std::vector<uint32_t>& affected = s.scratch_sim;
  affected.clear();
  for (uint32_t voxel : cut.changed_voxels) {
    if (cut.divided_of.get(voxel) == kDeadIndex) continue;
    int32_t vc[3];
    model.lattice.voxel_coords(voxel, vc);
    const uint32_t sv = sim_voxel_id(s, vc[0] / s.ratio, vc[1] / s.ratio, vc[2] / s.ratio);
    if (has_pieces(s, sv)) affected.push_back(sv);
  }
  sorted_unique(affected);

  if (!affected.empty()) {
    // The voxels whose pieces may change particles: the affected ones and their neighbours.
    std::vector<uint32_t>& near = s.scratch_near;
    near.clear();
    for (uint32_t sv : affected) {
      int32_t c[3];
      sim_voxel_coords(s, sv, c);
      for (int32_t dz = -1; dz <= 1; ++dz) {
        for (int32_t dy = -1; dy <= 1; ++dy) {
          for (int32_t dx = -1; dx <= 1; ++dx) {
            if (!sim_in_range(s, c[0] + dx, c[1] + dy, c[2] + dz)) continue;
            const uint32_t n = sim_voxel_id(s, c[0] + dx, c[1] + dy, c[2] + dz);
            if (has_pieces(s, n)) near.push_back(n);
          }
        }
      }
    }
    sorted_unique(near);
    // Detach their pieces (remembering the particles they used).
    std::vector<uint64_t>& touched = s.scratch_corners;
    touched.clear();
    for (uint32_t sv : near) {
      for_pieces(s, sv, [&](uint32_t slot) {
        for (uint32_t p : s.pieces[slot].particles) touched.push_back(p);
        detach_piece(s, slot);
      });
    }
    // Relabel the affected voxels.
    const uint32_t nodes = block_nodes(s);
    s.scratch_labels.resize(2 * size_t(nodes));
    s.scratch_old_slots.resize(kLabelSlots);
    for (uint32_t sv : affected) {
      uint8_t* old = s.scratch_labels.data() + nodes;
      const uint32_t d = s.voxel_divided[sv];
      const uint8_t old_count = s.pieces_in_voxel[sv];
      if (d != kDeadIndex) {
        std::copy(s.labels.begin() + s.divided[d].first_label, s.labels.begin() + s.divided[d].first_label + nodes, old);
        std::copy(s.label_slots.begin() + s.divided[d].first_slot,
                  s.label_slots.begin() + s.divided[d].first_slot + kLabelSlots, s.scratch_old_slots.begin());
      } else {
        int32_t c[3];
        sim_voxel_coords(s, sv, c);
        for (int32_t z = 0; z <= s.ratio; ++z) {
          for (int32_t y = 0; y <= s.ratio; ++y) {
            for (int32_t x = 0; x <= s.ratio; ++x) {
              old[block_index(s, x, y, z)] =
                  fine_inside(model, c[0] * s.ratio + x, c[1] * s.ratio + y, c[2] * s.ratio + z) ? 0 : kNoPiece;
            }
          }
        }
        s.scratch_old_slots[0] = s.voxel_piece[sv];
      }
      const uint8_t count = label_block(model, cut, s, sv, s.scratch_parent, s.scratch_labels.data());
      set_voxel_pieces(model, s, sv, s.scratch_labels.data(), count, old, s.scratch_old_slots.data(), old_count);
    }
    // Corner particles of the affected voxels.
    std::vector<uint64_t> corners;
    corners.reserve(affected.size() * 8);
    for (uint32_t sv : affected) {
      int32_t c[3];
      sim_voxel_coords(s, sv, c);
      for (int q = 0; q < 8; ++q) corners.push_back(corner_id(s, c[0] + (q & 1), c[1] + ((q >> 1) & 1), c[2] + ((q >> 2) & 1)));
    }
    sorted_unique(corners);
    CornerMembers members;
    for (uint64_t id : corners) {
      int32_t I, J, K;
      corner_coords(s, id, I, J, K);
      assign_corner(model, s, I, J, K, members);
    }
    // Re-attach; masses of every particle involved; unused particles go to the free list.
    for (uint32_t sv : near) {
      for_pieces(s, sv, [&](uint32_t slot) {
        attach_piece(s, slot);
        for (uint32_t p : s.pieces[slot].particles) touched.push_back(p);
      });
    }
    sorted_unique(touched);
    for (uint64_t p : touched) {
      update_mass(s, uint32_t(p));
      if (s.refs[p] == 0) {
        s.mass[p] = s.inv_mass[p] = 0.0;
        s.free_particles.push_back(uint32_t(p));
      }
    }
  }

  // Re-embed the changed vertex slots (vertices of relabelled voxels follow their node's label).
  grow_embedding(cut, s);
  for (uint32_t slot : cut.changed_vertices) {
    if (slot < s.embedding.size()) embed_vertex(model, cut, s, slot);
  }
  return uint32_t(affected.size());
}

void pbd_embed(const CutState& cut, PbdState& s, const TaskRunner& tasks) {
  const uint32_t count = uint32_t(std::min(s.embedding.size(), cut.surface.positions.size()));
  parallel(tasks, count, 4096, [&](uint32_t slot) {
    const VertexEmbedding& e = s.embedding[slot];
    const uint32_t piece = embedded_piece(s, e);
    if (piece == kDeadIndex) {
      s.deformed[slot] = cut.surface.positions[slot];
      return;
    }
    const uint32_t* particles = s.pieces[piece].particles;
    const double u = e.local.x(), v = e.local.y(), w = e.local.z();
    Vec3d p = Vec3d::Zero();
    for (int c = 0; c < 8; ++c) {
      const double weight = ((c & 1) ? u : 1.0 - u) * (((c >> 1) & 1) ? v : 1.0 - v) * (((c >> 2) & 1) ? w : 1.0 - w);
      p += weight * s.position[particles[c]];
    }
    s.deformed[slot] = p.cast<float>();
  });
}

void pbd_step(const CutState& cut, PbdState& s, const TaskRunner& tasks) {
  const PbdParams& params = s.params;
  const int substeps = std::max(1, params.substeps);
  const double h = params.dt / substeps;
  const uint32_t n = uint32_t(s.position.size());
  double* x = s.position.empty() ? nullptr : s.position[0].data();
  const double* w = s.inv_mass.data();
  // One constraint of each kind (the loops below run them colour by colour; overflow serially).
  const auto stretch = [&](uint8_t c, uint32_t i) {
    const StretchConstraint& k = s.stretch_groups[c][i];
    solve_distance(x, w, k.a, k.b, k.rest, params.stretch_compliance, h, s.stretch_lambda[c][i]);
  };
  const auto shape = [&](uint8_t c, uint32_t i) {
    const uint32_t slot = s.piece_groups[c][i];
    const uint32_t* particles = s.pieces[slot].particles;
    double rest[24];
    for (int k = 0; k < 8; ++k) {
      for (int a = 0; a < 3; ++a) rest[3 * k + a] = s.rest[particles[k]][a];
    }
    solve_shape_matching(x, w, particles, rest, 8, params.shape_stiffness, s.rotation[slot]);
  };
  gather_plane_contacts(cut, s);  // contact (sim/contact.h)
  collect_piece_contacts(cut, s);
  for (int sub = 0; sub < substeps; ++sub) {
    // Predict.
    parallel(tasks, n, 4096, [&](uint32_t p) {
      s.previous[p] = s.position[p];
      if (s.inv_mass[p] == 0.0) {
        s.velocity[p].setZero();
        return;
      }
      s.velocity[p] += h * params.gravity;
      s.position[p] += h * s.velocity[p];
    });
    for (std::vector<double>& lambda : s.stretch_lambda) std::fill(lambda.begin(), lambda.end(), 0.0);
    contacts_begin_substep(s.contacts);
    contacts_begin_substep(s.piece_contacts.set);
    double grab_lambda[3] = {0, 0, 0};
    for (int it = 0; it < params.iterations; ++it) {
      // Stretching, colour by colour; the overflow colour serially.
      for (uint8_t c = 0; c < kOverflowColour; ++c) {
        parallel(tasks, uint32_t(s.stretch_groups[c].size()), 2048, [&](uint32_t i) { stretch(c, i); });
      }
      for (uint32_t i = 0; i < s.stretch_groups[kOverflowColour].size(); ++i) stretch(kOverflowColour, i);
      // Shape matching, the same way.
      for (uint8_t c = 0; c < kOverflowColour; ++c) {
        parallel(tasks, uint32_t(s.piece_groups[c].size()), 256, [&](uint32_t i) { shape(c, i); });
      }
      for (uint32_t i = 0; i < s.piece_groups[kOverflowColour].size(); ++i) shape(kOverflowColour, i);
      // Grab: a compliant attachment of one particle to its target (XPBD, per axis).
      if (s.grab_particle < n && s.inv_mass[s.grab_particle] > 0.0) {
        const double alpha = s.grab_compliance / (h * h);
        for (int a = 0; a < 3; ++a) {
          const double constraint = s.position[s.grab_particle][a] - s.grab_target[a];
          const double dl = (-constraint - alpha * grab_lambda[a]) / (s.inv_mass[s.grab_particle] + alpha);
          grab_lambda[a] += dl;
          s.position[s.grab_particle][a] += s.inv_mass[s.grab_particle] * dl;
        }
      }
      // Contact between pieces, then with the static planes, last so each iteration ends with the
      // surface above them.
      solve_contacts(s, s.piece_contacts.set, tasks);
      solve_contacts(s, s.contacts, tasks);
    }
    // Velocities from the positional change, with damping.
    const double keep = 1.0 - params.damping;
    parallel(tasks, n, 4096, [&](uint32_t p) {
      if (s.inv_mass[p] == 0.0) return;
      plane_backstop(s, p);
      s.velocity[p] = (s.position[p] - s.previous[p]) * (keep / h);
    });
  }
  ++s.steps;
  pbd_embed(cut, s, tasks);
}

uint32_t piece_slot(const PbdState& s, uint32_t sv, uint8_t label) { return slot_of_label(s, sv, label); }

uint32_t piece_at_rest(const VoxelModel& model, const PbdState& s, const Vec3d& rest) {
  const Vec3d g = (rest - s.origin) / s.sim_size;
  if (!g.allFinite()) return kDeadIndex;
  const int32_t c[3] = {int32_t(std::floor(g.x())), int32_t(std::floor(g.y())), int32_t(std::floor(g.z()))};
  if (!sim_in_range(s, c[0], c[1], c[2])) return kDeadIndex;
  const uint32_t sv = sim_voxel_id(s, c[0], c[1], c[2]);
  if (!has_pieces(s, sv)) return kDeadIndex;
  // The nearest fine node, kept in the block.
  const Vec3d f = (rest - s.origin) / s.fine_size;
  int32_t node[3];
  for (int a = 0; a < 3; ++a) {
    node[a] = std::clamp(int32_t(std::lround(f[a])), c[a] * s.ratio, c[a] * s.ratio + s.ratio);
  }
  (void)model;
  return slot_of_label(s, sv, node_label(model, s, sv, c, node[0], node[1], node[2]));
}

bool piece_holds(const VoxelModel& model, const PbdState& s, uint32_t piece, const Vec3d& u) {
  const SimPiece& p = s.pieces[piece];
  if (p.sim_voxel == kDeadIndex || !u.allFinite()) return false;
  int32_t c[3], node[3];
  sim_voxel_coords(s, p.sim_voxel, c);
  for (int a = 0; a < 3; ++a) {
    node[a] = c[a] * s.ratio + int32_t(std::lround(std::clamp(u[a], 0.0, 1.0) * s.ratio));
  }
  return node_label(model, s, p.sim_voxel, c, node[0], node[1], node[2]) == p.piece;
}

Vec3d piece_rest_origin(const PbdState& s, uint32_t piece) {
  int32_t c[3];
  sim_voxel_coords(s, s.pieces[piece].sim_voxel, c);
  return corner_rest(s, c[0], c[1], c[2]);
}

void piece_corners(const PbdState& s, uint32_t piece, Vec3d corners[8]) {
  for (int c = 0; c < 8; ++c) corners[c] = s.position[s.pieces[piece].particles[c]];
}

void grab_begin(PbdState& s, const Vec3d& point, double compliance) {
  double best = std::numeric_limits<double>::infinity();
  s.grab_particle = ~0u;
  for (uint32_t p = 0; p < s.position.size(); ++p) {
    if (s.refs[p] == 0) continue;
    const double d = (s.position[p] - point).squaredNorm();
    if (d < best) {
      best = d;
      s.grab_particle = p;
    }
  }
  s.grab_target = point;
  s.grab_compliance = compliance;
}

void grab_move(PbdState& s, const Vec3d& target) { s.grab_target = target; }
void grab_end(PbdState& s) { s.grab_particle = ~0u; }

double total_mass(const PbdState& s) {
  uint64_t eighths = 0;
  for (size_t p = 0; p < s.mass_eighths.size(); ++p) eighths += s.refs[p] ? s.mass_eighths[p] : 0;
  const double h = s.fine_size;
  return s.params.density * (double(eighths) * (h * h * h / 64.0));
}

double kinetic_energy(const PbdState& s) {
  double e = 0.0;
  for (size_t p = 0; p < s.position.size(); ++p) {
    if (s.inv_mass[p] > 0.0) e += 0.5 * s.mass[p] * s.velocity[p].squaredNorm();
  }
  return e;
}

uint64_t count_nonfinite(const PbdState& s) {
  uint64_t bad = 0;
  for (size_t p = 0; p < s.position.size(); ++p) {
    if (s.refs[p] == 0) continue;
    bad += !s.position[p].allFinite() + !s.velocity[p].allFinite();
  }
  for (size_t v = 0; v < s.embedding.size(); ++v) {
    if (s.embedding[v].sim_voxel != kDeadIndex && !s.deformed[v].allFinite()) ++bad;
  }
  return bad;
}

uint32_t sim_voxels_divided(const PbdState& s) { return uint32_t(s.divided.size()); }
uint32_t live_pieces(const PbdState& s) { return uint32_t(s.pieces.size() - s.free_pieces.size()); }
uint32_t live_particles(const PbdState& s) { return uint32_t(s.rest.size() - s.free_particles.size()); }

uint32_t stretch_count(const PbdState& s) {
  size_t n = 0;
  for (const auto& group : s.stretch_groups) n += group.size();
  return uint32_t(n);
}

uint32_t overflow_constraints(const PbdState& s) {
  return uint32_t(s.stretch_groups[kOverflowColour].size() + s.piece_groups[kOverflowColour].size());
}

// ---- Consistency check ---------------------------------------------------------------------

namespace {

bool fail(std::string& error, const std::string& what) {
  error = what;
  return false;
}

// Pieces of every simulation voxel = material components of its block, recomputed from scratch.
bool check_pieces(const VoxelModel& model, const CutState& cut, const PbdState& s, std::string& error) {
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
bool check_corners(const VoxelModel& model, const PbdState& s, std::string& error) {
  CornerMembers m;
  for (int32_t K = 0; K <= s.sz; ++K) {
    for (int32_t J = 0; J <= s.sy; ++J) {
      for (int32_t I = 0; I <= s.sx; ++I) {
        corner_groups(model, s, I, J, K, m);
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
bool check_particles(const PbdState& s, std::string& error) {
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
    if (!s.position[p].allFinite()) return fail(error, where + ": position is not finite");
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
bool check_constraints(const PbdState& s, std::string& error) {
  FlatMap expected;
  for (const SimPiece& piece : s.pieces) {
    if (piece.sim_voxel == kDeadIndex) continue;
    for (const auto& e : kCubeEdges) {
      const uint64_t key = pair_key(std::min(piece.particles[e[0]], piece.particles[e[1]]),
                                    std::max(piece.particles[e[0]], piece.particles[e[1]]));
      expected.set(key, expected.get(key, 0) + 1);
    }
  }
  const size_t n = s.rest.size();
  std::vector<uint64_t> stretch_busy(n, 0), shape_busy(n, 0);
  uint32_t count = 0;
  for (int c = 0; c < kColourGroups; ++c) {
    if (s.stretch_lambda[c].size() != s.stretch_groups[c].size()) return fail(error, "lambdas out of step with constraints");
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

bool check_pbd_state(const VoxelModel& model, const CutState& cut, const PbdState& s, std::string& error) {
  if (!check_pieces(model, cut, s, error) || !check_corners(model, s, error) || !check_particles(s, error) ||
      !check_constraints(s, error)) {
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
