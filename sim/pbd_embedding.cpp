// The embedding of the surface in the simulation pieces (sim/pbd.h "Embedding"): each vertex slot's
// piece node and local position, the edit records the caches follow cuts by, and the rows the
// deformed surface is interpolated from.
#include "sim/pbd_internal.h"

#include <algorithm>

namespace dvx {
namespace pbd_internal {

// ---- Embedding -----------------------------------------------------------------------------

// Embeds a live surface vertex slot: its fine piece's simulation voxel, one node of the fine piece,
// and its local position.
void embed_vertex(const VoxelModel& model, const CutState& cut, PbdModel& s, uint32_t slot) {
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
// headroom for cuts, sim/cut.cpp): growing past a capacity copies every slot, a p99 spike of the
// cut step. The capacity is reserved, not touched: its pages are mapped as the surface grows into
// them, a few each cutting step, as the surface's own arrays are. (Touching all of it at once cost
// the step that reserved it ~9 ms at 256.)
void grow_embedding(const CutState& cut, PbdModel& s, PbdData& data) {
  if (s.embedding.size() < cut.surface.positions.size()) {
    s.embedding.reserve(cut.surface.positions.capacity());  // no-ops unless the surface's grew
    data.deformed.reserve(cut.surface.positions.capacity());
    s.embedding.resize(cut.surface.positions.size(), VertexEmbedding{kDeadIndex, 0, Vec3f::Zero()});
    data.deformed.resize(cut.surface.positions.size(), Vec3f::Zero());
  }
}

// ---- Edits (PbdModel::edits) --------------------------------------------------------------

// Bounds of the edit records kept for a cache that is not read every step (reserved at init, so a
// cut step does not allocate for them).
constexpr size_t kEditRecords = 64, kEditEntries = 8192;

void reserve_edits(PbdEdits& e) {
  e.records.reserve(kEditRecords + 1);
  e.slots.reserve(2 * kEditEntries);
  e.voxels.reserve(kEditEntries / 8);
  e.particles.reserve(2 * kEditEntries);
}

namespace {

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

}  // namespace

// Records what a pbd_apply_cut changed: the re-embedded slots, the relabelled voxels, the particles
// whose pieces or masses changed (sorted). Records every cache has seen are dropped first; all of
// them when they outgrow a bound (a cache not read every step then rebuilds once).
void record_edits(const CutState& cut, PbdModel& s, const PbdData& data, const std::vector<uint32_t>& voxels,
                  const std::vector<uint64_t>* particles) {
  PbdEdits& e = s.edits;
  uint64_t seen = e.count();
  for (const uint64_t c : {data.piece_contacts.index.edits, data.cache.blocks_edits}) {
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

namespace {

// Sets the row of a vertex slot from its piece in the contact index (none: the slot keeps its rest
// position), swapping the last row into a removed one.
void set_embed_row(const CutState& cut, const PbdModel& s, PbdData& data, uint32_t slot) {
  const uint32_t piece = data.piece_contacts.index.slot_piece[slot];
  uint32_t& row = data.cache.embed_row_of[slot];
  if (piece != kDeadIndex) {
    const VertexEmbedding& e = s.embedding[slot];
    const EmbedRow r{slot, piece, e.local.x(), e.local.y(), e.local.z()};
    if (row == kDeadIndex) {
      row = uint32_t(data.cache.embed_rows.size());
      data.cache.embed_rows.push_back(r);
    } else {
      data.cache.embed_rows[row] = r;
    }
    return;
  }
  data.deformed[slot] = cut.surface.positions[slot];
  if (row == kDeadIndex) return;
  const EmbedRow last = data.cache.embed_rows.back();
  data.cache.embed_rows[row] = last;
  data.cache.embed_row_of[last.slot] = row;
  data.cache.embed_rows.pop_back();
  row = kDeadIndex;
}

}  // namespace

// The rows of the embedded slots, following the contact index's slot pieces (labels are looked up
// once per model, cut or slot count, by refresh_slots): after one update of the index only the
// slots it revisited, else all (grouped by piece, so the interpolation reads each piece's corners
// in a run).
void refresh_embed_rows(const CutState& cut, const PbdModel& s, PbdData& data) {
  refresh_slots(cut, s, data);
  const ContactIndex& x = data.piece_contacts.index;
  const bool valid = data.cache.embed_revision != kNoRows;
  if (valid && data.cache.embed_updates == x.updates) return;
  // A row per embedded slot at most: both to the capacity of the surface's slots (which keeps
  // headroom for cuts, grow_embedding), reserved and not touched, so a cut that adds rows does not
  // copy them all (at 256, 320 000 rows: a 3 ms step in the middle of a stroke when they doubled).
  data.cache.embed_rows.reserve(cut.surface.positions.capacity());
  data.cache.embed_row_of.reserve(cut.surface.positions.capacity());
  data.cache.embed_row_of.resize(x.slots, kDeadIndex);
  if (valid && data.cache.embed_updates + 1 == x.updates && !x.rebuilt) {
    for (uint32_t slot : x.revisited) set_embed_row(cut, s, data, slot);
  } else {
    data.cache.embed_rows.clear();
    std::fill(data.cache.embed_row_of.begin(), data.cache.embed_row_of.end(), kDeadIndex);
    for (uint32_t i = 0; i < x.pieces; ++i) {
      for (uint32_t n = x.piece_begin[i]; n < x.piece_begin[i + 1]; ++n) set_embed_row(cut, s, data, x.piece_slots[n]);
    }
    for (uint32_t slot = 0; slot < x.slots; ++slot) {
      if (x.slot_piece[slot] == kDeadIndex) data.deformed[slot] = cut.surface.positions[slot];
    }
  }
  data.cache.embed_revision = s.revision;
  data.cache.embed_updates = x.updates;
}

}  // namespace pbd_internal
}  // namespace dvx
