// Internals of the simulation pieces shared by the PBD files (pbd.cpp: the solver and the public
// functions; pbd_labels.cpp: labelling and relabelling; pbd_topology.cpp: slots, colour groups, corner
// particles; pbd_embedding.cpp: embedding, edits, embedding rows; pbd_check.cpp: the consistency
// check; contact_points.cpp: contact points and their caches). Not for engine/, bench/ or ui/
// (tests/layers_test.sh): they use sim/pbd.h and sim/world.h.
#pragma once

#include "sim/pbd.h"
#include "sim/union_find.h"

#include <algorithm>
#include <vector>

namespace dvx {
namespace pbd_internal {

inline uint32_t sim_voxel_id(const PbdModel& s, int32_t I, int32_t J, int32_t K) {
  return uint32_t(I) + uint32_t(s.sx) * (uint32_t(J) + uint32_t(s.sy) * uint32_t(K));
}

inline bool has_pieces(const PbdModel& s, uint32_t sv) { return s.pieces_in_voxel[sv] != 0; }

inline uint32_t slot_of_label(const PbdModel& s, uint32_t sv, uint8_t label) {
  if (label == kNoPiece || label >= s.pieces_in_voxel[sv]) return kDeadIndex;
  const uint32_t d = s.voxel_divided[sv];
  if (d == kDeadIndex) return label == 0 ? s.voxel_piece[sv] : kDeadIndex;
  return s.label_slots[s.divided[d].first_slot + label];
}

template <typename F>
inline void for_pieces(const PbdModel& s, uint32_t sv, F&& f) {
  for (uint8_t p = 0; p < s.pieces_in_voxel[sv]; ++p) f(slot_of_label(s, sv, p));
}

// The piece slot an embedding names (kDeadIndex: none).
inline uint32_t embedded_piece(const PbdModel& s, const VertexEmbedding& e) {
  if (e.sim_voxel == kDeadIndex || !has_pieces(s, e.sim_voxel)) return kDeadIndex;
  const uint32_t d = s.voxel_divided[e.sim_voxel];
  if (d == kDeadIndex) return s.voxel_piece[e.sim_voxel];
  const uint8_t label = s.labels[s.divided[d].first_label + e.node];
  return label == kNoPiece ? kDeadIndex : s.label_slots[s.divided[d].first_slot + label];
}

template <typename T>
inline void sorted_unique(std::vector<T>& v) {
  std::sort(v.begin(), v.end());
  v.erase(std::unique(v.begin(), v.end()), v.end());
}

// The state (revision, cut steps) after record number n (n == edits.first: the base).
inline void edit_state(const PbdEdits& e, uint64_t n, uint64_t& revision, uint64_t& cut_steps) {
  if (n == e.first) {
    revision = e.base_revision;
    cut_steps = e.base_cut_steps;
  } else {
    revision = e.records[n - e.first - 1].revision;
    cut_steps = e.records[n - e.first - 1].cut_steps;
  }
}

// Whether a cache built at (revision, cut_steps) that has seen `seen` records can replay the rest to
// be current: the records it missed are kept, it matches the state after the last it saw, and
// nothing changed the model (or, with `surface`, the cut) since the last record.
inline bool edits_replayable(const PbdModel& s, const CutState& cut, uint64_t seen, uint64_t revision,
                             uint64_t cut_steps, bool surface) {
  const PbdEdits& e = s.edits;
  if (seen < e.first || seen > e.count()) return false;
  uint64_t r, c, now_r, now_c;
  edit_state(e, seen, r, c);
  edit_state(e, e.count(), now_r, now_c);
  if (r != revision || now_r != s.revision) return false;
  return !surface || (c == cut_steps && now_c == cut.steps);
}

// Offsets into the edit lists where the records after `seen` begin.
struct EditRange {
  uint32_t slots = 0, voxels = 0, particles = 0;
};

inline EditRange edits_after(const PbdEdits& e, uint64_t seen) {
  if (seen == e.first) return {};
  const PbdEdits::Record& r = e.records[seen - e.first - 1];
  return {r.slots_end, r.voxels_end, r.particles_end};
}

// ---- Fine lattice access -------------------------------------------------------------------

inline bool fine_inside(const VoxelModel& model, int32_t i, int32_t j, int32_t k) {
  const Lattice& l = model.lattice;
  if (i < 0 || j < 0 || k < 0 || i > l.nx || j > l.ny || k > l.nz) return false;
  return model.is_inside(l.node(i, j, k));
}

// ---- Simulation grid -----------------------------------------------------------------------

inline void sim_voxel_coords(const PbdModel& s, uint32_t v, int32_t c[3]) {
  c[0] = int32_t(v % uint32_t(s.sx));
  v /= uint32_t(s.sx);
  c[1] = int32_t(v % uint32_t(s.sy));
  c[2] = int32_t(v / uint32_t(s.sy));
}

inline bool sim_in_range(const PbdModel& s, int32_t I, int32_t J, int32_t K) {
  return I >= 0 && J >= 0 && K >= 0 && I < s.sx && J < s.sy && K < s.sz;
}

// Index of a fine node inside a simulation voxel's block ((ratio+1)^3 nodes).
inline uint32_t block_index(const PbdModel& s, int32_t a, int32_t b, int32_t c) {
  const uint32_t n = uint32_t(s.ratio + 1);
  return uint32_t(a) + n * (uint32_t(b) + n * uint32_t(c));
}

inline uint32_t block_nodes(const PbdModel& s) { return uint32_t((s.ratio + 1) * (s.ratio + 1) * (s.ratio + 1)); }

inline Vec3d corner_rest(const PbdModel& s, int32_t I, int32_t J, int32_t K) {
  return s.origin + s.sim_size * Vec3d(I, J, K);
}

// Label of a fine node given by its block index in simulation voxel sv (kNoPiece: no material).
inline uint8_t label_at(const VoxelModel& model, const PbdModel& s, uint32_t sv, const int32_t svc[3], uint32_t b,
                        int32_t i, int32_t j, int32_t k) {
  if (!has_pieces(s, sv)) return kNoPiece;
  const uint32_t d = s.voxel_divided[sv];
  if (d == kDeadIndex) return fine_inside(model, i, j, k) ? 0 : kNoPiece;
  (void)svc;
  return s.labels[s.divided[d].first_label + b];
}

// Label of a fine node (global fine coordinates) in simulation voxel sv.
inline uint8_t node_label(const VoxelModel& model, const PbdModel& s, uint32_t sv, const int32_t svc[3], int32_t i,
                          int32_t j, int32_t k) {
  const uint32_t b = block_index(s, i - svc[0] * s.ratio, j - svc[1] * s.ratio, k - svc[2] * s.ratio);
  return label_at(model, s, sv, svc, b, i, j, k);
}

// ---- Labelling and relabelling (pbd_labels.cpp) --------------------------------------------

constexpr uint8_t kMaxSimPieces = 250;  // labels are uint8; more components than this merge into the last
constexpr int32_t kSpanRatio = 32;  // spans fit a 64-bit row mask up to this ratio

// Labels the fine nodes of a simulation voxel's block by material component: nodes are joined when a
// fine voxel of the block puts them in one piece (voxel_pieces: the fine level decides what material
// joins). Components are numbered in node order. Returns the count (0: no material).
uint8_t label_block(const VoxelModel& model, const CutState& cut, const PbdModel& s, uint32_t sv,
                    std::vector<uint32_t>& parent, uint8_t* labels);

// Material volume of each label of a block, in eighths of a fine voxel: each inside node adds one
// eighth for each of the block's fine voxels around it (1, 2, 4 or 8), so volumes partition exactly.
void label_eighths(const VoxelModel& model, const PbdModel& s, uint32_t sv, const uint8_t* labels, uint64_t eighths[256]);

// Gives the count labels of simulation voxel sv their piece slots: the first label whose first node
// held old label inherit[p] reuses that label's slot (old_slots), the others get new slots starting
// from its particles and rotation; old slots nobody inherits are freed. eighths: each label's volume.
void assign_slots(PbdModel& s, PbdData& data, uint32_t sv, uint8_t count, const uint64_t* eighths,
                  const uint8_t* inherit, const uint32_t* old_slots, uint8_t old_count);

// Label storage for simulation voxel sv (a divided voxel's labels and slots), created on first use.
uint32_t ensure_divided(PbdModel& s, uint32_t sv);

// Gives simulation voxel sv the pieces of `labels` (count components): storage as one piece or as a
// divided voxel, new piece slots inheriting particles and rotation from the old piece that held the
// same fine node (old labels in `old`, old slots in `old_slots`; `old_count` 0: no pieces before).
// Old slots nobody inherits are freed.
void set_voxel_pieces(const VoxelModel& model, PbdModel& s, PbdData& data, uint32_t sv, const uint8_t* labels,
                      uint8_t count, const uint8_t* old, const uint32_t* old_slots, uint8_t old_count);

// Splits the pieces of simulation voxel sv that the changed fine voxels [first, last) (in the block)
// separated. Cuts only remove material connections, so only labels of the changed voxels' nodes can
// split, and every node of such a label is joined to one of those nodes. A breadth-first search runs
// from all of them at once (one group per seed; groups that meet unite) and a label stops searching
// when one group of it is left running: the groups that ran out are new pieces, the one left keeps
// the label. The cost is the material around the new cut (the smaller side of a split), not the block.
// Returns false (having changed nothing) when the search grew past a quarter of the block: a full
// relabel is then cheaper (it looks each fine voxel up once, the search once per corner).
bool relabel_local(const VoxelModel& model, const CutState& cut, PbdModel& s, PbdData& data, uint32_t sv,
                   const uint32_t* first, const uint32_t* last);

// Relabels a whole (labelled) block; new pieces inherit from the old piece of the same node.
void relabel_block(const VoxelModel& model, const CutState& cut, PbdModel& s, PbdData& data, uint32_t sv);

// The block arrays' warm reserves: at init their address space and whole reserves, after a cut step
// a few more pages.
void warm_block_arrays(PbdModel& s, bool init);

// Records a divided fine voxel and its cut edges in its simulation voxel's cut record (idempotent:
// cuts only add).
void note_cut_voxel(const VoxelModel& model, PbdModel& s, const DividedVoxel& dv);

// Spans of a block (ratio <= 32): the block's inside nodes as runs along x joined by x edges,
// united across neighbouring rows where a y or z edge joins them. An edge with both ends inside joins
// them unless the blade cut it (every fine voxel holding it, uncut or divided, joins its ends then);
// the other joins are diagonal: an uncut voxel whose inside corners its edges do not connect joins
// them all, and a divided voxel with an outside corner joins across its uncut ambiguous faces — those
// voxels join their own pieces' corners (fine_pieces). This is label_block's rule, a row at a time:
// O(ratio^2) row masks plus the block's few diagonal voxels, instead of 8 lookups per fine voxel.
void build_spans(const VoxelModel& model, const CutState& cut, const PbdModel& s, uint32_t sv, SpanScratch& w);

// Numbers the components of the spans build_spans left in w (w.label per span), by their first span
// in row order, x order within a row: a component's first span holds its first node, so they are
// numbered in node order as label_block numbers them (past kMaxSimPieces, merged into the last).
// Writes each label's first node (block index) to first_node when given. Returns the count.
uint8_t number_spans(SpanScratch& w, uint32_t n, uint32_t* first_node);

// label_block's labels and count from the block's spans (ratio <= kSpanRatio): the same rule and
// numbering, O(ratio^2) row masks instead of 8 lookups and a union per fine voxel (it was ~60 % of
// world_init's instructions at 16 fine voxels per simulation voxel).
uint8_t label_block_spans(const VoxelModel& model, const CutState& cut, const PbdModel& s, uint32_t sv, SpanScratch& w,
                          uint8_t* labels);

// Whether the last cut step left the material components of block sv (ratio <= 32) as they were,
// shown by a short search: every pair of corners that one of its reshaped fine voxels
// (cut.reshaped_voxels[reshaped[i]], with their pieces before the step) joined before and no longer
// joins must still be joined through the block, within one span (a run of nodes along x joined by
// uncut x edges) or from one span through the row next to it (uncut y or z edges: build_spans' joins;
// an edge with both ends inside in the block lies in a fine voxel of the block). Cuts only remove
// joins and the old labels are the components before the step, so the labels stay exact then. False
// when the search finds no such join (the block is relabelled).
bool keeps_components(const VoxelModel& model, const CutState& cut, const PbdModel& s, uint32_t sv,
                      const uint32_t* reshaped, const uint32_t* reshaped_end);

// Relabels a whole block from its spans (ratio <= 32) when its components changed; new pieces inherit
// from the old piece of their first node. Labels are numbered in node order, as label_block numbers
// them. Cuts only split components and the old labels are the components before the cut, so the
// components changed exactly when their count did (below the label range): a cut that splits nothing
// (a slit still joined around its front) leaves the block alone. When they changed, calls
// before_write() before changing anything. Returns whether they changed.
template <typename BeforeWrite>
bool relabel_spans(const VoxelModel& model, const CutState& cut, PbdModel& s, PbdData& data, uint32_t sv,
                   PbdCutStats* stats, BeforeWrite&& before_write) {
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
  uint32_t first_node[256];
  const uint8_t count = number_spans(w, uint32_t(n), first_node);
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
  assign_slots(s, data, sv, count, eighths, inherit, old_slots, old_count);
  return true;
}

// ---- Slots, colour groups, corner particles (pbd_topology.cpp) ------------------------------

// A piece slot (from the free list, else a new one) for label `label` of simulation voxel sv: no
// particles, volume or colour yet.
uint32_t new_piece(PbdModel& s, PbdData& data, uint32_t sv, uint8_t label);

// A piece made from part of another (a cut) starts from its corner particles, its rotation's warm
// start and its incompatible modes' amplitudes (the global step corrects these at its next substep).
inline void inherit_piece(PbdModel& s, PbdData& data, uint32_t slot, uint32_t from) {
  std::copy(s.pieces[from].particles, s.pieces[from].particles + 8, s.pieces[slot].particles);
  data.rotation[slot] = data.rotation[from];
  std::copy_n(data.enhancement.begin() + 9 * ptrdiff_t(from), 9, data.enhancement.begin() + 9 * ptrdiff_t(slot));
}

// Returns a piece slot to the free list.
void free_piece(PbdModel& s, uint32_t slot);

// Mass of a particle from its eighths (exact: one rounding of an integer product).
void update_mass(PbdModel& s, uint32_t p);

// Key of particle pair (a, b), a <= b, in PbdModel::stretch_of.
uint64_t pair_key(uint32_t a, uint32_t b);

// A piece joins the dynamics: masses, constraint references, shape-matching colour.
void attach_piece(PbdModel& s, PbdData& data, uint32_t slot);

// The reverse of attach_piece.
void detach_piece(PbdModel& s, PbdData& data, uint32_t slot);

// Material of each octant of the pieces of simulation voxel sv (SimPiece::octants), from their labels:
// each inside node's eighths (one per block voxel around it, as label_eighths counts them) go to the
// octant holding the point halfway between the node and that voxel's centre (for ratio 1, the node's
// own corner octant). The octants of a piece sum to its eighths.
void piece_octants(const VoxelModel& model, PbdModel& s, uint32_t sv);

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

// Fills the members around corner (I,J,K) and unites those joined by a fine node on their common
// boundary: the 12 faces between the (up to) 8 simulation voxels around the corner.
void corner_groups(const VoxelModel& model, const PbdModel& s, int32_t I, int32_t J, int32_t K, CornerMembers& m,
                   FaceCache& cache);

// Assigns particles at coarse corner (I,J,K): one per material group of the pieces around it.
// Existing particles are kept where possible (the smallest not yet claimed by another group).
void assign_corner(const VoxelModel& model, PbdModel& s, PbdData& data, int32_t I, int32_t J, int32_t K,
                   CornerMembers& m);

// The face pairs of a face follow from the labels of its two simulation voxels alone, so the cache
// outlives a cut step: only the 6 faces of each relabelled voxel are forgotten. Their old pairs stay
// in the data until it is cleared whole (rarely: it grows by the faces a step recomputes).
void forget_faces(PbdModel& s, const std::vector<uint32_t>& relabelled);

// Coarse corner id (I,J,K) packed for sorting.
uint64_t corner_id(const PbdModel& s, int32_t I, int32_t J, int32_t K);

// The coarse corner (I,J,K) of a corner_id.
void corner_coords(const PbdModel& s, uint64_t id, int32_t& I, int32_t& J, int32_t& K);

// ---- Embedding, edits, embedding rows (pbd_embedding.cpp) ----------------------------------

// Embeds a live surface vertex slot: its fine piece's simulation voxel, one node of the fine piece,
// and its local position.
void embed_vertex(const VoxelModel& model, const CutState& cut, PbdModel& s, uint32_t slot);

// Grows the embedding with the surface's vertex slots. Capacity follows the surface's own (it keeps
// headroom for cuts): growing past a capacity copies every slot, a p99 spike of the cut step.
// The new capacity is touched right away (grown to it and shrunk back, which keeps the pages): the
// surface grows by about a thousand vertices per cutting step at 512, and first touches of their
// pages inside the steps cost ~0.1 ms each step on a virtual machine.
void grow_embedding(const CutState& cut, PbdModel& s, PbdData& data);

constexpr uint64_t kNoRows = ~uint64_t(0);  // PbdCache::embed_revision of rows to build from scratch

// Reserves the edit records and lists to their bounds (init_pbd), so a cut step does not allocate.
void reserve_edits(PbdEdits& e);

// Records what a pbd_apply_cut changed: the re-embedded slots, the relabelled voxels, the particles
// whose pieces or masses changed (sorted). Records every cache has seen are dropped first; all of
// them when they outgrow a bound (a cache not read every step then rebuilds once).
void record_edits(const CutState& cut, PbdModel& s, const PbdData& data, const std::vector<uint32_t>& voxels,
                  const std::vector<uint64_t>* particles);

// The rows of the embedded slots, following the contact index's slot pieces (labels are looked up
// once per model, cut or slot count, by refresh_slots): after one update of the index only the
// slots it revisited, else all (grouped by piece, so the interpolation reads each piece's corners
// in a run).
void refresh_embed_rows(const CutState& cut, const PbdModel& s, PbdData& data);

// Contact points (contact_points.cpp): brings the contact index's vertex slots up to date with the
// surface (after init and every cut), and gathers this step's plane and piece contacts (the
// contact points to build spread over `tasks`: the same bits whatever the worker count).
void refresh_slots(const CutState& cut, const PbdModel& s, PbdData& data);
// The contact index (slots, contact points made stale, the bodies) brought up to the model; touches
// only data.piece_contacts, so it may run beside refresh_blocks (which touches only data.cache).
// gather_contacts calls it first (a no-op when it is up to date).
void refresh_contact_index(const CutState& cut, const PbdModel& s, PbdData& data);
// Whether gather_contacts gathers anything (planes or piece contact).
bool contacts_on(const PbdModel& s);
void gather_contacts(const CutState& cut, const PbdModel& s, PbdData& data, const TaskRunner& tasks);

}  // namespace pbd_internal
}  // namespace dvx
