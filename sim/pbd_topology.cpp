// The topology of the simulation pieces (sim/pbd.h "Particles"): piece and particle slots, the stretch
// constraints and colour groups pieces join and leave, the particles at the coarse corners (one per
// group of pieces that material joins there), and pbd_apply_cut, a cut step's update of them.
#include "sim/pbd_internal.h"
#include "sim/id_pool.h"

#include <algorithm>

namespace dvx {
namespace pbd_internal {

// ---- Slots ---------------------------------------------------------------------------------

namespace {

// Arguments by value: they may point into the arrays this grows.
uint32_t new_particle(PbdModel& s, PbdData& data, const Vec3d rest, const Vec3d position, const Vec3d velocity) {
  uint32_t p;
  if (!take_free_slot(s.free_particles, p)) {
    p = uint32_t(s.rest.size());
    data.position.emplace_back();
    data.velocity.emplace_back();
    data.previous.emplace_back();
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
  data.position[p] = position;
  data.previous[p] = position;
  data.velocity[p] = velocity;
  s.mass_eighths[p] = 0;
  s.refs[p] = 0;
  bool anchored = false;
  for (const Aabb& box : s.params.fixed) {
    anchored = anchored || ((rest.array() >= box.min.array()).all() && (rest.array() <= box.max.array()).all());
  }
  s.anchored[p] = anchored;
  return p;
}

}  // namespace

uint32_t new_piece(PbdModel& s, PbdData& data, uint32_t sv, uint8_t label) {
  uint32_t slot;
  if (!take_free_slot(s.free_pieces, slot)) {
    slot = uint32_t(s.pieces.size());
    s.pieces.emplace_back();
    data.rotation.push_back(Eigen::Quaterniond::Identity());
    data.enhancement.resize(data.enhancement.size() + 9);
  }
  SimPiece& piece = s.pieces[slot];
  piece.sim_voxel = sv;
  piece.piece = label;
  piece.colour = kOverflowColour;
  piece.colour_slot = kDeadIndex;
  std::fill(piece.particles, piece.particles + 8, kDeadIndex);
  piece.eighths = 0;
  std::fill(piece.octants, piece.octants + 8, 0u);
  data.rotation[slot] = Eigen::Quaterniond::Identity();
  std::fill_n(data.enhancement.begin() + 9 * ptrdiff_t(slot), 9, 0.0);
  return slot;
}

void free_piece(PbdModel& s, uint32_t slot) {
  s.pieces[slot].sim_voxel = kDeadIndex;
  s.free_pieces.push_back(slot);
}

// Mass of a particle from its eighths (exact: one rounding of an integer product).
void update_mass(PbdModel& s, uint32_t p) {
  const double h = s.fine_size;
  s.mass[p] = s.params.density * (double(s.mass_eighths[p]) * (h * h * h / 64.0));
  s.inv_mass[p] = s.anchored[p] || s.mass[p] <= 0.0 ? 0.0 : 1.0 / s.mass[p];
}

// ---- Colour groups -------------------------------------------------------------------------

uint64_t pair_key(uint32_t a, uint32_t b) { return (uint64_t(a) << 32) | b; }

namespace {

// One more piece edge uses particle pair (a, b): the constraint is created (and coloured) on first use.
void add_stretch(PbdModel& s, PbdData& data, uint32_t a, uint32_t b) {
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
  data.stretch_lambda[colour].push_back(0.0);
  s.stretch_of.set(key, handle);
}

// One piece edge fewer uses (a, b): the last use removes the constraint by swap-with-last in its group.
void remove_stretch(PbdModel& s, PbdData& data, uint32_t a, uint32_t b) {
  if (a > b) std::swap(a, b);
  const uint64_t key = pair_key(a, b);
  const uint32_t handle = s.stretch_of.get(key);
  if (handle == kDeadIndex) return;
  StretchHandle& h = s.stretch_handles[handle];
  if (--h.refs > 0) return;
  std::vector<StretchConstraint>& group = s.stretch_groups[h.colour];
  std::vector<double>& lambda = data.stretch_lambda[h.colour];
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

}  // namespace

// A piece joins the dynamics: masses, constraint references, shape-matching colour.
void attach_piece(PbdModel& s, PbdData& data, uint32_t slot) {
  SimPiece& piece = s.pieces[slot];
  for (uint32_t p : piece.particles) {
    ++s.refs[p];
    s.mass_eighths[p] += piece.eighths;
  }
  for (const VoxelEdge& e : kVoxelEdges) add_stretch(s, data, piece.particles[e.c0], piece.particles[e.c1]);
  piece.colour = take_colour(s.shape_busy.data(), piece.particles, 8);
  piece.colour_slot = uint32_t(s.piece_groups[piece.colour].size());
  s.piece_groups[piece.colour].push_back(slot);
}

// The reverse of attach_piece.
void detach_piece(PbdModel& s, PbdData& data, uint32_t slot) {
  SimPiece& piece = s.pieces[slot];
  for (uint32_t p : piece.particles) {
    --s.refs[p];
    s.mass_eighths[p] -= piece.eighths;
  }
  release_colour(s.shape_busy.data(), piece.particles, 8, piece.colour);
  for (const VoxelEdge& e : kVoxelEdges) remove_stretch(s, data, piece.particles[e.c0], piece.particles[e.c1]);
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
void piece_octants(const VoxelModel& model, PbdModel& s, uint32_t sv) {
  for_pieces(s, sv, [&](uint32_t slot) { std::fill(s.pieces[slot].octants, s.pieces[slot].octants + 8, 0u); });
  int32_t c[3];
  sim_voxel_coords(s, sv, c);
  const Lattice& l = model.lattice;
  const int32_t r = s.ratio, n[3] = {l.nx, l.ny, l.nz};
  // The rule per axis: of a node's two voxels along axis e (below, v = t - 1; above, v = t), those
  // in the block and the lattice, by the octant bit each gives (set when 4t +- 1 >= 2r). A voxel
  // around the node is one choice per axis, so an octant's count is the product of the three axes'
  // counts for its bits (the same integers as testing the node's 8 voxels one by one, ~8x fewer
  // operations: this was ~85 % of the model update of a cutting step at 16 fine voxels per
  // simulation voxel, ~140 us a relabelled voxel).
  std::vector<uint8_t>& count = s.scratch.octant_counts;  // [axis][t][bit]
  count.assign(3 * 2 * size_t(r + 1), 0);
  for (int e = 0; e < 3; ++e) {
    for (int32_t t = 0; t <= r; ++t) {
      for (int up = 0; up < 2; ++up) {
        const int32_t v = t - 1 + up;
        if (v < 0 || v >= r || c[e] * r + v >= n[e]) continue;
        ++count[(size_t(e) * (r + 1) + t) * 2 + (4 * t + (up ? 1 : -1) >= 2 * r)];
      }
    }
  }
  const uint8_t* cx = count.data();
  const uint8_t* cy = cx + 2 * size_t(r + 1);
  const uint8_t* cz = cy + 2 * size_t(r + 1);
  for (int32_t z = 0; z <= r; ++z) {
    for (int32_t y = 0; y <= r; ++y) {
      // The y and z factors of the row's octants (octant bit 1: y, bit 2: z).
      uint32_t wyz[4];
      for (int o = 0; o < 4; ++o) wyz[o] = uint32_t(cy[2 * y + (o & 1)]) * cz[2 * z + (o >> 1)];
      if ((wyz[0] | wyz[1] | wyz[2] | wyz[3]) == 0) continue;
      for (int32_t x = 0; x <= r; ++x) {
        const uint8_t label = label_at(model, s, sv, c, block_index(s, x, y, z), c[0] * r + x, c[1] * r + y, c[2] * r + z);
        const uint32_t slot = slot_of_label(s, sv, label);
        if (slot == kDeadIndex) continue;
        uint32_t* octants = s.pieces[slot].octants;
        for (int o = 0; o < 8; ++o) octants[o] += uint32_t(cx[2 * x + (o & 1)]) * wyz[o >> 1];
      }
    }
  }
}

// ---- Corner particles ----------------------------------------------------------------------

namespace {

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

}  // namespace

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
void assign_corner(const VoxelModel& model, PbdModel& s, PbdData& data, int32_t I, int32_t J, int32_t K,
                   CornerMembers& m) {
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
      best = from == kDeadIndex ? new_particle(s, data, rest, rest, Vec3d::Zero())
                                : new_particle(s, data, rest, data.position[from], data.velocity[from]);
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

// Coarse corner id (I,J,K) packed for sorting.
uint64_t corner_id(const PbdModel& s, int32_t I, int32_t J, int32_t K) {
  return uint64_t(I) + uint64_t(s.sx + 1) * (uint64_t(J) + uint64_t(s.sy + 1) * uint64_t(K));
}

void corner_coords(const PbdModel& s, uint64_t id, int32_t& I, int32_t& J, int32_t& K) {
  I = int32_t(id % uint64_t(s.sx + 1));
  J = int32_t((id / uint64_t(s.sx + 1)) % uint64_t(s.sy + 1));
  K = int32_t(id / (uint64_t(s.sx + 1) * uint64_t(s.sy + 1)));
}

}  // namespace pbd_internal

// ---- A cut step's model update ---------------------------------------------------------------

using namespace pbd_internal;

namespace {

// pbd_apply_cut's first stage: the cut step's reshaped fine voxels by simulation voxel in
// s.scratch.changed (sim voxel << 32 | index in reshaped_voxels up to kSpanRatio, else fine voxel),
// and the simulation voxels with pieces among them, sorted, in s.scratch.sim.
void collect_changed(const VoxelModel& model, const CutState& cut, PbdModel& s) {
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

}

// The second stage: relabels the changed simulation voxels (s.scratch.changed), detaching the pieces
// around each voxel whose components changed (s.scratch.near; the voxels in s.scratch.relabelled,
// the particles they used in s.scratch.corners). Returns the pieces detached.
uint32_t relabel_changed(const VoxelModel& model, const CutState& cut, PbdModel& s, PbdData& data,
                         PbdCutStats* stats) {
  const bool spans = s.ratio <= kSpanRatio;
  const std::vector<uint64_t>& changed = s.scratch.changed;
  const std::vector<uint32_t>& affected = s.scratch.sim;
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
            detach_piece(s, data, slot);
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
      relabel_spans(model, cut, s, data, sv, stats, [&] { detach_around(sv); });
      if (stats) ++stats->span_relabels;
      continue;
    }
    detach_around(sv);
    const bool local = relabel_local(model, cut, s, data, sv, fine.data(), fine.data() + fine.size());
    if (!local) relabel_block(model, cut, s, data, sv);
    if (stats) {
      stats->nodes_searched += s.scratch.search.visited.size();
      ++(local ? stats->local_relabels : stats->block_relabels);
    }
  }

  return pieces_touched;
}

// The third stage, after a relabel: the relabelled voxels' corner particles and octants, the pieces
// around them attached again, the masses of every particle involved (unused ones to the free list).
void rebuild_relabelled(const VoxelModel& model, PbdModel& s, PbdData& data, uint32_t pieces_touched,
                        PbdCutStats* stats) {
  std::vector<uint32_t>& near = s.scratch.near;
  std::vector<uint32_t>& relabelled = s.scratch.relabelled;
  std::vector<uint64_t>& touched = s.scratch.corners;
  std::vector<uint8_t>& detached = s.scratch.mark;
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
    assign_corner(model, s, data, I, J, K, members);
  }
  // The relabelled voxels' octants; re-attach; masses of every particle involved; unused particles
  // go to the free list.
  for (uint32_t sv : relabelled) piece_octants(model, s, sv);
  for (uint32_t sv : near) {
    for_pieces(s, sv, [&](uint32_t slot) {
      attach_piece(s, data, slot);
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

}  // namespace

uint32_t pbd_apply_cut(const VoxelModel& model, const CutState& cut, PbdModel& s, PbdData& data, PbdCutStats* stats) {
  collect_changed(model, cut, s);
  const std::vector<uint32_t>& affected = s.scratch.sim;
  const std::vector<uint32_t>& relabelled = s.scratch.relabelled;
  const uint32_t pieces_touched = relabel_changed(model, cut, s, data, stats);
  if (!relabelled.empty()) rebuild_relabelled(model, s, data, pieces_touched, stats);
  std::vector<uint64_t>& touched = s.scratch.corners;

  // Re-embed the changed vertex slots (vertices of relabelled voxels follow their node's label).
  grow_embedding(cut, s, data);
  for (uint32_t slot : cut.changed_vertices) {
    if (slot < s.embedding.size()) embed_vertex(model, cut, s, slot);
  }
  record_edits(cut, s, data, relabelled, relabelled.empty() ? nullptr : &touched);  // for the caches
  warm_block_arrays(s, false);
  if (stats) stats->sim_voxels += uint32_t(affected.size());
  return uint32_t(affected.size());
}

}  // namespace dvx
