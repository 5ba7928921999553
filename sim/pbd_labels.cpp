// Pieces of the simulation voxels from the fine material (sim/pbd.h "Simulation voxels"): the labelling
// of a block by material component, and the relabelling after a cut (by spans up to kSpanRatio, else by
// a local search or node by node); the block arrays that hold labels and cut records.
#include "sim/pbd_internal.h"
#include "sim/union_find.h"

#include <algorithm>
#include <array>
#include <limits>

namespace dvx {
namespace pbd_internal {

constexpr uint32_t kLabelSlots = 256;   // piece slots per divided simulation voxel

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

// ---- Relabelling ---------------------------------------------------------------------------

// Gives the count labels of simulation voxel sv their piece slots: the first label whose first node
// held old label inherit[p] reuses that label's slot (old_slots), the others get new slots starting
// from its particles and rotation; old slots nobody inherits are freed. eighths: each label's volume.
void assign_slots(PbdModel& s, PbdData& data, uint32_t sv, uint8_t count, const uint64_t* eighths,
                  const uint8_t* inherit, const uint32_t* old_slots, uint8_t old_count) {
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
      slot = new_piece(s, data, sv, p);
      if (was != kNoPiece && was < old_count) {
        inherit_piece(s, data, slot, old_slots[was]);
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

namespace {

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

}  // namespace

// Label storage for simulation voxel sv (a divided voxel's labels and slots), created on first use.
uint32_t ensure_divided(PbdModel& s, uint32_t sv) {
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
void set_voxel_pieces(const VoxelModel& model, PbdModel& s, PbdData& data, uint32_t sv, const uint8_t* labels,
                      uint8_t count, const uint8_t* old, const uint32_t* old_slots, uint8_t old_count) {
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
  assign_slots(s, data, sv, count, eighths, inherit, old_slots, old_count);
}

// ---- Local relabelling after a cut ---------------------------------------------------------

namespace {

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
void materialise_labels(const VoxelModel& model, PbdModel& s, uint32_t sv) {
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

}  // namespace

// After relabel_local's search: groups that ran out are pieces of their own; per label one group
// keeps it (the one left running, else the first). Fills w.new_label (kNoPiece: keeps its label).
void assign_group_labels(LocalSearch& w, const uint8_t* labels, SimDivided& div) {
  const auto find = [&](uint32_t x) { return uf_find(w.parent.data(), x); };
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
}

// Relabels the searched nodes of the new pieces of simulation voxel sv (block coordinates c); their
// volumes move from the old piece to the new, which starts with the old one's particles and rotation.
// Clears the search's owners.
void apply_group_labels(const VoxelModel& model, PbdModel& s, PbdData& data, uint32_t sv, const int32_t c[3],
                        uint8_t* labels) {
  LocalSearch& w = s.scratch.search;
  SimDivided& div = s.divided[s.voxel_divided[sv]];
  const Lattice& l = model.lattice;
  const int32_t n = s.ratio + 1;
  const auto find = [&](uint32_t x) { return uf_find(w.parent.data(), x); };
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
      slot = new_piece(s, data, sv, to);
      inherit_piece(s, data, slot, old);
    }
    s.pieces[s.label_slots[div.first_slot + from]].eighths -= e;
    s.pieces[slot].eighths += e;
    labels[b] = to;
  }
  s.pieces_in_voxel[sv] = div.piece_count;
}

// Splits the pieces of simulation voxel sv that the changed fine voxels [first, last) (in the block)
// separated. Cuts only remove material connections, so only labels of the changed voxels' nodes can
// split, and every node of such a label is joined to one of those nodes. A breadth-first search runs
// from all of them at once (one group per seed; groups that meet unite) and a label stops searching
// when one group of it is left running: the groups that ran out are new pieces, the one left keeps
// the label. The cost is the material around the new cut (the smaller side of a split), not the block.
// Returns false (having changed nothing) when the search grew past a quarter of the block: a full
// relabel is then cheaper (it looks each fine voxel up once, the search once per corner).
bool relabel_local(const VoxelModel& model, const CutState& cut, PbdModel& s, PbdData& data, uint32_t sv,
                   const uint32_t* first, const uint32_t* last) {
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
  assign_group_labels(w, labels, div);
  apply_group_labels(model, s, data, sv, c, labels);
  return true;
}

// Relabels a whole (labelled) block; new pieces inherit from the old piece of the same node.
void relabel_block(const VoxelModel& model, const CutState& cut, PbdModel& s, PbdData& data, uint32_t sv) {
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
  set_voxel_pieces(model, s, data, sv, s.scratch.labels.data(), count, old, s.scratch.old_slots.data(), old_count);
}

// ---- Span relabelling ----------------------------------------------------------------------

namespace {

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

}  // namespace

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

namespace {

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

}  // namespace

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

uint8_t number_spans(SpanScratch& w, uint32_t n, uint32_t* first_node) {
  w.label.assign(w.mask.size(), kNoPiece);
  uint8_t count = 0;
  for (uint32_t row = 0; row < n * n; ++row) {
    for (uint32_t i = w.row_begin[row]; i < w.row_begin[row + 1]; ++i) {
      uint32_t root = i;
      while (w.parent[root] != root) root = w.parent[root];
      if (w.label[root] == kNoPiece && count < kMaxSimPieces) {
        if (first_node) first_node[count] = row * n + uint32_t(__builtin_ctzll(w.mask[i]));
        w.label[root] = count++;
      } else if (w.label[root] == kNoPiece) {
        w.label[root] = uint8_t(kMaxSimPieces - 1);  // beyond the label range: merged into the last
      }
      w.label[i] = w.label[root];
    }
  }
  return count;
}

uint8_t label_block_spans(const VoxelModel& model, const CutState& cut, const PbdModel& s, uint32_t sv, SpanScratch& w,
                          uint8_t* labels) {
  build_spans(model, cut, s, sv, w);
  const uint32_t n = uint32_t(s.ratio + 1), rows = n * n;
  const uint8_t count = number_spans(w, n, nullptr);
  std::fill(labels, labels + size_t(rows) * n, kNoPiece);
  for (uint32_t row = 0; row < rows; ++row) {
    for (uint32_t i = w.row_begin[row]; i < w.row_begin[row + 1]; ++i) {
      for (uint64_t m = w.mask[i]; m != 0; m &= m - 1) labels[row * n + uint32_t(__builtin_ctzll(m))] = w.label[i];
    }
  }
  return count;
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

// relabel_spans (the span relabelling itself) is a template, for its caller's detach step: in
// sim/pbd_internal.h.

}  // namespace pbd_internal
}  // namespace dvx
