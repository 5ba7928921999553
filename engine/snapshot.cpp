#include "engine/snapshot.h"

#include <algorithm>
#include <limits>

namespace dvx {

void fill_snapshot(Snapshot& slot, uint64_t slot_sequence, const CutSurface& surface,
                   const std::vector<Vec3f>* deformed, DirtyHistory& history, uint32_t step,
                   const StepTimings& timings) {
  // This publish's dirty range joins the history of the last DirtyHistory::kKept publishes.
  const uint64_t sequence = history.first_sequence + history.ranges.size();
  history.ranges.emplace_back(surface.dirty_triangle_begin, surface.dirty_triangle_end);
  while (history.ranges.size() > DirtyHistory::kKept) {
    history.ranges.erase(history.ranges.begin());
    ++history.first_sequence;
  }
  // Positions: deformed where the physics runs, else the rest surface; free slots NaN.
  const size_t vertices = surface.positions.size();
  slot.positions.resize(vertices);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (size_t v = 0; v < vertices; ++v) {
    if (surface.vertex_piece[v] == CutSurface::kFreeKey) {
      slot.positions[v] = Vec3f::Constant(nan);
    } else {
      slot.positions[v] = deformed != nullptr && v < deformed->size() ? (*deformed)[v] : surface.positions[v];
    }
  }
  // Triangles: the union of the ranges this slot missed, or everything.
  const size_t triangles = surface.triangles.size();
  uint32_t begin = 0, end = uint32_t(triangles);
  const bool incremental = slot_sequence >= history.first_sequence && slot.triangles.size() <= triangles;
  if (incremental) {
    begin = std::numeric_limits<uint32_t>::max();
    end = 0;
    for (uint64_t s = slot_sequence + 1; s <= sequence; ++s) {
      const auto& r = history.ranges[size_t(s - history.first_sequence)];
      if (r.first < r.second) {
        begin = std::min(begin, r.first);
        end = std::max(end, r.second);
      }
    }
    const uint32_t old_size = uint32_t(slot.triangles.size());
    if (old_size < triangles) {  // new slots at the end are always copied
      begin = std::min(begin, old_size);
      end = uint32_t(triangles);
    }
  }
  slot.triangles.resize(triangles);
  slot.triangle_flags.resize(triangles);
  if (begin < end) {
    std::copy(surface.triangles.begin() + begin, surface.triangles.begin() + end, slot.triangles.begin() + begin);
    std::copy(surface.triangle_cut.begin() + begin, surface.triangle_cut.begin() + end,
              slot.triangle_flags.begin() + begin);
  }
  // What changed since the previous snapshot (for the renderer's upload).
  slot.dirty_triangle_begin = surface.dirty_triangle_begin;
  slot.dirty_triangle_end = surface.dirty_triangle_end;
  slot.step = step;
  slot.timings = timings;
}

void shadow_casters(const Snapshot& snapshot, std::vector<Vec3f>& out) {
  const uint32_t n = uint32_t(snapshot.positions.size());
  out.assign(n, Vec3f::Constant(std::numeric_limits<float>::quiet_NaN()));
  for (const Tri& t : snapshot.triangles) {
    if (t[0] >= n || t[1] >= n || t[2] >= n) continue;  // a free triangle slot
    for (uint32_t v : t) out[v] = snapshot.positions[v];
  }
}

}  // namespace dvx
