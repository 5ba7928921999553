// Internals of the simulation pieces shared by the PBD files (pbd.cpp: building, relabelling,
// embedding, solver; contact_points.cpp: contact points and their caches). Not for engine/, bench/ or
// ui/ (tests/layers_test.sh): they use sim/pbd.h and sim/world.h.
#pragma once

#include "sim/pbd.h"

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
inline bool edits_replayable(const PbdState& s, const CutState& cut, uint64_t seen, uint64_t revision, uint64_t cut_steps,
                      bool surface) {
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

// Contact points (contact_points.cpp): brings the contact index's vertex slots up to date with the
// surface (after init and every cut), and gathers this step's plane and piece contacts.
void refresh_slots(const CutState& cut, PbdState& s);
void gather_contacts(const CutState& cut, PbdState& s);

}  // namespace pbd_internal
}  // namespace dvx
