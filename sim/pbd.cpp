#include "sim/pbd.h"
#include "sim/id_pool.h"

#include "sim/pbd_internal.h"
#include "sim/pbd_kernels.h"
#include "sim/union_find.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>

namespace dvx {
using namespace pbd_internal;
namespace {

constexpr uint8_t kMaxSimPieces = 250;  // labels are uint8; more components than this merge into the last
constexpr uint32_t kLabelSlots = 256;   // piece slots per divided simulation voxel


// ---- Fine lattice access -------------------------------------------------------------------

bool fine_inside(const VoxelModel& model, int32_t i, int32_t j, int32_t k) {
  const Lattice& l = model.lattice;
  if (i < 0 || j < 0 || k < 0 || i > l.nx || j > l.ny || k > l.nz) return false;
  return model.is_inside(l.node(i, j, k));
}

// ---- Simulation grid -----------------------------------------------------------------------


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
  const auto find = [&](uint32_t x) { return uf_find(parent.data(), x); };
  for (int32_t z = 0; z < r && c[2] * r + z < l.nz; ++z) {
    for (int32_t y = 0; y < r && c[1] * r + y < l.ny; ++y) {
      for (int32_t x = 0; x < r && c[0] * r + x < l.nx; ++x) {
        const int32_t i = c[0] * r + x, j = c[1] * r + y, k = c[2] * r + z;
        const uint32_t voxel = l.voxel(i, j, k);
        // Inside corners; an uncut voxel is one piece of all of them (voxel_pieces' rule, without the call).
        uint8_t corner_piece[8], pieces = 0, inside = 0;
        for (int q = 0; q < 8; ++q) {
          inside |= uint8_t(model.is_inside(l.node(i + (q & 1), j + ((q >> 1) & 1), k + ((q >> 2) & 1))) << q);
        }
        if (inside == 0) continue;
        if (cut.divided_of.get(voxel) == kDeadIndex) {
          for (int q = 0; q < 8; ++q) corner_piece[q] = (inside >> q) & 1 ? 0 : kNoPiece;
        } else {
          voxel_pieces(model, cut, voxel, corner_piece, pieces);
        }
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
  if (!take_free_slot(s.free_particles, p)) {
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
  if (!take_free_slot(s.free_pieces, slot)) {
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
  std::fill(piece.octants, piece.octants + 8, 0u);
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
  if (!take_free_slot(s.free_stretch_handles, handle)) {
    handle = uint32_t(s.stretch_handles.size());
    s.stretch_handles.emplace_back();
  }
  const uint32_t ends[2] = {a, b};
  const uint8_t colour = take_colour(s.stretch_busy.data(), ends, 2);
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
  const uint32_t ends[2] = {a, b};
  release_colour(s.stretch_busy.data(), ends, 2, h.colour);
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
  for (uint32_t p : piece.particles) {
    ++s.refs[p];
    s.mass_eighths[p] += piece.eighths;
  }
  for (const VoxelEdge& e : kVoxelEdges) add_stretch(s, piece.particles[e.c0], piece.particles[e.c1]);
  piece.colour = take_colour(s.shape_busy.data(), piece.particles, 8);
  piece.colour_slot = uint32_t(s.piece_groups[piece.colour].size());
  s.piece_groups[piece.colour].push_back(slot);
}

// The reverse of attach_piece.
void detach_piece(PbdState& s, uint32_t slot) {
  SimPiece& piece = s.pieces[slot];
  for (uint32_t p : piece.particles) {
    --s.refs[p];
    s.mass_eighths[p] -= piece.eighths;
  }
  release_colour(s.shape_busy.data(), piece.particles, 8, piece.colour);
  for (const VoxelEdge& e : kVoxelEdges) remove_stretch(s, piece.particles[e.c0], piece.particles[e.c1]);
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

// Material of each octant of the pieces of simulation voxel sv (SimPiece::octants), from their labels:
// each inside node's eighths (one per block voxel around it, as label_eighths counts them) go to the
// octant holding the point halfway between the node and that voxel's centre (for ratio 1, the node's
// own corner octant). The octants of a piece sum to its eighths.
void piece_octants(const VoxelModel& model, PbdState& s, uint32_t sv) {
  for_pieces(s, sv, [&](uint32_t slot) { std::fill(s.pieces[slot].octants, s.pieces[slot].octants + 8, 0u); });
  int32_t c[3];
  sim_voxel_coords(s, sv, c);
  const Lattice& l = model.lattice;
  const int32_t r = s.ratio, n[3] = {l.nx, l.ny, l.nz};
  for (int32_t z = 0; z <= r; ++z) {
    for (int32_t y = 0; y <= r; ++y) {
      for (int32_t x = 0; x <= r; ++x) {
        const int32_t node[3] = {x, y, z};
        const uint8_t label = label_at(model, s, sv, c, block_index(s, x, y, z), c[0] * r + x, c[1] * r + y, c[2] * r + z);
        const uint32_t slot = slot_of_label(s, sv, label);
        if (slot == kDeadIndex) continue;
        for (int q = 0; q < 8; ++q) {
          int octant = 0;
          bool inside = true;
          for (int e = 0; e < 3 && inside; ++e) {
            const int up = (q >> e) & 1;  // the voxel above the node along e, else below
            const int32_t v = node[e] - 1 + up;
            inside = v >= 0 && v < r && c[e] * r + v < n[e];
            if (4 * node[e] + (up ? 1 : -1) >= 2 * r) octant |= 1 << e;
          }
          if (inside) ++s.pieces[slot].octants[octant];
        }
      }
    }
  }
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
  int find(int x) { return uf_find(parent, x); }
};

// Label pairs (a in simulation voxel lo, b in its neighbour hi along `axis`) that share a fine node on
// their common face, cached per face for the cut step (each face serves its 4 corners).
const uint16_t* face_pairs(const VoxelModel& model, const PbdModel& s, uint32_t lo, const int32_t loc[3], int axis,
                           uint32_t hi, const int32_t hic[3], FaceCache& cache, uint32_t& count) {
  const uint64_t key = uint64_t(lo) * 3 + uint64_t(axis);
  uint32_t at = cache.offset.get(key);
  if (at == kDeadIndex) {
    at = uint32_t(cache.data.size());
    cache.offset.set(key, at);
    cache.data.push_back(0);
    const int u_axis = (axis + 1) % 3, v_axis = (axis + 2) % 3;
    // The face's nodes in both blocks' label arrays (the face is x = ratio in lo, x = 0 in hi along
    // `axis`); an undivided block's label is 0 at an inside node (the node is the same in both).
    const uint32_t dl = s.voxel_divided[lo], dh = s.voxel_divided[hi];
    const uint8_t* lo_labels = dl == kDeadIndex ? nullptr : s.labels.data() + s.divided[dl].first_label;
    const uint8_t* hi_labels = dh == kDeadIndex ? nullptr : s.labels.data() + s.divided[dh].first_label;
    const uint32_t n = uint32_t(s.ratio + 1), stride[3] = {1, n, n * n};
    const uint32_t su = stride[u_axis], sv = stride[v_axis];
    const uint32_t lo_base = uint32_t(s.ratio) * stride[axis];
    const auto add = [&](uint16_t pair) {
      if (std::find(cache.data.begin() + at + 1, cache.data.end(), pair) != cache.data.end()) return;
      cache.data.push_back(pair);
      ++cache.data[at];
    };
    if (lo_labels && hi_labels) {
      const bool single = s.pieces_in_voxel[lo] == 1 && s.pieces_in_voxel[hi] == 1;  // one possible pair
      uint16_t last = 0xFFFF;  // no pair: labels are below kNoPiece
      for (uint32_t v = 0; v < n && !(single && last != 0xFFFF); ++v) {
        const uint8_t* a_row = lo_labels + lo_base + v * sv;
        const uint8_t* b_row = hi_labels + v * sv;
        for (uint32_t u = 0; u < n; ++u) {
          const uint8_t a = a_row[u * su], b = b_row[u * su];
          if (a == kNoPiece || b == kNoPiece) continue;
          const uint16_t pair = uint16_t(a << 8 | b);
          if (pair == last) continue;  // neighbouring nodes mostly repeat the last pair
          last = pair;
          add(pair);
        }
      }
    } else if (lo_labels || hi_labels) {
      // One side keeps labels: the node is inside exactly where its label is a piece, and the other
      // side's one piece (label 0) holds it too, so the pairs are that side's labels on the face
      // (until all its labels are seen).
      const uint8_t* labels = lo_labels ? lo_labels + lo_base : hi_labels;
      const uint32_t all = s.pieces_in_voxel[lo_labels ? lo : hi];
      uint64_t seen[4] = {};
      uint32_t found = 0;
      for (uint32_t v = 0; v < n && found < all; ++v) {
        const uint8_t* row = labels + v * sv;
        for (uint32_t u = 0; u < n; ++u) {
          const uint8_t p = row[u * su];
          if (p == kNoPiece || (seen[p >> 6] >> (p & 63)) & 1u) continue;
          seen[p >> 6] |= uint64_t(1) << (p & 63);
          ++found;
          add(lo_labels ? uint16_t(p << 8) : uint16_t(p));
        }
      }
    } else {
      // Neither keeps labels: each has one piece, joined when any face node is inside.
      int32_t node[3];
      node[axis] = hic[axis] * s.ratio;
      for (int32_t v = 0; v <= s.ratio; ++v) {
        for (int32_t u = 0; u <= s.ratio; ++u) {
          node[u_axis] = loc[u_axis] * s.ratio + u;
          node[v_axis] = loc[v_axis] * s.ratio + v;
          if (!fine_inside(model, node[0], node[1], node[2])) continue;
          add(0);
          v = s.ratio + 1;  // the one possible pair, found
          break;
        }
      }
    }
  }
  count = cache.data[at];
  return cache.data.data() + at + 1;
}

// Fills the members around corner (I,J,K) and unites those joined by a fine node on their common
// boundary: the 12 faces between the (up to) 8 simulation voxels around the corner.
void corner_groups(const VoxelModel& model, const PbdModel& s, int32_t I, int32_t J, int32_t K, CornerMembers& m,
                   FaceCache& cache) {
  m.count = 0;
  uint32_t voxels[8];
  int32_t vcs[8][3];
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
    }
  }
  for (int axis = 0; axis < 3; ++axis) {
    for (int q = 0; q < 8; ++q) {
      const int upper = q | (1 << axis);
      if ((q >> axis) & 1 || voxels[q] == kDeadIndex || voxels[upper] == kDeadIndex) continue;
      uint32_t count = 0;
      const uint16_t* pairs = face_pairs(model, s, voxels[q], vcs[q], axis, voxels[upper], vcs[upper], cache, count);
      for (uint32_t i = 0; i < count; ++i) {
        const int a = m.find(m.base[q] + (pairs[i] >> 8)), b = m.find(m.base[upper] + (pairs[i] & 0xFF));
        if (a != b) m.parent[std::max(a, b)] = std::min(a, b);
      }
    }
  }
}

// Assigns particles at coarse corner (I,J,K): one per material group of the pieces around it.
// Existing particles are kept where possible (the smallest not yet claimed by another group).
void assign_corner(const VoxelModel& model, PbdState& s, int32_t I, int32_t J, int32_t K, CornerMembers& m) {
  corner_groups(model, s, I, J, K, m, s.scratch.face_cache);
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

// The face pairs of a face follow from the labels of its two simulation voxels alone, so the cache
// outlives a cut step: only the 6 faces of each relabelled voxel are forgotten. Their old pairs stay
// in the data until it is cleared whole (rarely: it grows by the faces a step recomputes).
void forget_faces(PbdModel& s, const std::vector<uint32_t>& relabelled) {
  FaceCache& cache = s.scratch.face_cache;
  if (cache.data.size() > (size_t(1) << 16)) {
    cache.clear();
    return;
  }
  const uint32_t stride[3] = {1, uint32_t(s.sx), uint32_t(s.sx) * uint32_t(s.sy)};
  for (uint32_t sv : relabelled) {
    int32_t c[3];
    sim_voxel_coords(s, sv, c);
    for (int axis = 0; axis < 3; ++axis) {
      cache.offset.erase(uint64_t(sv) * 3 + uint64_t(axis));  // the face above sv
      if (c[axis] > 0) cache.offset.erase(uint64_t(sv - stride[axis]) * 3 + uint64_t(axis));  // below
    }
  }
}

// ---- Relabelling ---------------------------------------------------------------------------

// Gives the count labels of simulation voxel sv their piece slots: the first label whose first node
// held old label inherit[p] reuses that label's slot (old_slots), the others get new slots starting
// from its particles and rotation; old slots nobody inherits are freed. eighths: each label's volume.
void assign_slots(PbdState& s, uint32_t sv, uint8_t count, const uint64_t* eighths, const uint8_t* inherit,
                  const uint32_t* old_slots, uint8_t old_count) {
  const uint32_t d = s.voxel_divided[sv];
  if (d != kDeadIndex) s.divided[d].piece_count = count;
  s.pieces_in_voxel[sv] = count;
  bool reused[256] = {};
  for (uint8_t p = 0; p < count; ++p) {
    const uint8_t was = inherit[p];
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
  if (count == 0 || d != kDeadIndex) s.voxel_piece[sv] = kDeadIndex;
}

// Per-simulation-voxel block arrays (labels, label slots, cut records) hold their blocks up to a
// count in use (the divided voxels' or cut records' blocks); beyond it, up to the array's size, lies
// a warm reserve of elements set to the array's fill value (never written since), their pages touched. A cut step that starts blocks takes them from
// the reserve: a page's first touch is a fault (~20 us on the virtual machine measured, and 120 of
// them, 5 label blocks and 5 cut records at 512, were most of the heaviest cut step's time). init_pbd
// fills the reserve (kWarmBlocks blocks, at most kWarmBytes per array) and each cut step tops it up by
// at most kRefillBytes per array, so touching pages never lands on one step.
constexpr size_t kWarmBlocks = 128, kWarmBytes = size_t(8) << 20, kRefillBytes = size_t(4) << 10;

// Address space for a block of `count` elements per simulation voxel (up to 64 MiB; pages are
// touched only by the warm reserve), so growing never copies the array in a cut step.
template <typename T>
void reserve_blocks(const PbdModel& s, std::vector<T>& v, size_t count) {
  const size_t all = count * s.voxel_piece.size(), cap = (size_t(64) << 20) / sizeof(T);
  v.reserve(std::max(v.capacity(), std::min(all, cap)));
}

// Extends the warm reserve of v (blocks of `count`, `used` in use) towards its target, by at most
// `budget` bytes and within the reserved capacity; after a cut step only once it fell below half
// its target (steps that start few blocks then touch no page at all).
template <typename T>
void warm_blocks(std::vector<T>& v, size_t used, size_t count, T fill, size_t budget, bool init) {
  const size_t reserve = std::min(kWarmBlocks * count, std::max(count, kWarmBytes / sizeof(T)));
  const size_t end = std::min(used + reserve, v.capacity());
  if (end <= v.size() || (!init && v.size() - used >= reserve / 2)) return;
  v.resize(v.size() + std::min(end - v.size(), budget / sizeof(T)), fill);
}

// Appends one block of `count` elements set to `fill` (the array's) to a block array, from its warm
// reserve when it has one (already set); returns its offset.
template <typename T>
uint32_t append_block(std::vector<T>& v, size_t used, size_t count, T fill) {
  if (used + count > v.size()) {
    if (used + count > v.capacity()) v.reserve(std::max(used + count, 2 * v.capacity()));
    v.resize(used + count, fill);
  }
  return uint32_t(used);
}

// Label storage for simulation voxel sv (a divided voxel's labels and slots), created on first use.
uint32_t ensure_divided(PbdState& s, uint32_t sv) {
  uint32_t d = s.voxel_divided[sv];
  if (d != kDeadIndex) return d;
  d = uint32_t(s.divided.size());
  s.voxel_divided[sv] = d;
  const uint32_t first_label = append_block(s.labels, d * size_t(block_nodes(s)), block_nodes(s), kNoPiece);
  const uint32_t first_slot = append_block(s.label_slots, d * size_t(kLabelSlots), kLabelSlots, kDeadIndex);
  s.divided.push_back({sv, first_label, first_slot, 0});
  return d;
}

// Gives simulation voxel sv the pieces of `labels` (count components): storage as one piece or as a
// divided voxel, new piece slots inheriting particles and rotation from the old piece that held the
// same fine node (old labels in `old`, old slots in `old_slots`; `old_count` 0: no pieces before).
// Old slots nobody inherits are freed.
void set_voxel_pieces(const VoxelModel& model, PbdState& s, uint32_t sv, const uint8_t* labels, uint8_t count,
                      const uint8_t* old, const uint32_t* old_slots, uint8_t old_count) {
  const uint32_t nodes = block_nodes(s);
  // Storage of the labels.
  const uint32_t d = count > 1 ? ensure_divided(s, sv) : s.voxel_divided[sv];
  if (d != kDeadIndex) std::copy(labels, labels + nodes, s.labels.begin() + s.divided[d].first_label);
  uint64_t eighths[256];
  label_eighths(model, s, sv, labels, eighths);
  // The old label at each new label's first node (one pass over the block).
  uint8_t inherit[256];
  std::fill(inherit, inherit + 256, kNoPiece);
  bool seen[256] = {};
  for (uint32_t b = 0; b < nodes; ++b) {
    const uint8_t p = labels[b];
    if (p == kNoPiece || seen[p]) continue;
    seen[p] = true;
    inherit[p] = old_count ? old[b] : uint8_t(kNoPiece);
  }
  assign_slots(s, sv, count, eighths, inherit, old_slots, old_count);
}

// ---- Local relabelling after a cut ---------------------------------------------------------

// Fine voxels of the block around a node each add one eighth (1, 2, 4 or 8 of them).
uint64_t node_eighths(const Lattice& l, const PbdModel& s, const int32_t c[3], int32_t x, int32_t y, int32_t z) {
  const auto around = [&](int32_t t, int32_t first, int32_t n) {
    return uint64_t((t > 0 && first + t - 1 < n) + (t < s.ratio && first + t < n));
  };
  return around(x, c[0] * s.ratio, l.nx) * around(y, c[1] * s.ratio, l.ny) * around(z, c[2] * s.ratio, l.nz);
}

// Pieces of a fine voxel (global coords): the uncut rule inline, voxel_pieces for divided voxels.
void fine_pieces(const VoxelModel& model, const CutState& cut, int32_t i, int32_t j, int32_t k, uint8_t corner_piece[8]) {
  const Lattice& l = model.lattice;
  const uint32_t voxel = l.voxel(i, j, k);
  if (cut.divided_of.get(voxel) == kDeadIndex) {
    for (int q = 0; q < 8; ++q) {
      corner_piece[q] = model.is_inside(l.node(i + (q & 1), j + ((q >> 1) & 1), k + ((q >> 2) & 1))) ? 0 : kNoPiece;
    }
    return;
  }
  uint8_t count = 0;
  voxel_pieces(model, cut, voxel, corner_piece, count);
}

// Gives an undivided simulation voxel explicit labels (all inside nodes: its one piece).
void materialise_labels(const VoxelModel& model, PbdState& s, uint32_t sv) {
  if (s.voxel_divided[sv] != kDeadIndex) return;
  const uint32_t d = ensure_divided(s, sv);
  s.divided[d].piece_count = s.pieces_in_voxel[sv];
  s.label_slots[s.divided[d].first_slot] = s.voxel_piece[sv];
  s.voxel_piece[sv] = kDeadIndex;
  int32_t c[3];
  sim_voxel_coords(s, sv, c);
  uint8_t* labels = s.labels.data() + s.divided[d].first_label;
  for (int32_t z = 0; z <= s.ratio; ++z) {
    for (int32_t y = 0; y <= s.ratio; ++y) {
      for (int32_t x = 0; x <= s.ratio; ++x) {
        labels[block_index(s, x, y, z)] = fine_inside(model, c[0] * s.ratio + x, c[1] * s.ratio + y, c[2] * s.ratio + z) ? 0 : kNoPiece;
      }
    }
  }
}

// Splits the pieces of simulation voxel sv that the changed fine voxels [first, last) (in the block)
// separated. Cuts only remove material connections, so only labels of the changed voxels' nodes can
// split, and every node of such a label is joined to one of those nodes. A breadth-first search runs
// from all of them at once (one group per seed; groups that meet unite) and a label stops searching
// when one group of it is left running: the groups that ran out are new pieces, the one left keeps
// the label. The cost is the material around the new cut (the smaller side of a split), not the block.
// Returns false (having changed nothing) when the search grew past a quarter of the block: a full
// relabel is then cheaper (it looks each fine voxel up once, the search once per corner).
bool relabel_local(const VoxelModel& model, const CutState& cut, PbdState& s, uint32_t sv, const uint32_t* first,
                   const uint32_t* last) {
  materialise_labels(model, s, sv);
  SimDivided& div = s.divided[s.voxel_divided[sv]];
  uint8_t* labels = s.labels.data() + div.first_label;
  const Lattice& l = model.lattice;
  const int32_t r = s.ratio, n = r + 1;
  int32_t c[3];
  sim_voxel_coords(s, sv, c);
  LocalSearch& w = s.scratch.search;
  w.owner.resize(block_nodes(s), kDeadIndex);
  w.queue.clear();
  w.visited.clear();
  w.parent.clear();
  w.pending.clear();
  w.dropped.clear();
  std::fill(w.active, w.active + 256, 0);
  const auto find = [&](uint32_t x) { return uf_find(w.parent.data(), x); };
  // Seeds: the inside corners of the changed fine voxels.
  for (const uint32_t* v = first; v != last; ++v) {
    int32_t vc[3];
    l.voxel_coords(*v, vc);
    for (int q = 0; q < 8; ++q) {
      const int32_t x = vc[0] + (q & 1) - c[0] * r, y = vc[1] + ((q >> 1) & 1) - c[1] * r, z = vc[2] + ((q >> 2) & 1) - c[2] * r;
      const uint32_t b = block_index(s, x, y, z);
      if (labels[b] == kNoPiece || w.owner[b] != kDeadIndex) continue;
      const uint32_t g = uint32_t(w.parent.size());
      w.parent.push_back(g);
      w.pending.push_back(1);
      w.dropped.push_back(0);
      ++w.active[labels[b]];
      w.owner[b] = g;
      w.queue.push_back(b);
      w.visited.push_back(b);
    }
  }
  // Breadth first from all seeds at once.
  const size_t budget = block_nodes(s) / 4 + 64;
  for (size_t head = 0; head < w.queue.size(); ++head) {
    if (w.visited.size() > budget) {
      for (uint32_t b : w.visited) w.owner[b] = kDeadIndex;
      return false;
    }
    const uint32_t b = w.queue[head];
    const uint8_t label = labels[b];
    uint32_t g = find(w.owner[b]);
    --w.pending[g];
    if (w.active[label] <= 1) {
      // The last group of its label still running: it keeps the label (no need to finish it).
      w.dropped[g] = 1;
      if (w.pending[g] == 0) --w.active[label];
      continue;
    }
    const int32_t x = int32_t(b % uint32_t(n)), y = int32_t((b / uint32_t(n)) % uint32_t(n)), z = int32_t(b / uint32_t(n * n));
    for (int o = 0; o < 8; ++o) {
      const int32_t vx = x - 1 + (o & 1), vy = y - 1 + ((o >> 1) & 1), vz = z - 1 + ((o >> 2) & 1);
      if (vx < 0 || vy < 0 || vz < 0 || vx >= r || vy >= r || vz >= r) continue;
      if (c[0] * r + vx >= l.nx || c[1] * r + vy >= l.ny || c[2] * r + vz >= l.nz) continue;
      uint8_t corner_piece[8];
      fine_pieces(model, cut, c[0] * r + vx, c[1] * r + vy, c[2] * r + vz, corner_piece);
      const int self = (1 - (o & 1)) | ((1 - ((o >> 1) & 1)) << 1) | ((1 - ((o >> 2) & 1)) << 2);
      for (int q = 0; q < 8; ++q) {
        if (q == self || corner_piece[q] == kNoPiece || corner_piece[q] != corner_piece[self]) continue;
        const uint32_t m = block_index(s, vx + (q & 1), vy + ((q >> 1) & 1), vz + ((q >> 2) & 1));
        if (w.owner[m] == kDeadIndex) {
          w.owner[m] = g;
          w.queue.push_back(m);
          w.visited.push_back(m);
          ++w.pending[g];
          continue;
        }
        const uint32_t h = find(w.owner[m]);
        if (h == g) continue;
        // Two groups met: one group, running while either was.
        const int running = (w.pending[g] > 0) + (w.pending[h] > 0);
        const uint32_t root = std::min(g, h), other = std::max(g, h);
        w.parent[other] = root;
        w.pending[root] = w.pending[g] + w.pending[h];
        w.dropped[root] = uint8_t(w.dropped[g] | w.dropped[h]);
        w.active[label] -= running - (w.pending[root] > 0);
        g = root;
      }
    }
    if (w.pending[g] == 0) --w.active[label];
  }
  // Groups that ran out are pieces of their own; per label one group keeps it (the one left running,
  // else the first).
  uint8_t keeper_found[256] = {};
  w.new_label.assign(w.parent.size(), kNoPiece);
  for (uint32_t g = 0; g < w.parent.size(); ++g) {
    if (find(g) == g && w.dropped[g]) keeper_found[labels[w.visited[g]]] = 1;  // seed g is visited[g]
  }
  for (uint32_t g = 0; g < w.parent.size(); ++g) {
    if (find(g) != g) continue;
    const uint8_t label = labels[w.visited[g]];
    if (w.dropped[g]) continue;
    if (!keeper_found[label]) {
      keeper_found[label] = 1;
      continue;
    }
    if (div.piece_count >= kMaxSimPieces) continue;  // beyond the label range: stays merged
    w.new_label[g] = div.piece_count++;
  }
  // Relabel the nodes of the new pieces; their volumes move from the old piece to the new.
  const uint32_t count_before = s.pieces_in_voxel[sv];
  for (uint8_t p = uint8_t(count_before); p < div.piece_count; ++p) s.label_slots[div.first_slot + p] = kDeadIndex;
  for (uint32_t b : w.visited) {
    const uint32_t g = find(w.owner[b]);
    w.owner[b] = kDeadIndex;
    const uint8_t to = w.new_label[g];
    if (to == kNoPiece) continue;
    const uint8_t from = labels[b];
    const int32_t x = int32_t(b % uint32_t(n)), y = int32_t((b / uint32_t(n)) % uint32_t(n)), z = int32_t(b / uint32_t(n * n));
    const uint64_t e = node_eighths(l, s, c, x, y, z);
    uint32_t& slot = s.label_slots[div.first_slot + to];
    if (slot == kDeadIndex) {
      const uint32_t old = s.label_slots[div.first_slot + from];
      slot = new_piece(s, sv, to);
      std::copy(s.pieces[old].particles, s.pieces[old].particles + 8, s.pieces[slot].particles);
      s.rotation[slot] = s.rotation[old];
    }
    s.pieces[s.label_slots[div.first_slot + from]].eighths -= e;
    s.pieces[slot].eighths += e;
    labels[b] = to;
  }
  s.pieces_in_voxel[sv] = div.piece_count;
  return true;
}

// Relabels a whole (labelled) block; new pieces inherit from the old piece of the same node.
void relabel_block(const VoxelModel& model, const CutState& cut, PbdState& s, uint32_t sv) {
  const uint32_t nodes = block_nodes(s);
  s.scratch.labels.resize(2 * size_t(nodes));
  s.scratch.old_slots.resize(kLabelSlots);
  const SimDivided& div = s.divided[s.voxel_divided[sv]];
  uint8_t* old = s.scratch.labels.data() + nodes;
  const uint8_t old_count = s.pieces_in_voxel[sv];
  std::copy(s.labels.begin() + div.first_label, s.labels.begin() + div.first_label + nodes, old);
  std::copy(s.label_slots.begin() + div.first_slot, s.label_slots.begin() + div.first_slot + kLabelSlots,
            s.scratch.old_slots.begin());
  const uint8_t count = label_block(model, cut, s, sv, s.scratch.parent2, s.scratch.labels.data());
  set_voxel_pieces(model, s, sv, s.scratch.labels.data(), count, old, s.scratch.old_slots.data(), old_count);
}

// ---- Span relabelling ----------------------------------------------------------------------

constexpr int32_t kSpanRatio = 32;  // spans fit a 64-bit row mask up to this ratio

// Bits [first, first + count) of a bitset (count <= 64).
uint64_t bit_range(const std::vector<uint64_t>& bits, uint64_t first, int32_t count) {
  const uint64_t word = first >> 6;
  const int shift = int(first & 63);
  uint64_t v = bits[word] >> shift;
  if (shift != 0 && shift + count > 64 && word + 1 < bits.size()) v |= bits[word + 1] << (64 - shift);
  return count >= 64 ? v : v & ((uint64_t(1) << count) - 1);
}

// Whether the inside corners `bits` of a voxel are connected along the voxel's edges (an uncut voxel
// joins all its inside corners; only the patterns this is false for need a look of their own).
constexpr std::array<bool, 256> make_edge_connected() {
  std::array<bool, 256> table{};
  for (int bits = 0; bits < 256; ++bits) {
    int seen = bits & -bits;
    for (bool grew = true; grew;) {
      grew = false;
      for (const VoxelEdge& e : kVoxelEdges) {
        for (int k = 0; k < 2; ++k) {
          const int a = k == 0 ? e.c0 : e.c1, b = k == 0 ? e.c1 : e.c0;
          if (((seen >> a) & 1) && ((bits >> b) & 1) && !((seen >> b) & 1)) {
            seen |= 1 << b;
            grew = true;
          }
        }
      }
    }
    table[size_t(bits)] = seen == bits;
  }
  return table;
}
constexpr std::array<bool, 256> kEdgeConnected = make_edge_connected();

// The cut record of simulation voxel sv (null: none yet), made when a cut first divides one of its
// fine voxels. What cuts add: its divided fine voxels as ratio^2 voxel row masks, then its cut lattice
// edges along x, y and z as 3 x (ratio+1)^2 node row masks (bit x of row (y, z) along axis a: the edge
// from block node (x, y, z) along a is cut). Then what the model alone gives (static_rows): its inside
// nodes ((ratio+1)^2 node rows), the voxels with inside and outside corners, and among those the
// voxels whose inside corners their edges do not connect (ratio^2 voxel rows each).
size_t record_rows(int32_t r) { return size_t(3 * r * r + 4 * (r + 1) * (r + 1)); }

const uint64_t* cut_rows(const PbdModel& s, uint32_t sv) {
  const uint32_t at = s.cut_rows_of.get(sv);
  return at == kDeadIndex ? nullptr : s.cut_rows.data() + at;
}

// The block arrays' warm reserves: at init their address space and whole reserves, after a cut step
// a few more pages.
void warm_block_arrays(PbdModel& s, bool init) {
  const size_t budget = init ? std::numeric_limits<size_t>::max() : kRefillBytes;
  if (init) {
    reserve_blocks(s, s.labels, block_nodes(s));
    reserve_blocks(s, s.label_slots, kLabelSlots);
    if (s.ratio <= kSpanRatio) reserve_blocks(s, s.cut_rows, record_rows(s.ratio));
  }
  warm_blocks(s.labels, s.divided.size() * block_nodes(s), block_nodes(s), kNoPiece, budget, init);
  warm_blocks(s.label_slots, s.divided.size() * kLabelSlots, kLabelSlots, kDeadIndex, budget, init);
  if (s.ratio <= kSpanRatio) {
    warm_blocks(s.cut_rows, s.cut_rows_of.size() * record_rows(s.ratio), record_rows(s.ratio), uint64_t(0), budget, init);
  }
}

// The static part of a record (its rows after the cut edges), from the model.
void static_rows(const VoxelModel& model, const PbdModel& s, uint32_t sv, uint64_t* record) {
  const Lattice& l = model.lattice;
  const int32_t r = s.ratio, n = r + 1;
  int32_t c[3];
  sim_voxel_coords(s, sv, c);
  const int32_t gx = c[0] * r, gy = c[1] * r, gz = c[2] * r;
  uint64_t* inside = record + size_t(r * r + 3 * n * n);
  uint64_t* partial = inside + size_t(n * n);
  uint64_t* odd = partial + size_t(r * r);
  // Inside nodes per node row (the lattice's last node is nx; outside the lattice nothing is inside).
  const int32_t xnodes = std::min(r, l.nx - gx) + 1, xvoxels = std::min(r, l.nx - gx);
  for (int32_t z = 0; z < n && gz + z <= l.nz; ++z) {
    for (int32_t y = 0; y < n && gy + y <= l.ny; ++y) {
      inside[uint32_t(y + n * z)] = bit_range(model.inside, l.node(gx, gy + y, gz + z), xnodes);
    }
  }
  // Voxel rows in the lattice (every voxel of such a row is in the block: vmask).
  const uint64_t vmask = (uint64_t(1) << xvoxels) - 1;
  for (int32_t vz = 0; vz < r && gz + vz < l.nz; ++vz) {
    for (int32_t vy = 0; vy < r && gy + vy < l.ny; ++vy) {
      const uint64_t* in = inside + (vy + n * vz);
      const uint64_t all4 = in[0] & in[1] & in[n] & in[n + 1], any4 = in[0] | in[1] | in[n] | in[n + 1];
      const uint64_t all = all4 & (all4 >> 1) & vmask, any = (any4 | (any4 >> 1)) & vmask;
      const uint32_t v = uint32_t(vy + r * vz);
      partial[v] = any & ~all;
      for (uint64_t m = any & ~all; m != 0; m &= m - 1) {
        const int x = __builtin_ctzll(m);
        const uint32_t bits = uint32_t((in[0] >> x) & 3) | uint32_t((in[1] >> x) & 3) << 2 |
                              uint32_t((in[n] >> x) & 3) << 4 | uint32_t((in[n + 1] >> x) & 3) << 6;
        if (!kEdgeConnected[bits]) odd[v] |= uint64_t(1) << x;
      }
    }
  }
}

// Records a divided fine voxel and its cut edges in its simulation voxel's cut record (idempotent:
// cuts only add).
void note_cut_voxel(const VoxelModel& model, PbdModel& s, const DividedVoxel& dv) {
  if (s.ratio > kSpanRatio) return;
  const Lattice& l = model.lattice;
  const int32_t r = s.ratio, n = r + 1;
  int32_t vc[3];
  l.voxel_coords(dv.voxel, vc);
  const uint32_t sv = sim_voxel_id(s, vc[0] / r, vc[1] / r, vc[2] / r);
  uint32_t at = s.cut_rows_of.get(sv);
  if (at == kDeadIndex) {
    at = append_block(s.cut_rows, s.cut_rows_of.size() * record_rows(r), record_rows(r), uint64_t(0));
    s.cut_rows_of.set(sv, at);
    static_rows(model, s, sv, s.cut_rows.data() + at);
  }
  uint64_t* rows = s.cut_rows.data() + at;
  const int32_t x = vc[0] % r, y = vc[1] % r, z = vc[2] % r;
  rows[uint32_t(y + r * z)] |= uint64_t(1) << x;
  for (int e = 0; e < 12; ++e) {
    if (!((dv.cut_edges >> e) & 1u)) continue;
    const int c0 = kVoxelEdges[e].c0, axis = kVoxelEdges[e].axis;
    const int32_t row = (y + ((c0 >> 1) & 1)) + n * (z + ((c0 >> 2) & 1));
    rows[uint32_t(r * r + axis * n * n + row)] |= uint64_t(1) << (x + (c0 & 1));
  }
}

// Spans of a block (ratio <= 32): the block's inside nodes as runs along x joined by x edges,
// united across neighbouring rows where a y or z edge joins them. An edge with both ends inside joins
// them unless the blade cut it (every fine voxel holding it, uncut or divided, joins its ends then);
// the other joins are diagonal: an uncut voxel whose inside corners its edges do not connect joins
// them all, and a divided voxel with an outside corner joins across its uncut ambiguous faces — those
// voxels join their own pieces' corners (fine_pieces). This is label_block's rule, a row at a time:
// O(ratio^2) row masks plus the block's few diagonal voxels, instead of 8 lookups per fine voxel.
void build_spans(const VoxelModel& model, const CutState& cut, const PbdModel& s, uint32_t sv, SpanScratch& w) {
  const Lattice& l = model.lattice;
  const int32_t r = s.ratio, n = r + 1;
  int32_t c[3];
  sim_voxel_coords(s, sv, c);
  const int32_t gx = c[0] * r, gy = c[1] * r, gz = c[2] * r;
  const uint32_t rows = uint32_t(n * n), vrows = uint32_t(r * r);
  // The block's record (a block without one has no cuts: its static rows are made here).
  const uint64_t* record = cut_rows(s, sv);
  if (!record) {
    w.record.assign(record_rows(r), 0);
    static_rows(model, s, sv, w.record.data());
    record = w.record.data();
  }
  const uint64_t* divided = record;
  const uint64_t* cuts_x = divided + vrows;
  const uint64_t* cuts_y = cuts_x + rows;
  const uint64_t* cuts_z = cuts_y + rows;
  const uint64_t* inside = cuts_z + rows;
  const uint64_t* partial = inside + rows;
  const uint64_t* odd = partial + vrows;
  // Every voxel of a voxel row in the lattice is in the block (vmask); ry, rz: voxel rows in the
  // lattice along y and z.
  const int32_t xvoxels = std::min(r, l.nx - gx);
  const uint64_t vmask = (uint64_t(1) << xvoxels) - 1, vnodes = vmask | (vmask << 1);
  const int32_t ry = std::min(r, l.ny - gy), rz = std::min(r, l.nz - gz);
  // Spans per node row, in x order.
  w.row_begin.resize(rows + 1);
  w.mask.clear();
  w.parent.clear();
  for (int32_t z = 0; z < n; ++z) {
    for (int32_t y = 0; y < n; ++y) {
      const uint32_t row = uint32_t(y + n * z);
      w.row_begin[row] = uint32_t(w.mask.size());
      const uint64_t in = inside[row];
      if (in == 0) continue;
      // An x edge of node row (y, z) lies in voxel rows y-1 and y by z-1 and z: one in the lattice.
      const uint64_t joins = y <= ry && z <= rz ? in & (in >> 1) & ~cuts_x[row] & vmask : 0;
      for (uint64_t m = in; m != 0;) {
        const int x0 = __builtin_ctzll(m);
        const int run = __builtin_ctzll(~(joins >> x0));  // joined edges x0, x0+1, ...: nodes x0 .. x0+run
        const uint64_t span = ((uint64_t(2) << run) - 1) << x0;
        w.parent.push_back(uint32_t(w.mask.size()));
        w.mask.push_back(span);
        m &= ~span;
      }
    }
  }
  w.row_begin[rows] = uint32_t(w.mask.size());
  const auto find = [&](uint32_t x) {
    while (w.parent[x] != x) x = w.parent[x] = w.parent[w.parent[x]];
    return x;
  };
  const auto unite = [&](uint32_t a, uint32_t b) {
    a = find(a);
    b = find(b);
    if (a != b) w.parent[std::max(a, b)] = std::min(a, b);
  };
  // Rows joined by y and z edges: both ends inside, not cut, in a voxel of the block (voxel x holds
  // nodes x and x+1). Rows of one span each (the most) need no search for the spans that touch.
  const auto unite_rows = [&](uint32_t a_row, uint32_t b_row, uint64_t cut) {
    const uint64_t link = vnodes & inside[a_row] & inside[b_row] & ~cut;
    if (link == 0) return;
    const uint32_t a0 = w.row_begin[a_row], a1 = w.row_begin[a_row + 1];
    const uint32_t b0 = w.row_begin[b_row], b1 = w.row_begin[b_row + 1];
    if (a1 == a0 + 1 && b1 == b0 + 1) {
      unite(a0, b0);
      return;
    }
    for (uint32_t a = a0; a < a1; ++a) {
      if ((w.mask[a] & link) == 0) continue;
      for (uint32_t b = b0; b < b1; ++b) {
        if (w.mask[a] & w.mask[b] & link) unite(a, b);
      }
    }
  };
  for (int32_t z = 0; z < n; ++z) {
    for (int32_t y = 0; y < n; ++y) {
      const uint32_t row = uint32_t(y + n * z);
      if (inside[row] == 0) continue;
      if (y < ry && z <= rz) unite_rows(row, row + 1, cuts_y[row]);
      if (z < rz && y <= ry) unite_rows(row, row + uint32_t(n), cuts_z[row]);
    }
  }
  // The diagonal voxels: those with inside and outside corners that a cut divided, and the uncut
  // ones whose edges do not connect their inside corners. Each unites its pieces' corners.
  const auto span_at = [&](uint32_t row, int x) {
    for (uint32_t i = w.row_begin[row]; i < w.row_begin[row + 1]; ++i) {
      if ((w.mask[i] >> x) & 1u) return i;
    }
    return kDeadIndex;  // not reached: a corner with a piece is inside
  };
  for (int32_t vz = 0; vz < r; ++vz) {
    for (int32_t vy = 0; vy < r; ++vy) {
      const uint32_t v = uint32_t(vy + r * vz);
      for (uint64_t e = (divided[v] & partial[v]) | (odd[v] & ~divided[v]); e != 0; e &= e - 1) {
        const int x = __builtin_ctzll(e);
        uint8_t corner_piece[8];
        fine_pieces(model, cut, gx + x, gy + vy, gz + vz, corner_piece);
        uint32_t first[8] = {kDeadIndex, kDeadIndex, kDeadIndex, kDeadIndex, kDeadIndex, kDeadIndex, kDeadIndex, kDeadIndex};
        for (int q = 0; q < 8; ++q) {
          const uint8_t p = corner_piece[q];
          if (p >= 8) continue;
          const uint32_t span = span_at(uint32_t(vy + ((q >> 1) & 1) + n * (vz + ((q >> 2) & 1))), x + (q & 1));
          if (span == kDeadIndex) continue;
          if (first[p] == kDeadIndex) {
            first[p] = span;
          } else {
            unite(first[p], span);
          }
        }
      }
    }
  }
}

// Whether the last cut step left the material components of block sv (ratio <= 32) as they were,
// shown by a short search: every pair of corners that one of its reshaped fine voxels
// (cut.reshaped_voxels[reshaped[i]], with their pieces before the step) joined before and no longer
// joins must still be joined through the block, within one span (a run of nodes along x joined by
// uncut x edges) or from one span through the row next to it (uncut y or z edges: build_spans' joins;
// an edge with both ends inside in the block lies in a fine voxel of the block). Cuts only remove
// joins and the old labels are the components before the step, so the labels stay exact then. False
// when the search finds no such join (the block is relabelled).
bool keeps_components(const VoxelModel& model, const CutState& cut, const PbdModel& s, uint32_t sv,
                      const uint32_t* reshaped, const uint32_t* reshaped_end) {
  const uint64_t* record = cut_rows(s, sv);
  if (!record) return false;
  const int32_t r = s.ratio, n = r + 1;
  int32_t c[3];
  sim_voxel_coords(s, sv, c);
  const uint32_t rows = uint32_t(n * n);
  const uint64_t* cuts[3] = {record + size_t(r * r), record + size_t(r * r) + rows, record + size_t(r * r) + 2 * rows};
  const uint64_t* inside = record + size_t(r * r) + 3 * rows;
  // The span of row (y, z) holding node x (0: x is outside).
  const auto span = [&](int32_t y, int32_t z, int32_t x) -> uint64_t {
    const uint32_t row = uint32_t(y + n * z);
    const uint64_t in = inside[row];
    if (!((in >> x) & 1u)) return 0;
    const uint64_t joins = in & (in >> 1) & ~cuts[0][row];
    const int hi = x + __builtin_ctzll(~(joins >> x));
    const uint64_t below = ~joins & ((uint64_t(1) << x) - 1);
    const int lo = below ? 64 - __builtin_clzll(below) : 0;
    return ((uint64_t(2) << hi) - 1) & ~((uint64_t(1) << lo) - 1);  // hi <= ratio < 63
  };
  // The spans of row (y, z) meeting `bits` (nodes of that row).
  const auto spans_meeting = [&](int32_t y, int32_t z, uint64_t bits) {
    uint64_t out = 0;
    while (bits) {
      const uint64_t sp = span(y, z, __builtin_ctzll(bits));
      out |= sp;
      bits &= ~sp;
    }
    return out;
  };
  // The uncut edges from row (y, z) to row (y2, z2) (0: not the next row along y or z).
  const auto link = [&](int32_t y, int32_t z, int32_t y2, int32_t z2) -> uint64_t {
    int axis = 0;
    if (z == z2 && (y2 == y + 1 || y2 == y - 1)) axis = 1;
    if (y == y2 && (z2 == z + 1 || z2 == z - 1)) axis = 2;
    if (axis == 0) return 0;
    const uint32_t a = uint32_t(y + n * z), b = uint32_t(y2 + n * z2);
    return inside[a] & inside[b] & ~cuts[axis][std::min(a, b)];
  };
  // Nodes a and b (block coordinates x, y, z) joined within their span, from a's span to b's, or
  // through the spans of a row next to a's.
  const auto joined = [&](const int32_t a[3], const int32_t b[3]) {
    const uint64_t sa = span(a[1], a[2], a[0]), sb = span(b[1], b[2], b[0]);
    if (a[1] == b[1] && a[2] == b[2] && (sa & sb)) return true;
    if (sa & sb & link(a[1], a[2], b[1], b[2])) return true;
    const int32_t next[4][2] = {{a[1] - 1, a[2]}, {a[1] + 1, a[2]}, {a[1], a[2] - 1}, {a[1], a[2] + 1}};
    for (const auto& m : next) {
      if (m[0] < 0 || m[1] < 0 || m[0] > r || m[1] > r) continue;
      const uint64_t reach = spans_meeting(m[0], m[1], sa & link(a[1], a[2], m[0], m[1]));
      if (reach == 0) continue;
      const bool there = m[0] == b[1] && m[1] == b[2] ? (reach & sb) != 0 : (reach & sb & link(m[0], m[1], b[1], b[2])) != 0;
      if (there) return true;
    }
    return false;
  };
  for (const uint32_t* i = reshaped; i != reshaped_end; ++i) {
    const uint64_t entry = cut.reshaped_voxels[*i];
    const uint32_t voxel = uint32_t(entry >> 32), before = uint32_t(entry);
    const DividedVoxel& dv = cut.divided[cut.divided_of.get(voxel)];
    int32_t vc[3];
    model.lattice.voxel_coords(voxel, vc);
    for (int a = 0; a < 3; ++a) vc[a] -= c[a] * r;
    // Per piece before the step: its corners now in another piece than its first corner.
    for (uint32_t p = 0; p < 8; ++p) {
      int first = -1;
      uint32_t reached = 0;  // bit q: new piece q joined to the first corner's
      for (int q = 0; q < 8; ++q) {
        if (((before >> (4 * q)) & 0xF) != p) continue;
        const uint8_t now = dv.corner_piece[q];
        if (now >= 8) return false;  // not reached: cuts do not change what is inside
        if (first < 0) {
          first = q;
          reached = 1u << now;
          continue;
        }
        if ((reached >> now) & 1u) continue;
        const int32_t na[3] = {vc[0] + (first & 1), vc[1] + ((first >> 1) & 1), vc[2] + ((first >> 2) & 1)};
        const int32_t nb[3] = {vc[0] + (q & 1), vc[1] + ((q >> 1) & 1), vc[2] + ((q >> 2) & 1)};
        if (!joined(na, nb)) return false;
        reached |= 1u << now;
      }
    }
  }
  return true;
}

// Relabels a whole block from its spans (ratio <= 32) when its components changed; new pieces inherit
// from the old piece of their first node. Labels are numbered in node order, as label_block numbers
// them. Cuts only split components and the old labels are the components before the cut, so the
// components changed exactly when their count did (below the label range): a cut that splits nothing
// (a slit still joined around its front) leaves the block alone. When they changed, calls
// before_write() before changing anything. Returns whether they changed.
template <typename BeforeWrite>
bool relabel_spans(const VoxelModel& model, const CutState& cut, PbdState& s, uint32_t sv, PbdCutStats* stats,
                   BeforeWrite&& before_write) {
  SpanScratch& w = s.scratch.spans;
  build_spans(model, cut, s, sv, w);
  const Lattice& l = model.lattice;
  const int32_t r = s.ratio, n = r + 1;
  int32_t c[3];
  sim_voxel_coords(s, sv, c);
  const uint32_t rows = uint32_t(n * n), spans = uint32_t(w.mask.size());
  if (stats) stats->spans += spans;
  uint32_t roots = 0;
  for (uint32_t i = 0; i < spans; ++i) roots += w.parent[i] == i;
  if (roots == s.pieces_in_voxel[sv] && roots < kMaxSimPieces) return false;
  before_write();
  // Components numbered by their first span (row order, x order within a row).
  w.label.assign(spans, kNoPiece);
  uint8_t count = 0;
  uint32_t first_node[256];
  for (uint32_t row = 0; row < rows; ++row) {
    for (uint32_t i = w.row_begin[row]; i < w.row_begin[row + 1]; ++i) {
      uint32_t root = i;
      while (w.parent[root] != root) root = w.parent[root];
      if (w.label[root] == kNoPiece && count < kMaxSimPieces) {
        first_node[count] = row * uint32_t(n) + uint32_t(__builtin_ctzll(w.mask[i]));
        w.label[root] = count++;
      } else if (w.label[root] == kNoPiece) {
        w.label[root] = uint8_t(kMaxSimPieces - 1);  // beyond the label range: merged into the last
      }
      w.label[i] = w.label[root];
    }
  }
  // The old pieces: slots, and the label each new label's first node had.
  const uint8_t old_count = s.pieces_in_voxel[sv];
  uint32_t old_slots[256];
  for (uint8_t p = 0; p < old_count; ++p) old_slots[p] = slot_of_label(s, sv, p);
  uint8_t inherit[256];
  for (uint8_t p = 0; p < count; ++p) {
    const uint32_t b = first_node[p];
    const int32_t x = int32_t(b % uint32_t(n)), y = int32_t((b / uint32_t(n)) % uint32_t(n)), z = int32_t(b / uint32_t(n * n));
    inherit[p] = old_count ? label_at(model, s, sv, c, b, c[0] * r + x, c[1] * r + y, c[2] * r + z) : uint8_t(kNoPiece);
  }
  // Volumes: per span, the eighths of its row times the prefix sums along x.
  const auto around = [&](int32_t t, int32_t first, int32_t count_along) {
    return uint64_t((t > 0 && first + t - 1 < count_along) + (t < r && first + t < count_along));
  };
  w.weight.assign(size_t(n) + 1, 0);
  for (int32_t x = 0; x < n; ++x) w.weight[size_t(x) + 1] = w.weight[size_t(x)] + around(x, c[0] * r, l.nx);
  uint64_t eighths[256] = {};
  // Labels: written span by span when the block keeps labels.
  const uint32_t d = count > 1 ? ensure_divided(s, sv) : s.voxel_divided[sv];
  uint8_t* labels = d == kDeadIndex ? nullptr : s.labels.data() + s.divided[d].first_label;
  uint64_t wy[kSpanRatio + 1], wz[kSpanRatio + 1];  // voxels around a node along y and z
  for (int32_t t = 0; t < n; ++t) {
    wy[t] = around(t, c[1] * r, l.ny);
    wz[t] = around(t, c[2] * r, l.nz);
  }
  for (uint32_t row = 0; row < rows; ++row) {
    const uint64_t wyz = wy[row % uint32_t(n)] * wz[row / uint32_t(n)];
    if (labels) std::fill(labels + row * uint32_t(n), labels + (row + 1) * uint32_t(n), kNoPiece);
    for (uint32_t i = w.row_begin[row]; i < w.row_begin[row + 1]; ++i) {
      const int x0 = __builtin_ctzll(w.mask[i]), x1 = 63 - __builtin_clzll(w.mask[i]);
      eighths[w.label[i]] += wyz * (w.weight[size_t(x1) + 1] - w.weight[size_t(x0)]);
      if (labels) std::fill(labels + row * uint32_t(n) + uint32_t(x0), labels + row * uint32_t(n) + uint32_t(x1) + 1, w.label[i]);
    }
  }
  assign_slots(s, sv, count, eighths, inherit, old_slots, old_count);
  return true;
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


// Grows the embedding with the surface's vertex slots. Capacity follows the surface's own (it keeps
// headroom for cuts): growing past a capacity copies every slot, a p99 spike of the cut step.
// The new capacity is touched right away (grown to it and shrunk back, which keeps the pages): the
// surface grows by about a thousand vertices per cutting step at 512, and first touches of their
// pages inside the steps cost ~0.1 ms each step on a virtual machine.
void grow_embedding(const CutState& cut, PbdState& s) {
  if (s.embedding.size() < cut.surface.positions.size()) {
    if (s.embedding.capacity() < cut.surface.positions.capacity()) {
      const size_t size = s.embedding.size(), capacity = cut.surface.positions.capacity();
      s.embedding.reserve(capacity);
      s.deformed.reserve(capacity);
      s.embedding.resize(capacity, VertexEmbedding{kDeadIndex, 0, Vec3f::Zero()});
      s.deformed.resize(capacity, Vec3f::Zero());
      s.embedding.resize(size);
      s.deformed.resize(size);
    }
    s.embedding.resize(cut.surface.positions.size(), VertexEmbedding{kDeadIndex, 0, Vec3f::Zero()});
    s.deformed.resize(cut.surface.positions.size(), Vec3f::Zero());
  }
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


// ---- Edits (PbdModel::edits) --------------------------------------------------------------

constexpr uint64_t kNoRows = ~uint64_t(0);  // PbdData::embed_revision of rows to build from scratch
// Bounds of the edit records kept for a cache that is not read every step (reserved at init, so a
// cut step does not allocate for them).
constexpr size_t kEditRecords = 64, kEditEntries = 8192;

void reserve_edits(PbdEdits& e) {
  e.records.reserve(kEditRecords + 1);
  e.slots.reserve(2 * kEditEntries);
  e.voxels.reserve(kEditEntries / 8);
  e.particles.reserve(2 * kEditEntries);
}




// Drops the first n records.
void drop_edits(PbdEdits& e, uint64_t n) {
  if (n == 0) return;
  const PbdEdits::Record last = e.records[n - 1];
  e.base_revision = last.revision;
  e.base_cut_steps = last.cut_steps;
  e.slots.erase(e.slots.begin(), e.slots.begin() + last.slots_end);
  e.voxels.erase(e.voxels.begin(), e.voxels.begin() + last.voxels_end);
  e.particles.erase(e.particles.begin(), e.particles.begin() + last.particles_end);
  e.records.erase(e.records.begin(), e.records.begin() + ptrdiff_t(n));
  for (PbdEdits::Record& r : e.records) {
    r.slots_end -= last.slots_end;
    r.voxels_end -= last.voxels_end;
    r.particles_end -= last.particles_end;
  }
  e.first += n;
}

// Records what a pbd_apply_cut changed: the re-embedded slots, the relabelled voxels, the particles
// whose pieces or masses changed (sorted). Records every cache has seen are dropped first; all of
// them when they outgrow a bound (a cache not read every step then rebuilds once).
void record_edits(const CutState& cut, PbdState& s, const std::vector<uint32_t>& voxels,
                  const std::vector<uint64_t>* particles) {
  PbdEdits& e = s.edits;
  uint64_t seen = e.count();
  for (const uint64_t c : {s.piece_contacts.index.edits, s.blocks_edits}) {
    if (c >= e.first && c < seen) seen = c;
  }
  drop_edits(e, seen - e.first);
  if (e.records.size() >= kEditRecords || e.slots.size() > kEditEntries || e.particles.size() > kEditEntries) {
    drop_edits(e, e.records.size());
  }
  for (uint32_t slot : cut.changed_vertices) {
    if (slot < s.embedding.size()) e.slots.push_back(slot);
  }
  e.voxels.insert(e.voxels.end(), voxels.begin(), voxels.end());
  if (particles) {
    for (uint64_t p : *particles) e.particles.push_back(uint32_t(p));
  }
  e.records.push_back({s.revision, cut.steps, uint32_t(e.slots.size()), uint32_t(e.voxels.size()),
                       uint32_t(e.particles.size())});
}

// ---- Embedding rows ---------------------------------------------------------------------------

// Sets the row of a vertex slot from its piece in the contact index (none: the slot keeps its rest
// position), swapping the last row into a removed one.
void set_embed_row(const CutState& cut, PbdState& s, uint32_t slot) {
  const uint32_t piece = s.piece_contacts.index.slot_piece[slot];
  uint32_t& row = s.embed_row_of[slot];
  if (piece != kDeadIndex) {
    const VertexEmbedding& e = s.embedding[slot];
    const EmbedRow r{slot, piece, e.local.x(), e.local.y(), e.local.z()};
    if (row == kDeadIndex) {
      row = uint32_t(s.embed_rows.size());
      s.embed_rows.push_back(r);
    } else {
      s.embed_rows[row] = r;
    }
    return;
  }
  s.deformed[slot] = cut.surface.positions[slot];
  if (row == kDeadIndex) return;
  const EmbedRow last = s.embed_rows.back();
  s.embed_rows[row] = last;
  s.embed_row_of[last.slot] = row;
  s.embed_rows.pop_back();
  row = kDeadIndex;
}

// The rows of the embedded slots, following the contact index's slot pieces (labels are looked up
// once per model, cut or slot count, by refresh_slots): after one update of the index only the
// slots it revisited, else all (grouped by piece, so the interpolation reads each piece's corners
// in a run).
void refresh_embed_rows(const CutState& cut, PbdState& s) {
  refresh_slots(cut, s);
  const ContactIndex& x = s.piece_contacts.index;
  const bool valid = s.embed_revision != kNoRows;
  if (valid && s.embed_updates == x.updates) return;
  s.embed_row_of.resize(x.slots, kDeadIndex);
  if (valid && s.embed_updates + 1 == x.updates && !x.rebuilt) {
    for (uint32_t slot : x.revisited) set_embed_row(cut, s, slot);
  } else {
    s.embed_rows.clear();
    std::fill(s.embed_row_of.begin(), s.embed_row_of.end(), kDeadIndex);
    for (uint32_t i = 0; i < x.pieces; ++i) {
      for (uint32_t n = x.piece_begin[i]; n < x.piece_begin[i + 1]; ++n) set_embed_row(cut, s, x.piece_slots[n]);
    }
    for (uint32_t slot = 0; slot < x.slots; ++slot) {
      if (x.slot_piece[slot] == kDeadIndex) s.deformed[slot] = cut.surface.positions[slot];
    }
  }
  s.embed_revision = s.revision;
  s.embed_updates = x.updates;
}

// ---- Solver step -----------------------------------------------------------------------------

// ---- Solver blocks ----------------------------------------------------------------------------

// Where a piece's cluster sits in the shape blocks (PbdData::shape_lane): its lane in the low
// kLaneBits, its block above, its colour in the top 6 bits.
constexpr int kLaneBits = 3;
static_assert(kShapeLanes <= 1 << kLaneBits && kColourGroups <= 64, "a lane code holds every lane and colour");
constexpr uint32_t kLaneMask = (1u << kLaneBits) - 1;
uint32_t lane_code(uint32_t colour, size_t block, int lane) {
  return colour << 26 | uint32_t(block) << kLaneBits | uint32_t(lane);
}

// Copies lane `from` of block `src` into lane `to` of block `dst`.
void copy_lane(ShapeBlock& dst, int to, const ShapeBlock& src, int from) {
  dst.piece[to] = src.piece[from];
  dst.inv_total[to] = src.inv_total[from];
  for (int k = 0; k < kShapeMaxParticles; ++k) {
    dst.index[k][to] = src.index[k][from];
    dst.mass[k][to] = src.mass[k][from];
    dst.moves[k][to] = src.moves[k][from];
    for (int e = 0; e < 3; ++e) dst.offset[k][e][to] = src.offset[k][e][from];
  }
}

// Adds a live piece's cluster (its rest frame from the particles' rest positions and masses) at the
// end of its colour's blocks; the overflow colour's clusters may share particles: one per block,
// solved in order. A cluster without a rest frame (no mass) joins no block.
void add_cluster(PbdState& s, uint32_t slot) {
  const SimPiece& piece = s.pieces[slot];
  const uint32_t* particles = piece.particles;
  double rest[24];
  for (int k = 0; k < 8; ++k) {
    for (int a = 0; a < 3; ++a) rest[3 * k + a] = s.rest[particles[k]][a];
  }
  ShapeRest r;
  if (!shape_matching_rest(s.inv_mass.data(), particles, rest, 8, r)) return;
  std::vector<ShapeBlock>& blocks = s.shape_blocks[piece.colour];
  const int lanes = piece.colour == kOverflowColour ? 1 : kShapeLanes;
  if (blocks.empty() || blocks.back().lanes == lanes) blocks.emplace_back();
  s.shape_lane[slot] = lane_code(piece.colour, blocks.size() - 1, blocks.back().lanes);
  shape_block_add(blocks.back(), slot, particles, r);
}

// Takes a piece's cluster out of its block: the colour's last lane moves into its place (the unused
// lanes of the last block repeat its last, as shape_block_add leaves them).
void remove_cluster(PbdState& s, uint32_t slot) {
  const uint32_t code = s.shape_lane[slot];
  const uint32_t colour = code >> 26, block = (code & ((1u << 26) - 1)) >> kLaneBits;
  const int lane = int(code & kLaneMask);
  std::vector<ShapeBlock>& blocks = s.shape_blocks[colour];
  ShapeBlock& last = blocks.back();
  const int last_lane = last.lanes - 1;
  if (block + 1 != blocks.size() || lane != last_lane) {
    copy_lane(blocks[block], lane, last, last_lane);
    s.shape_lane[blocks[block].piece[lane]] = code;
  }
  if (--last.lanes == 0) {
    blocks.pop_back();
  } else {
    for (int l = last.lanes; l < kShapeLanes; ++l) copy_lane(last, l, last, last.lanes - 1);
  }
  s.shape_lane[slot] = kDeadIndex;
}

// Shape-matching rest frames of the live pieces in blocks of kShapeLanes per colour, from scratch
// (in their colour groups' order).
void build_shape_blocks(PbdState& s) {
  s.shape_lane.assign(s.pieces.size(), kDeadIndex);
  for (int c = 0; c < kColourGroups; ++c) {
    s.shape_blocks[c].clear();
    for (const uint32_t slot : s.piece_groups[c]) add_cluster(s, slot);
  }
}

// The same from the recorded cuts: the clusters of the pieces freed or using a changed particle
// (rest position, mass, or the piece's particles and colour) leave their blocks and the live ones
// join again at the end of their colour; the overflow colour is rebuilt in its group's order.
void update_shape_blocks(PbdState& s) {
  const PbdEdits& e = s.edits;
  const EditRange from = edits_after(e, s.blocks_edits);
  std::vector<uint8_t>& mark = s.blocks_mark;
  mark.resize(s.position.size(), 0);
  for (size_t i = from.particles; i < e.particles.size(); ++i) mark[e.particles[i]] = 1;
  s.shape_lane.resize(s.pieces.size(), kDeadIndex);
  for (const ShapeBlock& b : s.shape_blocks[kOverflowColour]) {
    for (int l = 0; l < b.lanes; ++l) s.shape_lane[b.piece[l]] = kDeadIndex;
  }
  s.shape_blocks[kOverflowColour].clear();
  std::vector<uint32_t>& dirty = s.blocks_dirty;
  dirty.clear();
  for (uint32_t slot = 0; slot < s.pieces.size(); ++slot) {
    const SimPiece& piece = s.pieces[slot];
    const bool live = piece.sim_voxel != kDeadIndex;
    bool changed = !live;
    for (int k = 0; live && k < 8 && !changed; ++k) changed = mark[piece.particles[k]] != 0;
    if (!changed) continue;
    if (s.shape_lane[slot] != kDeadIndex) remove_cluster(s, slot);
    if (live && piece.colour != kOverflowColour) dirty.push_back(slot);
  }
  for (const uint32_t slot : dirty) add_cluster(s, slot);
  for (const uint32_t slot : s.piece_groups[kOverflowColour]) add_cluster(s, slot);
  for (size_t i = from.particles; i < e.particles.size(); ++i) mark[e.particles[i]] = 0;
}

// The clusters of each parallel colour in the order of their smallest particle (unique: they share
// no particle), kShapeLanes to a block, their lanes' codes renumbered; the unused lanes of the last
// block repeat its last, as shape_block_add leaves them. The order never changes a result (a colour's
// clusters are independent); it is for the task pool, which gives each thread the same share of
// every colour (task_pool.h): with the clusters, and the stretch rows, in particle order that share
// covers about the same particles in every colour, so their cache lines stay on one core. Without
// it the blocks mix clusters from all over after a few cuts (remove_cluster moves the colour's last
// lane into each hole).
void sort_shape_lanes(PbdState& s) {
  std::vector<std::pair<uint32_t, uint32_t>> order;  // (key, block << kLaneBits | lane)
  std::vector<ShapeBlock> sorted;
  for (int c = 0; c < kOverflowColour; ++c) {
    std::vector<ShapeBlock>& blocks = s.shape_blocks[c];
    order.clear();
    for (uint32_t b = 0; b < blocks.size(); ++b) {
      for (int l = 0; l < blocks[b].lanes; ++l) {
        uint32_t key = ~0u;
        for (int k = 0; k < kShapeMaxParticles; ++k) key = std::min(key, blocks[b].index[k][l]);
        order.emplace_back(key, b << kLaneBits | uint32_t(l));
      }
    }
    if (std::is_sorted(order.begin(), order.end())) continue;
    std::sort(order.begin(), order.end());
    sorted.assign((order.size() + kShapeLanes - 1) / kShapeLanes, ShapeBlock{});
    for (uint32_t i = 0; i < order.size(); ++i) {
      ShapeBlock& dst = sorted[i / kShapeLanes];
      const int lane = int(i % kShapeLanes);
      copy_lane(dst, lane, blocks[order[i].second >> kLaneBits], int(order[i].second & kLaneMask));
      dst.lanes = lane + 1;
      s.shape_lane[dst.piece[lane]] = lane_code(uint32_t(c), i / kShapeLanes, lane);
    }
    if (!sorted.empty()) {
      ShapeBlock& last = sorted.back();
      for (int l = last.lanes; l < kShapeLanes; ++l) copy_lane(last, l, last, last.lanes - 1);
    }
    blocks.swap(sorted);
  }
}

// The solver's blocks, when the model changed: the shape-matching blocks from the recorded cuts when
// they can follow them, else from scratch; the stretch constraints' rows (with the particles'
// masses: O(constraints), a copy each), those of the parallel colours in particle order (as the
// blocks above; a row's multiplier is its substep's, so they follow the rows), the overflow's in its
// group's order (it is solved in order).
void refresh_blocks(const CutState& cut, PbdState& s) {
  if (s.blocks_revision != s.revision) {
    if (edits_replayable(s, cut, s.blocks_edits, s.blocks_revision, 0, false) && s.shape_lane.size() <= s.pieces.size()) {
      update_shape_blocks(s);
    } else {
      build_shape_blocks(s);
    }
    sort_shape_lanes(s);
    for (int c = 0; c < kColourGroups; ++c) {
      std::vector<StretchRow>& rows = s.stretch_rows[c];
      rows.clear();
      for (const StretchConstraint& k : s.stretch_groups[c]) rows.push_back(stretch_row(s.inv_mass.data(), k.a, k.b, k.rest));
      if (c != kOverflowColour) {
        std::sort(rows.begin(), rows.end(), [](const StretchRow& x, const StretchRow& y) { return x.a != y.a ? x.a < y.a : x.b < y.b; });
      }
    }
    // The hexahedra of the material model (kNeoHookean): each colour's pieces in their group's order
    // (a parallel colour's rows share no particle, so their order does not change the bits).
    const bool elastic = s.params.elastic == ElasticModel::kNeoHookean;
    const double eighth = s.fine_size * s.fine_size * s.fine_size / 8.0;
    for (int c = 0; c < kColourGroups; ++c) {
      std::vector<ElasticRow>& rows = s.elastic_rows[c];
      rows.clear();
      for (const uint32_t slot : s.piece_groups[c]) {
        if (!elastic) break;
        const SimPiece& piece = s.pieces[slot];
        ElasticRow row;
        row.piece = slot;
        for (int a = 0; a < 8; ++a) {
          row.p[a] = piece.particles[a];
          row.w[a] = s.inv_mass[piece.particles[a]];
        }
        row.volume = double(piece.eighths) * eighth;
        // Each Gauss point's share of it: half uniform, half its octant's material. Octant weights
        // alone leave a partly filled piece's empty octants without a shear term, and its corners
        // there without stiffness (zero-energy modes: measured, the liver's surface wrinkled); the
        // uniform half keeps every mode stiff, the other half puts stiffness where the material is.
        uint64_t counted = 0;
        for (int g = 0; g < 8; ++g) counted += piece.octants[g];
        for (int g = 0; g < 8; ++g) {
          const double share = counted > 0 ? double(piece.octants[g]) / double(counted) : 0.125;
          row.octant[g] = row.volume * (0.5 * 0.125 + 0.5 * share);
        }
        rows.push_back(row);
      }
      s.elastic_lambda[c].assign(rows.size() * kElasticConstraints, 0.0);
    }
    s.blocks_revision = s.revision;
  }
  s.blocks_edits = s.edits.count();
}

// Grains of the step's batches: a batch below its grain is one chunk (one thread, no barrier inside
// a run of such batches). Each grain is the items of about PbdData::chunk_work instructions, from the
// costs measured on the default recording (callgrind): a stretch constraint ~36 instructions, a block
// of 8 shape-matching clusters ~2 800, a particle's velocity + predict ~30, a contact group (a piece's
// contacts with the planes, or the contacts between two pieces, often 10 or more) ~4 000. A stage
// shared by two threads costs a barrier plus the particle lines the other core wrote in the stage
// before: ~5-8 µs a stage on the 2-core machine, so a chunk under ~10 µs of work loses
// (kDefaultChunkWork). Measured with 2 workers (issue 17, bench replay / bench deform, deform p50):
// with the former grains (chunks of ~5 000-15 000 instructions) the default recording (bunny at 128,
// sim 16) ran 193 stages a step and took 1.2-1.4 ms against 0.85-0.9 ms on one thread; with these it
// runs as one stage, and liver at 64 with sim 32 (5 200 clusters) is within noise of the former
// grains (2.5 against 2.1-2.5 ms).
constexpr uint32_t kParticleCost = 30, kStretchCost = 36, kShapeBlockCost = kShapeLanes * 350, kContactGroupCost = 4000;
constexpr uint32_t kElasticCost = 2500;  // a hexahedron's 9 constraints (estimated from its operations)
constexpr uint32_t kSerial = ~0u;

// The batches of a whole step (all substeps: one TaskRunner job, one wake-up of the workers), in
// order: predict; per iteration the stretch colours (overflow last, serially), the shape-matching
// colours, the grab, the contact batches between pieces and with the planes; kFinalContactSweeps
// more sweeps of the piece contacts and one of the planes; then the velocities fused with the next
// substep's predict (index 1; one pass over the particles, both per particle), or alone after the
// last substep (index 0). The first chunk of each predict batch resets the substep's multipliers.
void build_step_batches(PbdState& s, bool stretch_on, int substeps) {
  std::vector<StepBatch>& steps = s.step_batches;
  std::vector<TaskBatch>& batches = s.task_batches;
  steps.clear();
  batches.clear();
  const auto add = [&](uint8_t kind, uint32_t index, uint32_t count, uint32_t grain) {
    if (count == 0) return;
    steps.push_back(StepBatch{kind, index});
    batches.push_back(TaskBatch{count, grain});
  };
  const auto grain = [&](uint32_t cost) { return std::max<uint32_t>(1, s.chunk_work / cost); };
  const uint32_t particle_grain = grain(kParticleCost), stretch_grain = grain(kStretchCost);
  const uint32_t shape_grain = grain(kShapeBlockCost), contact_grain = grain(kContactGroupCost);
  const uint32_t elastic_grain = grain(kElasticCost);
  const bool elastic = s.params.elastic == ElasticModel::kNeoHookean;
  const auto add_contacts = [&](uint8_t kind, const ContactSet& set) {
    for (uint32_t b = 0; b < contact_batches(set); ++b) {
      const bool serial = b == kOverflowColour || set.points.size() < 256;
      add(kind, b, set.batch_begin[b + 1] - set.batch_begin[b], serial ? kSerial : contact_grain);
    }
  };
  const uint32_t n = uint32_t(s.position.size());
  if (n == 0) return;
  // The first substep: its predict, then the rest of its batches (the body).
  add(StepBatch::kPredict, 0, n, particle_grain);
  for (int it = 0; it < s.params.iterations; ++it) {
    // The material's hexahedra (kNeoHookean), or the paper's stretch and shape matching.
    for (int c = 0; elastic && stretch_on && c < kColourGroups; ++c) {
      add(StepBatch::kElastic, uint32_t(c), uint32_t(s.elastic_rows[c].size()), c == kOverflowColour ? kSerial : elastic_grain);
    }
    for (int c = 0; !elastic && stretch_on && c < kColourGroups; ++c) {
      add(StepBatch::kStretch, uint32_t(c), uint32_t(s.stretch_groups[c].size()), c == kOverflowColour ? kSerial : stretch_grain);
    }
    for (int c = 0; !elastic && c < kColourGroups; ++c) {
      add(StepBatch::kShape, uint32_t(c), uint32_t(s.shape_blocks[c].size()), c == kOverflowColour ? kSerial : shape_grain);
    }
    if (s.grab_particle < n && s.inv_mass[s.grab_particle] > 0.0) add(StepBatch::kGrab, 0, 1, kSerial);
    // Contact between pieces, then with the static planes, last so each iteration ends with the
    // surface above them.
    static_assert(kContactOverflow == kOverflowColour, "one overflow batch for both contact sets");
    add_contacts(StepBatch::kPieceContact, s.piece_contacts.set);
    add_contacts(StepBatch::kPlaneContact, s.contacts);
  }
  // The piece contacts' own sweeps (sim/contact.h, "Resting offset"), then the planes again so the
  // substep still ends with the surface above them.
  if (!s.piece_contacts.set.points.empty()) {
    for (int sweep = 0; sweep < kFinalContactSweeps; ++sweep) add_contacts(StepBatch::kPieceContact, s.piece_contacts.set);
    add_contacts(StepBatch::kPlaneContact, s.contacts);
  }
  // The other substeps: velocities fused with the next predict, then the body again.
  const size_t body = steps.size() - 1;
  for (int sub = 1; sub < substeps; ++sub) {
    add(StepBatch::kVelocity, 1, n, particle_grain);
    for (size_t i = 1; i <= body; ++i) {
      const StepBatch step = steps[i];
      const TaskBatch batch = batches[i];
      steps.push_back(step);
      batches.push_back(batch);
    }
  }
  add(StepBatch::kVelocity, 0, n, particle_grain);
}

// Grab: a compliant attachment of one particle to its target (XPBD, per axis).
void solve_grab(PbdState& s, double h, double lambda[3]) {
  const uint32_t p = s.grab_particle;
  const double alpha = s.grab_compliance / (h * h);
  for (int a = 0; a < 3; ++a) {
    const double constraint = s.position[p][a] - s.grab_target[a];
    const double dl = (-constraint - alpha * lambda[a]) / (s.inv_mass[p] + alpha);
    lambda[a] += dl;
    s.position[p][a] += s.inv_mass[p] * dl;
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
  ++s.revision;
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
  warm_block_arrays(s, true);
  for (const DividedVoxel& dv : cut.divided) note_cut_voxel(model, s, dv);
  s.scratch.labels.resize(block_nodes(s));
  for (uint32_t sv = 0; sv < voxels; ++sv) {
    const uint8_t count = label_block(model, cut, s, sv, s.scratch.parent, s.scratch.labels.data());
    if (count > 0) set_voxel_pieces(model, s, sv, s.scratch.labels.data(), count, nullptr, nullptr, 0);
  }
  // Octants of every piece (the material model's quadrature weights).
  for (uint32_t sv = 0; sv < voxels; ++sv) {
    if (has_pieces(s, sv)) piece_octants(model, s, sv);
  }
  // Particles: one per material group at every coarse corner.
  CornerMembers members;
  for (int32_t K = 0; K <= s.sz; ++K) {
    for (int32_t J = 0; J <= s.sy; ++J) {
      for (int32_t I = 0; I <= s.sx; ++I) assign_corner(model, s, I, J, K, members);
    }
  }
  s.scratch.face_cache = FaceCache{};
  // Constraints, colours and masses.
  for (uint32_t slot = 0; slot < s.pieces.size(); ++slot) {
    if (s.pieces[slot].sim_voxel != kDeadIndex) attach_piece(s, slot);
  }
  for (uint32_t p = 0; p < s.rest.size(); ++p) update_mass(s, p);
  // The embedding of every live vertex.
  grow_embedding(cut, s);
  for (uint32_t slot = 0; slot < cut.surface.positions.size(); ++slot) embed_vertex(model, cut, s, slot);
  warm_block_arrays(s, true);
  reserve_edits(s.edits);
  s.edits.base_revision = s.revision;  // the caches follow the cuts from here
  s.edits.base_cut_steps = cut.steps;
  pbd_embed(cut, s);
  return true;
}

uint32_t pbd_apply_cut(const VoxelModel& model, const CutState& cut, PbdState& s, PbdCutStats* stats) {
  // The simulation voxels holding fine voxels whose pieces may have changed (new cut or air edges;
  // the others only moved vertices). Up to kSpanRatio a block is relabelled whole, so only the
  // voxels are needed (consecutive fine voxels mostly share one: deduplicated on the fly, then
  // sorted); beyond it the local search needs the changed fine voxels of each, sorted by simulation
  // voxel (sim voxel << 32 | fine voxel).
  const bool spans = s.ratio <= kSpanRatio;
  std::vector<uint64_t>& changed = s.scratch.changed;
  std::vector<uint32_t>& affected = s.scratch.sim;
  changed.clear();
  affected.clear();
  for (uint32_t i = 0; i < cut.reshaped_voxels.size(); ++i) {
    const uint32_t voxel = uint32_t(cut.reshaped_voxels[i] >> 32);
    const uint32_t d = cut.divided_of.get(voxel);
    if (d == kDeadIndex) continue;
    note_cut_voxel(model, s, cut.divided[d]);
    int32_t vc[3];
    model.lattice.voxel_coords(voxel, vc);
    const uint32_t sv = sim_voxel_id(s, vc[0] / s.ratio, vc[1] / s.ratio, vc[2] / s.ratio);
    changed.push_back(uint64_t(sv) << 32 | (spans ? i : voxel));
  }
  std::sort(changed.begin(), changed.end());
  for (uint64_t c : changed) {
    const uint32_t sv = uint32_t(c >> 32);
    if (has_pieces(s, sv) && (affected.empty() || affected.back() != sv)) affected.push_back(sv);
  }

  // Relabel the affected voxels: by spans (O(ratio^2) row masks for the whole block); beyond
  // kSpanRatio locally from their changed fine voxels, else node by node. Before a voxel's pieces
  // change, the pieces that may change particles with them (its own and its neighbours') are
  // detached, remembering the particles they used; a voxel whose components did not change touches
  // nothing.
  std::vector<uint32_t>& near = s.scratch.near;
  std::vector<uint32_t>& relabelled = s.scratch.relabelled;  // the voxels whose components changed
  std::vector<uint64_t>& touched = s.scratch.corners;
  std::vector<uint8_t>& detached = s.scratch.mark;  // (sim voxels) in `near`
  near.clear();
  relabelled.clear();
  touched.clear();
  if (!affected.empty()) detached.resize(s.pieces_in_voxel.size(), 0);
  uint32_t pieces_touched = 0;
  const auto detach_around = [&](uint32_t sv) {
    relabelled.push_back(sv);
    int32_t c[3];
    sim_voxel_coords(s, sv, c);
    for (int32_t dz = -1; dz <= 1; ++dz) {
      for (int32_t dy = -1; dy <= 1; ++dy) {
        for (int32_t dx = -1; dx <= 1; ++dx) {
          if (!sim_in_range(s, c[0] + dx, c[1] + dy, c[2] + dz)) continue;
          const uint32_t n = sim_voxel_id(s, c[0] + dx, c[1] + dy, c[2] + dz);
          if (!has_pieces(s, n) || detached[n]) continue;
          detached[n] = 1;
          near.push_back(n);
          for_pieces(s, n, [&](uint32_t slot) {
            for (uint32_t p : s.pieces[slot].particles) touched.push_back(p);
            detach_piece(s, slot);
            ++pieces_touched;
          });
        }
      }
    }
  };
  std::vector<uint32_t>& fine = s.scratch.parent;
  for (size_t i = 0; i < changed.size();) {
    const uint32_t sv = uint32_t(changed[i] >> 32);
    fine.clear();
    for (; i < changed.size() && uint32_t(changed[i] >> 32) == sv; ++i) fine.push_back(uint32_t(changed[i]));
    if (!has_pieces(s, sv)) continue;
    if (spans) {
      // The joins the cut removed mostly reconnect next to it (a slit joined around its front).
      if (keeps_components(model, cut, s, sv, fine.data(), fine.data() + fine.size())) {
        if (stats) ++stats->kept_by_search;
        continue;
      }
      relabel_spans(model, cut, s, sv, stats, [&] { detach_around(sv); });
      if (stats) ++stats->span_relabels;
      continue;
    }
    detach_around(sv);
    const bool local = relabel_local(model, cut, s, sv, fine.data(), fine.data() + fine.size());
    if (!local) relabel_block(model, cut, s, sv);
    if (stats) {
      stats->nodes_searched += s.scratch.search.visited.size();
      ++(local ? stats->local_relabels : stats->block_relabels);
    }
  }

  if (!relabelled.empty()) {
    ++s.revision;  // pieces, particles and masses change: the solver rebuilds its blocks
    for (uint32_t n : near) detached[n] = 0;
    sorted_unique(near);
    sorted_unique(relabelled);
    // Corner particles of the relabelled voxels.
    std::vector<uint64_t>& corners = s.scratch.corner_ids;
    corners.clear();
    for (uint32_t sv : relabelled) {
      int32_t c[3];
      sim_voxel_coords(s, sv, c);
      for (int q = 0; q < 8; ++q) corners.push_back(corner_id(s, c[0] + (q & 1), c[1] + ((q >> 1) & 1), c[2] + ((q >> 2) & 1)));
    }
    sorted_unique(corners);
    forget_faces(s, relabelled);
    CornerMembers members;
    for (uint64_t id : corners) {
      int32_t I, J, K;
      corner_coords(s, id, I, J, K);
      assign_corner(model, s, I, J, K, members);
    }
    // The relabelled voxels' octants; re-attach; masses of every particle involved; unused particles
    // go to the free list.
    for (uint32_t sv : relabelled) piece_octants(model, s, sv);
    for (uint32_t sv : near) {
      for_pieces(s, sv, [&](uint32_t slot) {
        attach_piece(s, slot);
        for (uint32_t p : s.pieces[slot].particles) touched.push_back(p);
        ++pieces_touched;
      });
    }
    if (stats) {
      stats->pieces_touched += pieces_touched;
      stats->corners += uint32_t(corners.size());
      stats->components_changed += uint32_t(relabelled.size());
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
  record_edits(cut, s, relabelled, relabelled.empty() ? nullptr : &touched);  // for the caches
  warm_block_arrays(s, false);
  if (stats) stats->sim_voxels += uint32_t(affected.size());
  return uint32_t(affected.size());
}

void pbd_embed(const CutState& cut, PbdState& s, const TaskRunner& tasks) {
  // Each piece's 8 corners in float, once (a piece serves ~40 surface vertices), padded to 4 floats
  // a corner so one corner is one 4-float vector.
  s.piece_corners.resize(s.pieces.size() * 32);
  for (uint32_t slot = 0; slot < s.pieces.size(); ++slot) {
    if (s.pieces[slot].sim_voxel == kDeadIndex) continue;
    float* out = &s.piece_corners[32 * size_t(slot)];
    for (int c = 0; c < 8; ++c) {
      const Vec3d& p = s.position[s.pieces[slot].particles[c]];
      for (int a = 0; a < 3; ++a) out[4 * c + a] = float(p[a]);
      out[4 * c + 3] = 0.0f;
    }
  }
  refresh_embed_rows(cut, s);
  // The interpolation (pbd_kernels.h embed_rows); the deformed surface is float anyway and not part
  // of the state hash.
  static_assert(sizeof(Vec3f) == 3 * sizeof(float), "deformed positions are packed float triples");
  const float* corners = s.piece_corners.data();
  const EmbedRow* rows = s.embed_rows.data();
  float* out = s.deformed.empty() ? nullptr : s.deformed[0].data();
  const TaskBatch batch{uint32_t(s.embed_rows.size()), 4096};
  run_batches(tasks, &batch, 1, [&](uint32_t, uint32_t begin, uint32_t end) { embed_rows(corners, rows, begin, end, out); });
}

void pbd_step(const CutState& cut, PbdState& s, const TaskRunner& tasks, bool embed) {
  const PbdParams& params = s.params;
  const int substeps = std::max(1, params.substeps);
  const double h = params.dt / substeps;
  double* x = s.position.empty() ? nullptr : s.position[0].data();
  const double* w = s.inv_mass.data();
  // The constraint blocks change only with the model (a cut, or init).
  refresh_blocks(cut, s);
  // A soft constraint without a time step does nothing (solve_distance's rule).
  const bool stretch_on = !(params.stretch_compliance > 0.0) || h > 0.0;
  const double alpha = params.stretch_compliance > 0.0 && h > 0.0 ? params.stretch_compliance / (h * h) : 0.0;
  // Damping per unit time: `damping` of the velocity goes per time step dt whatever the substeps.
  // The material model damps through its constraints instead (strain rates only, not rigid motion).
  const bool elastic = params.elastic == ElasticModel::kNeoHookean;
  const double keep = elastic ? 1.0 : substeps == 1 ? 1.0 - params.damping : std::pow(1.0 - params.damping, 1.0 / substeps);
  const ElasticConstants material = elastic && h > 0.0 ? elastic_constants(params.youngs_modulus, params.poisson_ratio,
                                                                           params.stiffness_damping, s.sim_size, h)
                                                       : ElasticConstants{};
  gather_contacts(cut, s);  // contact (sim/contact.h)
  build_step_batches(s, elastic ? h > 0.0 : stretch_on, substeps);
  double grab_lambda[3] = {0, 0, 0};
  // A substep starts with zero multipliers (the first chunk of its predict pass resets them; nothing
  // else reads them then).
  const auto begin_substep = [&] {
    for (std::vector<double>& lambda : s.stretch_lambda) std::fill(lambda.begin(), lambda.end(), 0.0);
    for (std::vector<double>& lambda : s.elastic_lambda) std::fill(lambda.begin(), lambda.end(), 0.0);
    contacts_begin_substep(s.contacts);
    contacts_begin_substep(s.piece_contacts.set);
    for (int a = 0; a < 3; ++a) grab_lambda[a] = 0.0;
  };
  // Per particle: the end of a substep (the planes' backstop, velocities), then the start of the next
  // (previous positions, gravity, prediction), in one pass over the particles (raw arrays: Eigen's
  // packet stores may alias anything, so its loops reload every array pointer per particle);
  // anchored particles stay and keep no velocity. The same operations as Eigen's per axis.
  const double gravity_h[3] = {h * params.gravity.x(), h * params.gravity.y(), h * params.gravity.z()};
  const double keep_h = keep / h;
  double* __restrict xp = x;
  double* __restrict vp = s.velocity.empty() ? nullptr : s.velocity[0].data();
  double* __restrict pp = s.previous.empty() ? nullptr : s.previous[0].data();
  const auto advance = [&](uint32_t begin, uint32_t end, bool velocity, bool predict) {
    if (velocity && !params.planes.empty()) {
      project_particles_to_planes(x, w, begin, end, params.planes.data(), uint32_t(params.planes.size()), s.sim_size);
    }
    for (uint32_t p = begin; p < end; ++p) {
      double* xi = xp + 3 * size_t(p);
      double* vi = vp + 3 * size_t(p);
      double* pi = pp + 3 * size_t(p);
      if (w[p] == 0.0) {
        if (!predict) continue;
        for (int e = 0; e < 3; ++e) {
          pi[e] = xi[e];
          vi[e] = 0.0;
        }
        continue;
      }
      for (int e = 0; e < 3; ++e) {
        double v = vi[e];
        if (velocity) v = (xi[e] - pi[e]) * keep_h;
        if (predict) {
          pi[e] = xi[e];
          v += gravity_h[e];
          xi[e] += h * v;
        }
        vi[e] = v;
      }
    }
  };
  // One job for the whole step: the batches of build_step_batches in order (a barrier between batches).
  const auto run = [&](uint32_t batch, uint32_t begin, uint32_t end) {
    const StepBatch& b = s.step_batches[batch];
    switch (b.kind) {
      case StepBatch::kPredict:
        if (begin == 0) begin_substep();
        advance(begin, end, false, true);
        break;
      case StepBatch::kStretch: {
        // Four at a time where a colour shares no particle (pbd_kernels.h); the overflow group in order.
        solve_stretch_rows(x, s.stretch_rows[b.index].data(), s.stretch_lambda[b.index].data(), begin, end, alpha,
                           b.index != kOverflowColour);
        break;
      }
      case StepBatch::kShape:
        // Two blocks at once where a colour shares no particle (pbd_kernels.h); the overflow's in order.
        solve_shape_blocks(x, s.shape_blocks[b.index].data(), begin, end, params.shape_stiffness, s.rotation.data(),
                           b.index != kOverflowColour);
        break;
      case StepBatch::kElastic:
        // One colour's hexahedra share no particle; the overflow's in order (pbd_elastic.h).
        solve_elastic_rows(x, s.previous[0].data(), s.elastic_rows[b.index].data(), s.elastic_lambda[b.index].data(), begin,
                           end, material, s.rotation.data());
        break;
      case StepBatch::kGrab:
        solve_grab(s, h, grab_lambda);
        break;
      case StepBatch::kPieceContact:
      case StepBatch::kPlaneContact: {
        ContactSet& set = b.kind == StepBatch::kPieceContact ? s.piece_contacts.set : s.contacts;
        const uint32_t first = set.batch_begin[b.index];
        for (uint32_t g = begin; g < end; ++g) solve_contact_group(x, s.previous[0].data(), w, set, first + g);
        break;
      }
      case StepBatch::kVelocity:
        if (b.index != 0 && begin == 0) begin_substep();
        advance(begin, end, true, b.index != 0);
        break;
    }
  };
  run_batches(tasks, s.task_batches.data(), uint32_t(s.task_batches.size()), run);
  ++s.steps;
  if (embed) pbd_embed(cut, s, tasks);
}

void pbd_forget_caches(PbdState& s) {
  s.blocks_revision = s.blocks_edits = ~uint64_t(0);
  s.embed_revision = kNoRows;
  s.piece_contacts.index.revision = s.piece_contacts.index.edits = ~uint64_t(0);
  s.piece_contacts.seen_steps = ~uint64_t(0);  // the allowances compare every slot
}

uint32_t piece_slot(const PbdState& s, uint32_t sv, uint8_t label) { return slot_of_label(s, sv, label); }

uint32_t vertex_sim_piece(const PbdState& s, uint32_t slot) {
  return slot < s.embedding.size() ? embedded_piece(s, s.embedding[slot]) : kDeadIndex;
}

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
    // Nearest node: the value is in [0, ratio], so truncating x + 0.5 rounds it (inline, where
    // lround is a library call; the mapping asks this for every blade sample in material).
    node[a] = c[a] * s.ratio + int32_t(std::clamp(u[a], 0.0, 1.0) * s.ratio + 0.5);
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
