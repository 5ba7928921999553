// Contact points of the simulation pieces (sim/contact.h): each piece's representative surface
// points and rest normals, kept per vertex slot and rebuilt only for the pieces a cut touched; the
// plane and piece-against-piece contacts gathered each step for the solver.
#include "sim/pbd_internal.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>

namespace dvx {
namespace pbd_internal {
namespace {

// ---- Contact hook (sim/contact.h) ----------------------------------------------------------

// The corner positions of a piece (corner c = dx | dy<<1 | dz<<2), read once for all its points.
void piece_corner_positions(const PbdModel& s, const PbdData& data, uint32_t piece, Vec3d corners[8]) {
  for (int c = 0; c < 8; ++c) corners[c] = data.position[s.pieces[piece].particles[c]];
}

// The deformed position of a surface point at rest coordinates `local` in its piece (corner
// positions `corners`), and its trilinear weights: weights[c] = (f_x f_y) f_z, f_a = u_a or 1 - u_a
// by the corner's side (each f_x f_y formed once).
void slot_point(const Vec3d corners[8], const Vec3f& local, Vec3d& point, double weights[8]) {
  const double u = local.x(), v = local.y(), w = local.z();
  const double fu[2] = {1.0 - u, u}, fv[2] = {1.0 - v, v}, fw[2] = {1.0 - w, w};
  double fuv[4];
  for (int c = 0; c < 4; ++c) fuv[c] = fu[c & 1] * fv[c >> 1];
  Vec3d sum = Vec3d::Zero();  // not summed in `point`, which may alias the corners for the compiler
  for (int c = 0; c < 8; ++c) {
    weights[c] = fuv[c & 3] * fw[c >> 2];
    sum += weights[c] * corners[c];
  }
  point = sum;
}

// The slots of each piece from scratch (counting sort: ascending within a piece).
void build_slots(const PbdModel& s, PbdData& data, uint32_t slots, uint32_t pieces) {
  ContactIndex& x = data.piece_contacts.index;
  x.slot_piece.resize(slots);
  x.piece_begin.assign(pieces + 1, 0);
  for (uint32_t slot = 0; slot < slots; ++slot) {
    const uint32_t piece = embedded_piece(s, s.embedding[slot]);
    x.slot_piece[slot] = piece;
    if (piece != kDeadIndex) ++x.piece_begin[piece + 1];
  }
  for (uint32_t i = 0; i < pieces; ++i) x.piece_begin[i + 1] += x.piece_begin[i];
  x.piece_slots.resize(x.piece_begin[pieces]);
  x.scratch.assign(x.piece_begin.begin(), x.piece_begin.end() - 1);
  for (uint32_t slot = 0; slot < slots; ++slot) {
    if (x.slot_piece[slot] != kDeadIndex) x.piece_slots[x.scratch[x.slot_piece[slot]]++] = slot;
  }
}

// The slots whose piece the recorded cuts may have changed: the re-embedded ones, the new ones, and
// those of the relabelled voxels' pieces -- before (a vertex keeps its node, whose label may now name
// another piece slot) and after. Their pieces before are the current pieces of the voxels relabelled
// since (a piece slot is made only by a relabel) and the slots freed since.
void collect_revisited(const PbdModel& s, uint32_t slots, ContactIndex& x) {
  const PbdEdits& e = s.edits;
  const EditRange from = edits_after(e, x.edits);
  std::vector<uint32_t>& out = x.revisited;
  out.clear();
  out.insert(out.end(), e.slots.begin() + from.slots, e.slots.end());
  for (uint32_t slot = x.slots; slot < slots; ++slot) out.push_back(slot);
  const auto add_piece = [&](uint32_t piece) {
    if (piece < x.pieces) out.insert(out.end(), x.piece_slots.begin() + x.piece_begin[piece], x.piece_slots.begin() + x.piece_begin[piece + 1]);
  };
  for (size_t v = from.voxels; v < e.voxels.size(); ++v) {
    const uint32_t sv = e.voxels[v];
    if (v > from.voxels && e.voxels[v - 1] == sv) continue;
    for_pieces(s, sv, add_piece);
  }
  if (from.voxels != e.voxels.size()) {
    for (uint32_t i = 0; i < x.pieces; ++i) {
      if (s.pieces[i].sim_voxel == kDeadIndex) add_piece(i);
    }
  }
  sorted_unique(out);
}

// Brings the slots of each piece up to date from the recorded cuts: looks up the revisited slots'
// pieces, then copies the piece lists that did not change and merges the others (the same arrays a
// build from scratch makes).
void update_slots(const PbdModel& s, PbdData& data, uint32_t slots, uint32_t pieces) {
  ContactIndex& x = data.piece_contacts.index;
  collect_revisited(s, slots, x);
  x.slot_piece.resize(slots, kDeadIndex);
  x.arrivals.clear();
  x.changed.clear();
  x.flipped.clear();
  x.scratch.assign(pieces, 0);  // new count minus old count, wrapping
  for (uint32_t slot : x.revisited) {
    const uint32_t now = embedded_piece(s, s.embedding[slot]), was = x.slot_piece[slot];
    if (now == was) continue;
    if ((now == kDeadIndex) != (was == kDeadIndex)) x.flipped.push_back(slot);
    x.slot_piece[slot] = now;
    if (was != kDeadIndex) {
      --x.scratch[was];
      x.changed.push_back(was);
    }
    if (now != kDeadIndex) {
      ++x.scratch[now];
      x.changed.push_back(now);
      x.arrivals.push_back(uint64_t(now) << 32 | slot);
    }
  }
  sorted_unique(x.changed);
  std::sort(x.arrivals.begin(), x.arrivals.end());
  // New offsets.
  const auto old_count = [&](uint32_t i) { return i < x.pieces ? x.piece_begin[i + 1] - x.piece_begin[i] : 0u; };
  x.next_begin.resize(pieces + 1);
  x.next_begin[0] = 0;
  for (uint32_t i = 0; i < pieces; ++i) x.next_begin[i + 1] = x.next_begin[i] + old_count(i) + x.scratch[i];
  x.next_slots.resize(x.next_begin[pieces]);
  // Unchanged pieces between changed ones: one copy per run; changed ones: old slots still there
  // merged with the arrivals (both ascending).
  uint32_t next = 0;  // first piece not yet written
  size_t a = 0;
  const auto copy_run = [&](uint32_t end) {
    const uint32_t stop = std::min(end, x.pieces);
    if (next < stop) {
      std::copy(x.piece_slots.begin() + x.piece_begin[next], x.piece_slots.begin() + x.piece_begin[stop],
                x.next_slots.begin() + x.next_begin[next]);
    }
  };
  for (uint32_t i : x.changed) {
    copy_run(i);
    uint32_t* out = x.next_slots.data() + x.next_begin[i];
    const uint32_t* old = i < x.pieces ? x.piece_slots.data() + x.piece_begin[i] : nullptr;
    const uint32_t* old_end = old ? x.piece_slots.data() + x.piece_begin[i + 1] : nullptr;
    while (a < x.arrivals.size() && uint32_t(x.arrivals[a] >> 32) == i) {
      const uint32_t slot = uint32_t(x.arrivals[a]);
      for (; old != old_end && *old < slot; ++old) {
        if (x.slot_piece[*old] == i) *out++ = *old;
      }
      *out++ = slot;
      ++a;
    }
    for (; old != old_end; ++old) {
      if (x.slot_piece[*old] == i) *out++ = *old;
    }
    next = i + 1;
  }
  copy_run(pieces);
  x.piece_begin.swap(x.next_begin);
  x.piece_slots.swap(x.next_slots);
}

}  // namespace

// Brings the slots of each piece (ContactIndex: slot_piece, piece_begin, piece_slots) up to date
// with the model and the surface: from the recorded cuts when it can, else from scratch.
void refresh_slots(const CutState& cut, const PbdModel& s, PbdData& data) {
  ContactIndex& x = data.piece_contacts.index;
  const uint32_t slots = uint32_t(std::min(s.embedding.size(), cut.surface.positions.size()));
  const uint32_t pieces = uint32_t(s.pieces.size());
  if (x.revision == s.revision && x.cut_steps == cut.steps && x.slots == slots && x.pieces == pieces &&
      x.triangle_count == cut.surface.triangles.size()) {
    x.edits = s.edits.count();  // records without a change (a cut step that cut nothing)
    return;
  }
  x.rebuilt = !(edits_replayable(s, cut, x.edits, x.revision, x.cut_steps, true) && slots >= x.slots && pieces >= x.pieces);
  if (x.rebuilt) {
    x.revisited.clear();
    build_slots(s, data, slots, pieces);
  } else {
    update_slots(s, data, slots, pieces);
  }
  x.revisited_since = x.cut_steps;
  x.revision = s.revision;
  x.cut_steps = cut.steps;
  x.edits = s.edits.count();
  x.slots = slots;
  x.pieces = pieces;
  x.triangle_count = uint32_t(cut.surface.triangles.size());
  ++x.updates;
}

namespace {

void refresh_reps(const CutState& cut, const PbdModel& s, PbdData& data);
void refresh_quad_blocks(const CutState& cut, const PbdModel& s, PieceContacts& pc);

// Brings the contact index (sim/contact.h) up to date when a cut changed the model or the surface:
// the piece of each vertex slot and the slots of each piece (refresh_slots), which pieces can move,
// the bodies (O(pieces), from scratch).
void refresh_index(const CutState& cut, const PbdModel& s, PbdData& data) {
  refresh_slots(cut, s, data);
  refresh_reps(cut, s, data);
  refresh_quad_blocks(cut, s, data.piece_contacts);
  ContactIndex& x = data.piece_contacts.index;
  PieceContacts& pc = data.piece_contacts;
  if (x.bodies_updates == x.updates) return;
  x.bodies_updates = x.updates;
  const uint32_t pieces = x.pieces, particles = uint32_t(data.position.size());
  // Live pieces, their corners, whether they can move (a piece pinned at every corner cannot be pushed).
  pc.corners.resize(size_t(pieces) * 8);
  pc.live.assign(pieces, 0);
  x.mobile.assign(pieces, 0);
  for (uint32_t i = 0; i < pieces; ++i) {
    if (s.pieces[i].sim_voxel == kDeadIndex) continue;  // free slot
    pc.live[i] = 1;
    std::copy(s.pieces[i].particles, s.pieces[i].particles + 8, pc.corners.begin() + 8 * size_t(i));
    for (uint32_t p : s.pieces[i].particles) x.mobile[i] = x.mobile[i] || s.inv_mass[p] > 0.0;
  }
  // Bodies (only piece-piece contact needs them), numbered in order of their first piece.
  x.bodies = 0;
  x.body_index.assign(pieces, ~0u);
  if (!s.params.piece_contact) return;
  find_bodies(pc.corners.data(), pc.live.data(), pieces, particles, pc.body, pc.scratch);
  x.scratch.assign(particles, ~0u);
  for (uint32_t i = 0; i < pieces; ++i) {
    if (!pc.live[i]) continue;
    uint32_t& number = x.scratch[pc.body[i]];
    if (number == ~0u) number = x.bodies++;
    x.body_index[i] = number;
  }
}

// Whether the three corners of a live triangle are embedded (slots the index knows, in a piece):
// only such triangles give the contact points' rest normals.
bool embedded_triangle(const ContactIndex& x, const Tri& tri) {
  for (uint32_t v : tri) {
    if (v >= x.slots || x.slot_piece[v] == kDeadIndex) return false;
  }
  return true;
}

// How far each live piece may move in this step: (its fastest corner's speed + g dt) dt (what bounds
// its contact reach: a piece's own, so a falling piece does not widen everyone's).
void piece_motions(const PbdModel& s, PbdData& data) {
  PieceContacts& pc = data.piece_contacts;
  const double dt = s.params.dt, fall = s.params.gravity.norm() * dt;
  pc.motion.assign(s.pieces.size(), 0.0);
  for (uint32_t i = 0; i < s.pieces.size(); ++i) {
    if (s.pieces[i].sim_voxel == kDeadIndex) continue;
    double speed2 = 0.0;
    for (uint32_t p : s.pieces[i].particles) {
      if (s.inv_mass[p] > 0.0) speed2 = std::max(speed2, data.velocity[p].squaredNorm());
    }
    pc.motion[i] = (std::sqrt(speed2) + fall) * dt;
  }
}

// build_stale_reps hands its pieces to the workers in chunks of at least this many (a piece on a
// cut face at 16 fine voxels per simulation voxel: ~300 slots, ~600 triangles).
constexpr uint32_t kRepPiecesPerChunk = 4;

// A new stamp for `marks` (an entry equal to it was marked since): 1, 2, ... and all entries reset
// when the count wraps.
uint32_t next_stamp(std::vector<uint32_t>& marks, uint32_t& stamp) {
  if (++stamp == 0) {
    std::fill(marks.begin(), marks.end(), 0u);
    stamp = 1;
  }
  return stamp;
}

// Adds to the list of quad `quad`'s block the simulation voxels of the four fine voxels around its
// lattice edge (none when the slot is free).
void note_quad_block(const CutState& cut, const PbdModel& s, std::vector<QuadBlock>& blocks, uint32_t quad) {
  const uint64_t key = cut.surface.quad_half_edge[quad];
  if (key == CutSurface::kFreeKey) return;
  const Lattice& l = cut.lattice;
  const uint32_t edge = uint32_t(key / 2);
  const int axis = int(edge % 3);
  int32_t n[3];
  l.node_coords(edge / 3, n);
  const int32_t dims[3] = {l.nx, l.ny, l.nz};
  // The voxels around the edge: n - 1 and n across it, n along it (within the lattice), as
  // simulation voxel coordinates.
  int32_t lo[3], hi[3];
  for (int a = 0; a < 3; ++a) {
    lo[a] = std::max(0, a == axis ? n[a] : n[a] - 1) / s.ratio;
    hi[a] = std::min(dims[a] - 1, n[a]) / s.ratio;
  }
  QuadBlock& b = blocks[quad / kQuadBlock];
  for (int32_t k = lo[2]; k <= hi[2] && !b.all; ++k) {
    for (int32_t j = lo[1]; j <= hi[1] && !b.all; ++j) {
      for (int32_t i = lo[0]; i <= hi[0] && !b.all; ++i) {
        const uint32_t sv = sim_voxel_id(s, i, j, k);
        if (std::find(b.voxels, b.voxels + b.count, sv) != b.voxels + b.count) continue;
        if (b.count == kQuadBlockVoxels) {
          b.all = true;
        } else {
          b.voxels[b.count++] = sv;
        }
      }
    }
  }
}

// Brings the quad blocks' lists up to the surface: from the quads the last surface update wrote when
// they follow the update before it, else all of them from scratch (the first gather's, so not in the
// step that first scans: a sever).
void refresh_quad_blocks(const CutState& cut, const PbdModel& s, PieceContacts& pc) {
  if (pc.quad_blocks_changes == cut.surface_changes) return;
  const bool incremental = pc.quad_blocks_changes != ~uint64_t(0) && pc.quad_blocks_changes + 1 == cut.surface_changes;
  pc.quad_blocks_changes = cut.surface_changes;
  const uint32_t quads = uint32_t(cut.surface.quad_half_edge.size());
  const size_t blocks = (size_t(quads) + kQuadBlock - 1) / kQuadBlock;
  if (!incremental) {
    pc.quad_blocks.assign(blocks, QuadBlock{});
    for (uint32_t q = 0; q < quads; ++q) note_quad_block(cut, s, pc.quad_blocks, q);
    return;
  }
  pc.quad_blocks.resize(blocks, QuadBlock{});
  for (const uint32_t q : cut.touched_quads) {
    if (q < quads) note_quad_block(cut, s, pc.quad_blocks, q);
  }
}

// Marks stale the contact points of the pieces whose points a cut may have changed, after the
// contact index's update (refresh_slots): a piece's points follow from its slots, their rest
// positions and the live triangles around them whose corners are embedded, so after one index
// update and one change of the surface (CutState::touched_vertices) since the last call, only the
// pieces whose slots changed and the pieces of the simulation voxels around the vertices the cut
// moved or re-triangulated and the slots that became embedded or stopped being so (a triangle
// around a vertex has its corners in the fine voxels next to the vertex's) are rebuilt, on their
// next need; otherwise all are. The points of the others stay where they are in `reps`, which is
// compacted when mostly stale.
void refresh_reps(const CutState& cut, const PbdModel& s, PbdData& data) {
  PieceContacts& pc = data.piece_contacts;
  const ContactIndex& x = pc.index;
  if (pc.rep_updates == x.updates && pc.rep_surface_changes == cut.surface_changes) return;
  const bool index_changed = pc.rep_updates != x.updates;
  const bool incremental = pc.rep_updates != ~uint64_t(0) && (!index_changed || (pc.rep_updates + 1 == x.updates && !x.rebuilt)) &&
                           cut.surface_changes - pc.rep_surface_changes <= 1 && pc.rep_begin.size() <= x.pieces;
  pc.rep_updates = x.updates;
  const bool surface_changed = pc.rep_surface_changes != cut.surface_changes;
  pc.rep_surface_changes = cut.surface_changes;
  if (!incremental) {
    pc.rep_begin.assign(x.pieces, ~0u);
    pc.rep_count.assign(x.pieces, 0);
    pc.reps.clear();
    pc.rep_pending.clear();  // all stale: built on need
    return;
  }
  // A piece a cut made stale (or made) is pending: built ahead once settled (build_settled_reps).
  const uint32_t before = uint32_t(pc.rep_begin.size());
  pc.rep_begin.resize(x.pieces, ~0u);
  pc.rep_count.resize(x.pieces, 0);
  pc.rep_stale_at.resize(x.pieces, ~uint64_t(0));
  const auto pend = [&](uint32_t piece) {
    if (pc.rep_stale_at[piece] != pc.rep_clock) pc.rep_pending.push_back(piece);  // once a gather
    pc.rep_stale_at[piece] = pc.rep_clock;
  };
  for (uint32_t piece = before; piece < x.pieces; ++piece) pend(piece);
  const auto stale = [&](uint32_t piece) {
    if (piece >= x.pieces) return;
    pc.rep_begin[piece] = ~0u;
    pend(piece);
  };
  if (index_changed) {
    for (uint32_t piece : x.changed) stale(piece);
  }
  // The simulation voxels within one fine voxel of a vertex (the vertex's own, and across the faces
  // it is next to), consecutive repeats left out.
  std::vector<uint32_t>& near = pc.rep_voxels;
  near.clear();
  const Lattice& l = cut.lattice;
  const CutSurface& surface = cut.surface;
  const int32_t dims[3] = {l.nx, l.ny, l.nz};
  if (pc.slot_marks.size() < surface.vertex_patch.size()) pc.slot_marks.resize(surface.vertex_patch.size(), 0u);
  const uint32_t stamp = next_stamp(pc.slot_marks, pc.slot_stamp);
  const auto around = [&](uint32_t slot) {
    if (slot >= surface.vertex_patch.size() || surface.vertex_patch[slot] == CutSurface::kFreeKey) return;
    if (pc.slot_marks[slot] == stamp) return;  // a repeat (the lists name a vertex once per quad)
    pc.slot_marks[slot] = stamp;
    int32_t vc[3], lo[3], hi[3];
    l.voxel_coords(uint32_t(surface.vertex_patch[slot] / 16), vc);
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::max(0, vc[a] - 1) / s.ratio;
      hi[a] = std::min(dims[a] - 1, vc[a] + 1) / s.ratio;
    }
    for (int32_t k = lo[2]; k <= hi[2]; ++k) {
      for (int32_t j = lo[1]; j <= hi[1]; ++j) {
        for (int32_t i = lo[0]; i <= hi[0]; ++i) {
          const uint32_t sv = sim_voxel_id(s, i, j, k);
          if (near.empty() || near.back() != sv) near.push_back(sv);
        }
      }
    }
  };
  // Slots that became embedded or stopped being so change their neighbours' normals; those that
  // moved or were re-triangulated, theirs and their neighbours'.
  if (index_changed) {
    for (uint32_t slot : x.flipped) around(slot);
  }
  if (surface_changed) {
    for (uint32_t slot : cut.touched_vertices) around(slot);
  }
  sorted_unique(near);
  for (uint32_t sv : near) for_pieces(s, sv, stale);
  // Compaction: the live pieces' points to the front, in piece order.
  size_t live = 0;
  for (uint32_t i = 0; i < x.pieces; ++i) live += pc.rep_begin[i] != ~0u ? pc.rep_count[i] : 0;
  if (pc.reps.size() > 2 * live + 4096) {
    std::vector<ContactRep>& kept = pc.rep_kept;
    kept.clear();
    for (uint32_t i = 0; i < x.pieces; ++i) {
      if (pc.rep_begin[i] == ~0u) continue;
      const uint32_t begin = uint32_t(kept.size());
      kept.insert(kept.end(), pc.reps.begin() + pc.rep_begin[i], pc.reps.begin() + pc.rep_begin[i] + pc.rep_count[i]);
      pc.rep_begin[i] = begin;
    }
    pc.reps.swap(kept);
  }
}

// The most contact points a piece has: one per contact cell and direction.
constexpr uint32_t kRepEntries = kContactCells * kContactCells * kContactCells * 6;

// The area vector of triangle `tri` (rest positions): twice its area along its normal.
inline Vec3d triangle_area(const CutSurface& surface, const Tri& tri) {
  const Vec3d a = surface.positions[tri[0]].cast<double>(), b = surface.positions[tri[1]].cast<double>(),
              c = surface.positions[tri[2]].cast<double>();
  return (b - a).cross(c - a);
}

// The rest normals of piece `piece`'s slots (normal[n] for its n-th slot): area-weighted sums over
// the live triangles holding each whose three corners are embedded, in ascending triangle order,
// found through the quads around the slots (vertex_quads, each quad once). Writes only `quads` and
// the entries of `slot_index` of the piece's own slots (n), which it leaves at ~0u again (a slot is
// in one piece: pieces may be built at once).
void piece_rest_normals(const CutState& cut, const ContactIndex& x, uint32_t piece, uint32_t* slot_index,
                        std::vector<uint32_t>& quads, Vec3d* normal) {
  const CutSurface& surface = cut.surface;
  const uint32_t first = x.piece_begin[piece], count = x.piece_begin[piece + 1] - first;
  std::fill(normal, normal + count, Vec3d::Zero());
  for (uint32_t n = 0; n < count; ++n) slot_index[x.piece_slots[first + n]] = n;
  quads.clear();
  for (uint32_t n = 0; n < count; ++n) {
    uint32_t around[kMaxVertexQuads];
    const uint32_t found = vertex_quads(cut, x.piece_slots[first + n], around);
    quads.insert(quads.end(), around, around + found);
  }
  sorted_unique(quads);  // a quad joins up to four of the slots
  for (const uint32_t quad : quads) {
    for (const uint32_t t : {2 * quad, 2 * quad + 1}) {
      const Tri& tri = surface.triangles[t];
      if (!embedded_triangle(x, tri)) continue;
      const Vec3d area = triangle_area(surface, tri);
      for (int k = 0; k < 3; ++k) {
        if (x.slot_piece[tri[k]] == piece) normal[slot_index[tri[k]]] += area;
      }
    }
  }
  for (uint32_t n = 0; n < count; ++n) slot_index[x.piece_slots[first + n]] = ~0u;
}

// The rest normals of the slots of many pieces at once, in one pass over the surface's quads near
// them: slot_index[v] is the entry of `normal` of each slot v to build (~0u: none), `wanted` the
// slots to sum as bits (all of them, or one part's), `sim_wanted` the simulation voxels of their
// pieces as bits. A block of quads whose list (PieceContacts::quad_blocks) names none of those
// simulation voxels holds no triangle with a corner to build and is passed over; in the others, a
// quad none of whose corners is to be built costs six bit tests. Each live triangle whose three
// corners are embedded adds its area vector to the entries of its wanted corners, in ascending
// triangle order (the sums piece_rest_normals forms).
void scan_rest_normals(const CutState& cut, const PieceContacts& pc, const uint32_t* slot_index,
                       const uint64_t* wanted, const uint64_t* sim_wanted, Vec3d* normal) {
  const CutSurface& surface = cut.surface;
  const ContactIndex& x = pc.index;
  const uint32_t quads = uint32_t(surface.triangles.size() / 2), slots = x.slots;
  // A free quad's triangles name kDeadIndex (>= slots); a corner beyond the index is not embedded.
  const auto is_wanted = [&](uint32_t v) { return v < slots && ((wanted[v >> 6] >> (v & 63)) & 1u); };
  const auto block_wanted = [&](const QuadBlock& b) {
    if (b.all) return true;
    for (uint32_t k = 0; k < b.count; ++k) {
      if ((sim_wanted[b.voxels[k] >> 6] >> (b.voxels[k] & 63)) & 1u) return true;
    }
    return false;
  };
  for (uint32_t block = 0; block * kQuadBlock < quads; ++block) {
    if (!block_wanted(pc.quad_blocks[block])) continue;
    const uint32_t end = std::min(quads, (block + 1) * kQuadBlock);
    for (uint32_t q = block * kQuadBlock; q < end; ++q) {
      const Tri& first = surface.triangles[2 * q];
      const Tri& second = surface.triangles[2 * q + 1];
      const bool any = is_wanted(first[0]) | is_wanted(first[1]) | is_wanted(first[2]) | is_wanted(second[0]) |
                       is_wanted(second[1]) | is_wanted(second[2]);
      if (!any || surface.quad_half_edge[q] == CutSurface::kFreeKey) continue;
      for (const Tri* tri : {&first, &second}) {
        if (!embedded_triangle(x, *tri)) continue;
        const Vec3d area = triangle_area(surface, *tri);
        for (int k = 0; k < 3; ++k) {
          if (is_wanted((*tri)[k])) normal[slot_index[(*tri)[k]]] += area;  // this part's slots only
        }
      }
    }
  }
}

// The contact points of piece `piece` (sim/contact.h "Contact points") from the rest normals of its
// slots (normal[n]: its n-th slot's): in each cell of a grid of contact_cells(ratio)^3 cells over its
// simulation voxel (in its rest frame) and each of six normal directions (the dominant axis of the
// rest normal and its sign), the slot nearest the cell's centre (ties: the lowest), into out[0 ..)
// by slot; returns how many (at most kRepEntries).
uint32_t choose_piece_reps(const PbdModel& s, const PbdData& data, uint32_t piece, const Vec3d* normal, ContactRep* out) {
  const ContactIndex& x = data.piece_contacts.index;
  const uint32_t first = x.piece_begin[piece], count = x.piece_begin[piece + 1] - first;
  const int cells = contact_cells(s.ratio);
  uint32_t best[kRepEntries];
  double best_d[kRepEntries];
  uint16_t used[kRepEntries];  // the entries taken, in order of first use
  uint32_t used_count = 0;
  std::fill(best, best + kRepEntries, ~0u);
  for (uint32_t n = 0; n < count; ++n) {
    const uint32_t slot = x.piece_slots[first + n];
    if (!(normal[n].squaredNorm() > 0.0)) continue;  // on no live triangle: no normal (norm() > 0 exactly then)
    const Vec3f& local = s.embedding[slot].local;
    int entry = 0;
    double d = 0.0;
    for (int a = 2; a >= 0; --a) {
      // The cell: floor(local * cells) clamped to [0, cells - 1]; truncation gives the same after the
      // clamp (they differ only below 0) without a call to floor.
      const int c = std::max(0, std::min(cells - 1, int(double(local[a]) * cells)));
      entry = entry * cells + c;
      const double off = double(local[a]) * cells - (c + 0.5);
      d += off * off;
    }
    int axis = 0;
    normal[n].cwiseAbs().maxCoeff(&axis);
    entry = entry * 6 + 2 * axis + (normal[n][axis] < 0.0);
    if (best[entry] == ~0u) used[used_count++] = uint16_t(entry);
    if (best[entry] == ~0u || d < best_d[entry]) {  // slots ascending: ties keep the lowest
      best[entry] = n;
      best_d[entry] = d;
    }
  }
  uint32_t chosen[kRepEntries];
  for (uint32_t e = 0; e < used_count; ++e) chosen[e] = best[used[e]];
  std::sort(chosen, chosen + used_count);  // by slot (ascending within the piece)
  for (uint32_t e = 0; e < used_count; ++e) {
    const Vec3d n = normal[chosen[e]].normalized();
    out[e] = ContactRep{x.piece_slots[first + chosen[e]], {float(n.x()), float(n.y()), float(n.z())}};
  }
  return used_count;
}

// The contact points of piece `piece`, built since the last cut that changed it (refresh_reps,
// build_stale_reps before each gather).
std::pair<const ContactRep*, uint32_t> piece_reps(const PieceContacts& pc, uint32_t piece) {
  return {pc.reps.data() + pc.rep_begin[piece], pc.rep_count[piece]};
}

// Builds the contact points of the pieces in `list` whose points are stale (refresh_reps), before a
// gather reads them (piece_reps): each piece's rest normals (one scan of the surface for a large
// batch, else through the quads around its slots), then its points into its own entries of a
// staging area, the pieces in chunks through `tasks`; then appended to reps in the list's order.
// A piece's points depend only on the model and the rest surface (the same bits whatever the
// worker count, the batch or the way its triangles were found), and are chosen on its first need
// after a cut changed it, so they never flicker between steps. A batch holding more slots than the
// surface's triangles / PieceContacts::rep_slots_per_scan (4096) is scanned: a few reads for each
// block of 16 quads, ~15 instructions for each quad of the blocks near the batch; a smaller one goes
// through the half-edge map around each slot (vertex_quads: ~5 lookups a slot, mostly cache misses,
// ~870 ns a slot measured). At 256 (647 000 triangles, 20 000 blocks) the pass over the blocks costs
// about what 150 slots cost through the map, and a piece has ~220: nearly every batch is scanned.
void build_stale_reps(const CutState& cut, const PbdModel& s, PbdData& data, const TaskRunner& tasks, const std::vector<uint32_t>& list) {
  PieceContacts& pc = data.piece_contacts;
  const ContactIndex& x = pc.index;
  std::vector<uint32_t>& build = pc.rep_build;
  std::vector<uint32_t>& offset = pc.rep_offset;  // of each piece's slots in the batch
  build.clear();
  offset.assign(1, 0);
  for (const uint32_t piece : list) {
    if (pc.rep_begin[piece] != ~0u) continue;
    build.push_back(piece);
    offset.push_back(offset.back() + x.piece_begin[piece + 1] - x.piece_begin[piece]);
  }
  if (build.empty()) return;
  const uint32_t n = uint32_t(build.size()), slots = offset.back();
  const bool scan = slots > x.triangle_count / std::max(1u, pc.rep_slots_per_scan);
  if (pc.rep_scratch.size() < x.slots) pc.rep_scratch.resize(x.slots, ~0u);
  uint32_t* slot_index = pc.rep_scratch.data();
  std::vector<Vec3d>& normal = pc.rep_normal;  // of the batch's slots, by piece then slot
  normal.resize(slots);
  if (scan) {
    // A large batch is scanned in two parts at once, its pieces split at the median of their
    // simulation voxels along the axis the batch spans most: each part reads the blocks near its
    // own pieces and sums only their slots (a slot is in one piece, a piece in one part), each slot
    // over its triangles in ascending order, so the bits do not depend on the split.
    // (PieceContacts::rep_slots_per_part: 16 384; a sever at 256 builds ~100 000 slots, and their
    // scan took ~3.5 ms in one part.)
    const uint32_t parts = slots >= pc.rep_slots_per_part ? 2 : 1;
    pc.counters.scans_split += parts == 2;
    const size_t slot_words = (size_t(x.slots) + 63) / 64, voxel_words = (size_t(s.sx) * size_t(s.sy) * size_t(s.sz) + 63) / 64;
    std::vector<uint64_t>& wanted = pc.rep_wanted;         // (parts x slot_words)
    std::vector<uint64_t>& sim_wanted = pc.rep_sim_voxels;  // (parts x voxel_words)
    wanted.assign(parts * slot_words, 0u);
    sim_wanted.assign(parts * voxel_words, 0u);
    std::vector<uint32_t>& part = pc.rep_part;  // of each piece of the batch
    part.assign(n, 0u);
    if (parts == 2) {
      // Simulation voxel coordinates (i, j, k) of each piece, the axis of the largest extent, and the
      // pieces ranked along it (ties by batch order).
      std::vector<uint64_t>& rank = pc.rep_rank;
      int32_t lo[3] = {s.sx, s.sy, s.sz}, hi[3] = {-1, -1, -1};
      const auto coords = [&](uint32_t i, int32_t c[3]) {
        const uint32_t sv = s.pieces[build[i]].sim_voxel;
        c[0] = int32_t(sv % uint32_t(s.sx));
        c[1] = int32_t(sv / uint32_t(s.sx) % uint32_t(s.sy));
        c[2] = int32_t(sv / uint32_t(s.sx) / uint32_t(s.sy));
      };
      for (uint32_t i = 0; i < n; ++i) {
        int32_t c[3];
        coords(i, c);
        for (int a = 0; a < 3; ++a) {
          lo[a] = std::min(lo[a], c[a]);
          hi[a] = std::max(hi[a], c[a]);
        }
      }
      int axis = 0;
      for (int a = 1; a < 3; ++a) axis = hi[a] - lo[a] > hi[axis] - lo[axis] ? a : axis;
      rank.resize(n);
      for (uint32_t i = 0; i < n; ++i) {
        int32_t c[3];
        coords(i, c);
        rank[i] = uint64_t(uint32_t(c[axis])) << 32 | i;
      }
      std::nth_element(rank.begin(), rank.begin() + n / 2, rank.end());
      for (uint32_t r = n / 2; r < n; ++r) part[uint32_t(rank[r])] = 1;
    }
    // Each part marks its slots, scans, and unmarks them (slot_index is read only through a part's
    // own bits, so the parts share it).
    const TaskBatch scans{parts, 1};
    run_batches(tasks, &scans, 1, [&](uint32_t, uint32_t begin, uint32_t end) {
      for (uint32_t p = begin; p < end; ++p) {
        uint64_t* part_wanted = wanted.data() + p * slot_words;
        uint64_t* part_voxels = sim_wanted.data() + p * voxel_words;
        // f(entry, slot) over the slots of the part's pieces.
        const auto part_slots = [&](auto&& f) {
          for (uint32_t i = 0; i < n; ++i) {
            if (part[i] != p) continue;
            const uint32_t first = x.piece_begin[build[i]];
            for (uint32_t k = offset[i]; k < offset[i + 1]; ++k) f(k, x.piece_slots[first + k - offset[i]]);
          }
        };
        for (uint32_t i = 0; i < n; ++i) {
          if (part[i] != p) continue;
          const uint32_t sv = s.pieces[build[i]].sim_voxel;
          part_voxels[sv >> 6] |= uint64_t(1) << (sv & 63);
        }
        part_slots([&](uint32_t k, uint32_t slot) {
          normal[k] = Vec3d::Zero();
          slot_index[slot] = k;
          part_wanted[slot >> 6] |= uint64_t(1) << (slot & 63);
        });
        scan_rest_normals(cut, pc, slot_index, part_wanted, part_voxels, normal.data());
        part_slots([&](uint32_t, uint32_t slot) { slot_index[slot] = ~0u; });
      }
    });
  }
  pc.rep_staged.resize(size_t(n) * kRepEntries);
  pc.rep_staged_count.resize(n);
  const PbdModel& model = s;
  const PbdData& data_read = data;  // the workers read the index only
  const auto run = [&](uint32_t, uint32_t begin, uint32_t end) {
    std::vector<uint32_t> quads;
    for (uint32_t i = begin; i < end; ++i) {
      if (!scan) piece_rest_normals(cut, x, build[i], slot_index, quads, normal.data() + offset[i]);
      pc.rep_staged_count[i] = uint16_t(choose_piece_reps(model, data_read, build[i], normal.data() + offset[i], pc.rep_staged.data() + size_t(i) * kRepEntries));
    }
  };
  const TaskBatch batch{n, kRepPiecesPerChunk};
  run_batches(tasks, &batch, 1, run);
  pc.counters.reps_scanned += scan ? n : 0;
  for (uint32_t i = 0; i < n; ++i) {
    const uint32_t piece = build[i];
    ++pc.counters.reps_built;
    pc.rep_begin[piece] = uint32_t(pc.reps.size());
    pc.reps.insert(pc.reps.end(), pc.rep_staged.begin() + size_t(i) * kRepEntries,
                   pc.rep_staged.begin() + size_t(i) * kRepEntries + pc.rep_staged_count[i]);
    pc.rep_count[piece] = pc.rep_staged_count[i];
  }
}

// Builds ahead the contact points of the pending pieces (PieceContacts::rep_pending) that no cut
// touched in this gather, and of the pieces of the simulation voxels around them, whichever are
// stale, up to rep_ahead_slots slots; the others stay pending. When a stroke severs, the pieces
// paired across the new gap are those its cut touched and their neighbours (a piece's bounds span
// its whole simulation voxel, so the pieces beside a cut piece face the far side's): built as the
// blade leaves them, they are not all built in the step that severs. Only with piece contact (the
// plane gather builds its few pieces on need).
//
// Why the pieces within two simulation voxels: a piece's reach is capped at a simulation voxel, and
// the pieces beside a cut move as it opens; in `divvox bench contact`'s sliced bunny at 256, the
// pieces one simulation voxel around left 80-137 pieces to build in each step that severs (3-4 ms),
// two left 0-20.
constexpr int32_t kAheadRing = 2;
void build_settled_reps(const CutState& cut, const PbdModel& s, PbdData& data, const TaskRunner& tasks) {
  PieceContacts& pc = data.piece_contacts;
  const ContactIndex& x = pc.index;
  if (!s.params.piece_contact || pc.rep_pending.empty()) return;
  std::vector<uint32_t>& ahead = pc.rep_need;  // scratch (the gathers are done with it)
  ahead.clear();
  sorted_unique(pc.rep_pending);  // a piece pended again while pending
  const auto settled_stale = [&](uint32_t piece) {
    return piece < x.pieces && pc.rep_begin[piece] == ~0u && pc.rep_stale_at[piece] != pc.rep_clock &&
           s.pieces[piece].sim_voxel != kDeadIndex;
  };
  uint32_t slots = 0, kept = 0;
  for (const uint32_t piece : pc.rep_pending) {
    if (piece >= x.pieces || s.pieces[piece].sim_voxel == kDeadIndex) continue;  // gone
    if (pc.rep_stale_at[piece] == pc.rep_clock || slots >= pc.rep_ahead_slots) {
      pc.rep_pending[kept++] = piece;  // touched in this gather, or over this gather's share
      continue;
    }
    int32_t c[3];
    sim_voxel_coords(s, s.pieces[piece].sim_voxel, c);
    for (int32_t k = std::max(0, c[2] - kAheadRing); k <= std::min(s.sz - 1, c[2] + kAheadRing); ++k) {
      for (int32_t j = std::max(0, c[1] - kAheadRing); j <= std::min(s.sy - 1, c[1] + kAheadRing); ++j) {
        for (int32_t i = std::max(0, c[0] - kAheadRing); i <= std::min(s.sx - 1, c[0] + kAheadRing); ++i) {
          for_pieces(s, sim_voxel_id(s, i, j, k), [&](uint32_t near) {
            if (!settled_stale(near)) return;
            pc.rep_begin[near] = ~0u - 1;  // listed (build_stale_reps builds those at ~0u: reset below)
            slots += x.piece_begin[near + 1] - x.piece_begin[near];
            ahead.push_back(near);
          });
        }
      }
    }
  }
  pc.rep_pending.resize(kept);
  for (const uint32_t piece : ahead) pc.rep_begin[piece] = ~0u;
  std::sort(ahead.begin(), ahead.end());
  pc.counters.reps_ahead += ahead.size();
  build_stale_reps(cut, s, data, tasks, ahead);
}

// The deformed normal of a contact point of a piece (corner positions `corners`): its rest normal
// under the piece's trilinear map at the point (cofactor of the map's Jacobian J = [a b c]: (b x c,
// c x a, a x b) n). Column a sums, over the corners in order, the corner times its weight's derivative
// along axis a: the product of the other two factors (lower axis first), negated on the low side.
Vec3d deformed_normal(const Vec3d corners[8], const Vec3f& local, const float rest[3]) {
  const double u[3] = {local.x(), local.y(), local.z()};
  const double f[3][2] = {{1.0 - u[0], u[0]}, {1.0 - u[1], u[1]}, {1.0 - u[2], u[2]}};
  Vec3d column[3] = {Vec3d::Zero(), Vec3d::Zero(), Vec3d::Zero()};
  for (int c = 0; c < 8; ++c) {
    const int h0 = c & 1, h1 = (c >> 1) & 1, h2 = (c >> 2) & 1;
    const double d0 = f[1][h1] * f[2][h2], d1 = f[0][h0] * f[2][h2], d2 = f[0][h0] * f[1][h1];
    column[0] += (h0 ? d0 : -d0) * corners[c];
    column[1] += (h1 ? d1 : -d1) * corners[c];
    column[2] += (h2 ? d2 : -d2) * corners[c];
  }
  return column[1].cross(column[2]) * double(rest[0]) + column[2].cross(column[0]) * double(rest[1]) +
         column[0].cross(column[1]) * double(rest[2]);
}

// Gathers this step's contact points: the surface vertices that may reach a plane within the step,
// grouped by piece. A piece is skipped when even its lowest corner particle (every embedded point is a
// convex combination of the corners) stays out of reach.
void gather_plane_contacts(const CutState& cut, const PbdModel& s, PbdData& data, const TaskRunner& tasks) {
  ContactSet& set = data.contacts;
  contacts_clear(set);
  const std::vector<ContactPlane>& planes = s.params.planes;
  if (planes.empty()) return;
  const ContactIndex& x = data.piece_contacts.index;
  const uint32_t plane_count = uint32_t(std::min<size_t>(planes.size(), 32));
  // The planes each piece may reach (bit k: plane k), and the pieces that may reach one, whose
  // contact points are built first (build_stale_reps).
  std::vector<uint32_t>& near_planes = set.group_mask;
  std::vector<uint32_t>& near_pieces = data.piece_contacts.rep_need;
  near_planes.assign(x.pieces, 0u);
  near_pieces.clear();
  const auto reach_of = [&](uint32_t i) { return 2.0 * data.piece_contacts.motion[i] + 2.0 * s.sim_size / s.ratio; };
  for (uint32_t i = 0; i < x.pieces; ++i) {
    if (!x.mobile[i]) continue;  // free slot, or pinned at every corner
    const double reach = reach_of(i);
    uint32_t near = 0;
    for (uint32_t k = 0; k < plane_count; ++k) {
      double lowest = 1e300;
      for (uint32_t p : s.pieces[i].particles) lowest = std::min(lowest, plane_distance(planes[k], data.position[p]));
      if (lowest < reach) near |= 1u << k;
    }
    near_planes[i] = near;
    if (near != 0) near_pieces.push_back(i);
  }
  build_stale_reps(cut, s, data, tasks, near_pieces);
  for (const uint32_t i : near_pieces) {
    const double reach = reach_of(i);
    const uint32_t near = near_planes[i];
    const uint32_t* particles = s.pieces[i].particles;
    const auto [reps, count] = piece_reps(data.piece_contacts, i);
    Vec3d corners[8];
    piece_corner_positions(s, data, i, corners);
    for (uint32_t r = 0; r < count; ++r) {
      double weights[8], mobility = 0.0;
      Vec3d point;
      slot_point(corners, s.embedding[reps[r].slot].local, point, weights);
      for (int c = 0; c < 8; ++c) mobility += weights[c] * weights[c] * s.inv_mass[particles[c]];
      if (mobility == 0.0) continue;  // interpolates anchored particles only
      for (uint32_t k = 0; k < plane_count; ++k) {
        if (((near >> k) & 1u) && plane_distance(planes[k], point) < reach) {
          contacts_add(set, s.pieces[i].colour, i, plane_contact(planes[k], particles, weights));
        }
      }
    }
  }
  contacts_finish(set);
}

// Marks the vertex slots a cut made or moved since the last step as fresh (allowance = infinity).
// After one cut step only the slots it wrote (CutState::changed_vertices) can have moved; after none,
// none; otherwise every slot is compared.
void refresh_allowances(const CutState& cut, PieceContacts& pc) {
  const size_t slots = cut.surface.positions.size();
  const bool first = pc.seen.empty();
  if (first) {  // the first step: the surface as built is not fresh
    pc.seen = cut.surface.positions;
    pc.allowance.assign(slots, 0.0f);
  }
  const size_t before = std::min(pc.seen.size(), slots);
  pc.allowance.resize(slots, 0.0f);
  pc.seen.resize(slots, Vec3f::Constant(std::numeric_limits<float>::quiet_NaN()));
  const auto refresh = [&](size_t v) {
    if (pc.seen[v] == cut.surface.positions[v]) return;  // NaN never compares equal: new and freed slots too
    pc.seen[v] = cut.surface.positions[v];
    pc.allowance[v] = std::numeric_limits<float>::infinity();
  };
  const ContactIndex& x = pc.index;
  if (!first && cut.steps != pc.seen_steps && !x.rebuilt && x.cut_steps == cut.steps && x.revisited_since == pc.seen_steps) {
    // The index's last update followed the cuts since: the slots it revisited hold every slot they
    // re-embedded (one cut step may run several cut_divide calls, so CutState::steps moves by more
    // than one).
    for (uint32_t v : x.revisited) {
      if (v < slots) refresh(v);
    }
    for (size_t v = before; v < slots; ++v) refresh(v);
  } else if (!first && cut.steps == pc.seen_steps + 1) {
    for (uint32_t v : cut.changed_vertices) {
      if (v < slots) refresh(v);
    }
    for (size_t v = before; v < slots; ++v) refresh(v);
  } else if (first || cut.steps != pc.seen_steps) {
    for (size_t v = 0; v < slots; ++v) refresh(v);
  } else {
    for (size_t v = before; v < slots; ++v) refresh(v);
  }
  pc.seen_steps = cut.steps;
}

// The contact points of the exposed pieces within reach of a partner (by piece, then slot), with
// their allowances and deformed normals.
void gather_surface_points(const CutState& cut, const PbdModel& s, PbdData& data, const TaskRunner& tasks) {
  PieceContacts& pc = data.piece_contacts;
  const ContactIndex& x = pc.index;
  pc.points.clear();
  pc.gathered.clear();
  pc.rep_need.clear();
  for (uint32_t i = 0; i < x.pieces; ++i) {
    if (pc.exposed[i]) pc.rep_need.push_back(i);
  }
  build_stale_reps(cut, s, data, tasks, pc.rep_need);
  // The pieces in chunks (PieceContacts::point_pieces_per_chunk) over the workers, each into its own lists,
  // joined in chunk order: the arrays one pass in piece order makes, for any worker count. A slot is
  // in one piece, so each chunk writes only its own slots' allowances.
  const std::vector<uint32_t>& need = pc.rep_need;
  const size_t per_chunk = std::max(1u, pc.point_pieces_per_chunk);
  const uint32_t chunks = uint32_t((need.size() + per_chunk - 1) / per_chunk);
  if (pc.point_chunks.size() < chunks) pc.point_chunks.resize(chunks);
  const PbdModel& model = s;
  const PbdData& state = data;
  const TaskBatch batch{chunks, 1};
  run_batches(tasks, &batch, chunks > 0 ? 1 : 0, [&](uint32_t, uint32_t begin, uint32_t end) {
    for (uint32_t c = begin; c < end; ++c) {
      PieceContacts::PointChunk& out = pc.point_chunks[c];
      out.points.clear();
      out.gathered.clear();
      const size_t last = std::min(need.size(), size_t(c + 1) * per_chunk);
      for (size_t k = size_t(c) * per_chunk; k < last; ++k) {
        const uint32_t i = need[k];
        const auto [reps, count] = piece_reps(pc, i);
        partner_regions(pc.scratch, pc.lo.data(), pc.hi.data(), pc.reach.data(), i, out.region_lo, out.region_hi);
        Vec3d corners[8];
        piece_corner_positions(model, state, i, corners);
        for (uint32_t r = 0; r < count; ++r) {
          const uint32_t slot = reps[r].slot;
          const Vec3f& local = model.embedding[slot].local;
          SurfacePoint sp;
          sp.allowance = pc.allowance[slot];
          sp.slot = slot;
          slot_point(corners, local, sp.position, sp.weights);
          if (!in_regions(out.region_lo, out.region_hi, sp.position)) {
            pc.allowance[slot] = 0.0f;  // out of reach of other bodies: out of contact (as unpaired below)
            continue;
          }
          const Vec3d normal = deformed_normal(corners, local, reps[r].normal);
          const double length = normal.norm();
          out.gathered.push_back(slot);
          if (!(length > 0.0)) continue;  // a degenerate map: no normal (no allowance, see the caller)
          sp.normal = normal / length;
          std::copy(model.pieces[i].particles, model.pieces[i].particles + 8, sp.particles);
          sp.body = x.body_index[i];
          sp.piece = i;
          sp.reach = float(pc.reach[i]);
          out.points.push_back(sp);
        }
      }
    }
  });
  for (uint32_t c = 0; c < chunks; ++c) {
    const PieceContacts::PointChunk& chunk = pc.point_chunks[c];
    pc.points.insert(pc.points.end(), chunk.points.begin(), chunk.points.end());
    pc.gathered.insert(pc.gathered.end(), chunk.gathered.begin(), chunk.gathered.end());
  }
}

// Gathers this step's piece-piece contacts (sim/contact.h): bodies, exposed pieces, their surface
// vertices with deformed normals, the nearest facing vertex of another body.
void collect_piece_contacts(const CutState& cut, const PbdModel& s, PbdData& data, const TaskRunner& tasks) {
  PieceContacts& pc = data.piece_contacts;
  contacts_clear(pc.set);
  pc.exposed_pieces = 0;
  const uint32_t pieces = uint32_t(s.pieces.size()), particles = uint32_t(data.position.size());
  if (!s.params.piece_contact || pieces == 0) return;
  refresh_allowances(cut, pc);  // every step, so a cut is fresh when its sides first touch
  const ContactIndex& x = pc.index;
  if (x.bodies < 2) return;  // one body: nothing to collide with
  // Reach: two fine voxels (the two faces of a cut can sit a voxel apart at its rim) or a contact
  // cell (the spacing of the contact points), whichever is larger, plus twice what the piece moves
  // in a step; capped at a simulation voxel. A pair of pieces touches within the larger reach.
  const double fine = s.sim_size / s.ratio;
  const double base = std::max(2.0 * fine, s.sim_size / contact_cells(s.ratio));
  pc.lo.resize(pieces);
  pc.hi.resize(pieces);
  // The broad phase grows both boxes of a pair, each by its own growth, so it admits a pair within
  // the sum of the two; a pair may touch only within the larger reach. Each grown by its reach less
  // half the least reach any piece has (r_i + r_j - least >= max(r_i, r_j)) still admits every
  // such pair, and at rest (every reach the least) exactly those. (Grown by the full reach, an
  // exposed piece of the sliced bunny at 256 at rest had ~43 partners, each a region built and tested
  // per point; grown so, ~12, and a fifth fewer pieces exposed. The same points and contacts.)
  const double least = std::min(base, s.sim_size);
  pc.reach.assign(pieces, 0.0);
  pc.broad_reach.assign(pieces, 0.0);
  for (uint32_t i = 0; i < pieces; ++i) {
    if (!pc.live[i]) continue;
    pc.reach[i] = std::min(s.sim_size, base + 2.0 * pc.motion[i]);
    pc.broad_reach[i] = pc.reach[i] - 0.5 * least;
    pc.lo[i] = pc.hi[i] = data.position[s.pieces[i].particles[0]];
    for (uint32_t p : s.pieces[i].particles) {
      pc.lo[i] = pc.lo[i].cwiseMin(data.position[p]);
      pc.hi[i] = pc.hi[i].cwiseMax(data.position[p]);
    }
  }
  // Bodies near another body, then their pieces near another body's pieces.
  if (find_candidate_pieces(pc.lo.data(), pc.hi.data(), pc.broad_reach.data(), pc.live.data(), x.body_index.data(), x.bodies,
                            pieces, pc.scratch) == 0) {
    return;
  }
  // Through the pair cache (sim/contact.h PairCache), whose entries hold while a candidate moves no
  // more than a margin of a quarter simulation voxel from where it was cached (a margin of a contact
  // cell, half a simulation voxel at 8 fine voxels per simulation voxel, cost the default recording's
  // broad phase 0.62 M instructions a step instead of 0.54).
  pc.exposed_pieces = find_exposed_pieces_cached(pc.lo.data(), pc.hi.data(), pc.broad_reach.data(), pc.scratch.candidate.data(), pc.body.data(), pieces,
                                                 0.25 * s.sim_size, pc.exposed, pc.scratch, &pc.counters.piece_pairs);
  if (pc.exposed_pieces == 0) return;
  gather_surface_points(cut, s, data, tasks);
  ++pc.counters.gathers;
  pc.counters.points += pc.points.size();
  pc.counters.contacts += gather_piece_contacts(pc.points.data(), uint32_t(pc.points.size()), data.position[0].data(), particles,
                                                kMaxPush * fine, s.params.piece_friction, pc.set, pc.scratch,
                                                &pc.counters.point_pairs);
  contacts_finish(pc.set);
  pc.counters.contact_pairs += pc.set.group_begin.size() - 1;
  for (const uint32_t slot : pc.gathered) pc.allowance[slot] = 0.0f;  // dropped (no normal): no allowance
  for (const SurfacePoint& sp : pc.points) pc.allowance[sp.slot] = sp.allowance;
}

}  // namespace

void refresh_contact_index(const CutState& cut, const PbdModel& s, PbdData& data) { refresh_index(cut, s, data); }

bool contacts_on(const PbdModel& s) { return !s.params.planes.empty() || s.params.piece_contact; }

// This step's contacts with the planes and between pieces, from one index and the pieces' motions;
// the contact points the gathers need are built first, the pieces spread over `tasks`.
void gather_contacts(const CutState& cut, const PbdModel& s, PbdData& data, const TaskRunner& tasks) {
  contacts_clear(data.contacts);
  contacts_clear(data.piece_contacts.set);
  data.piece_contacts.exposed_pieces = 0;
  if (!contacts_on(s)) return;
  refresh_index(cut, s, data);
  piece_motions(s, data);
  gather_plane_contacts(cut, s, data, tasks);
  collect_piece_contacts(cut, s, data, tasks);
  build_settled_reps(cut, s, data, tasks);
  ++data.piece_contacts.rep_clock;
}

}  // namespace pbd_internal
}  // namespace dvx
