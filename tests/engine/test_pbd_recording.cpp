// The shipped recording with the physics: the severed top of the head is a free body (no particle
// shared with the rest) and falls clear of it.
#include "engine/recording.h"
#include "engine/session.h"
#include "sim/pbd.h"
#include "support.h"

#include <doctest/doctest.h>

#include <algorithm>
#include <numeric>

using namespace dvx;

namespace {

uint32_t find(std::vector<uint32_t>& parent, uint32_t x) {
  while (parent[x] != x) x = parent[x] = parent[parent[x]];
  return x;
}

void unite(std::vector<uint32_t>& parent, uint32_t a, uint32_t b) {
  a = find(parent, a);
  b = find(parent, b);
  if (a != b) parent[std::max(a, b)] = std::min(a, b);
}

}  // namespace

TEST_SUITE("pbd_recording") {
  TEST_CASE("the default recording's severed head top shares no particle with the body and lands on the tray beside it") {
    const Recording recording = read_recording(dvx_test::source_path("assets/recordings/bunny_cut.jsonl"));
    Session s;
    open_session(recording.scene, recording.dt, true, 1, s);
    size_t line = 0;
    for (uint32_t step = 0; step <= recording.last_step(); ++step) {
      StepCommands commands;
      for (; line < recording.steps.size() && recording.steps[line].step == step; ++line) {
        const RecordedStep& r = recording.steps[line];
        if (!r.has_blade) continue;
        commands.has_blade = true;
        commands.blade = r.blade;
        commands.cutting = r.cutting;
      }
      session_step(s, commands);
    }
    const PbdState& pbd = *s.pbd;
    std::string error;
    REQUIRE_MESSAGE(check_pbd_state(s.model, s.cut, pbd, error), error);
    // Surface components (vertex slots joined by triangles).
    const CutSurface& surface = s.cut.surface;
    std::vector<uint32_t> component(surface.positions.size());
    std::iota(component.begin(), component.end(), 0u);
    for (const Tri& t : surface.triangles) {
      if (t[0] == kDeadIndex) continue;
      unite(component, t[0], t[1]);
      unite(component, t[0], t[2]);
    }
    // Particle components (particles joined by the pieces using them).
    std::vector<uint32_t> body(pbd.rest.size());
    std::iota(body.begin(), body.end(), 0u);
    for (const SimPiece& piece : pbd.pieces) {
      if (piece.sim_voxel == kDeadIndex) continue;
      for (int c = 1; c < 8; ++c) unite(body, piece.particles[0], piece.particles[c]);
    }
    // The two surface components, the smaller one being the head top.
    std::vector<uint32_t> roots;
    std::vector<size_t> sizes;
    for (uint32_t v = 0; v < surface.positions.size(); ++v) {
      if (surface.vertex_piece[v] == CutSurface::kFreeKey) continue;
      const uint32_t r = find(component, v);
      const auto it = std::find(roots.begin(), roots.end(), r);
      if (it == roots.end()) {
        roots.push_back(r);
        sizes.push_back(1);
      } else {
        ++sizes[size_t(it - roots.begin())];
      }
    }
    REQUIRE(roots.size() == 2);
    const uint32_t head = sizes[0] < sizes[1] ? roots[0] : roots[1];
    // No particle of the head is a particle of the body; the head fell below the body.
    std::vector<uint32_t> head_bodies, rest_bodies;
    double head_min_y = 1e30, head_max_x = -1e30, rest_min_x = 1e30, head_drop = 0.0;
    size_t head_vertices = 0, unembedded = 0;
    for (uint32_t v = 0; v < surface.positions.size(); ++v) {
      if (surface.vertex_piece[v] == CutSurface::kFreeKey) continue;
      const uint32_t piece = vertex_sim_piece(pbd, v);
      if (piece == kDeadIndex) {
        ++unembedded;
        continue;
      }
      const bool is_head = find(component, v) == head;
      for (uint32_t p : pbd.pieces[piece].particles) (is_head ? head_bodies : rest_bodies).push_back(find(body, p));
      if (is_head) {
        head_min_y = std::min(head_min_y, double(pbd.deformed[v].y()));
        head_max_x = std::max(head_max_x, double(pbd.deformed[v].x()));
        head_drop += double(surface.positions[v].y() - pbd.deformed[v].y());
        ++head_vertices;
      } else {
        rest_min_x = std::min(rest_min_x, double(pbd.deformed[v].x()));
      }
    }
    std::sort(head_bodies.begin(), head_bodies.end());
    std::sort(rest_bodies.begin(), rest_bodies.end());
    std::vector<uint32_t> shared;
    std::set_intersection(head_bodies.begin(), head_bodies.end(), rest_bodies.begin(), rest_bodies.end(),
                          std::back_inserter(shared));
    CHECK(unembedded == 0);
    CHECK(shared.empty());
    // It fell, and lies on the scene's tray (lowest point within half a fine voxel of the plane) in
    // front of the body (the cut slopes down to -x), not on the stump or inside the body.
    REQUIRE(recording.scene.planes.size() == 1);
    const double tray_y = recording.scene.planes[0].point.y();
    const double half_voxel = 0.5 * s.model.lattice.voxel_size;
    MESSAGE("head top: mean drop " << head_drop / double(head_vertices) << ", lowest point " << head_min_y
                                   << " (tray at " << tray_y << "), right end x " << head_max_x
                                   << "; body's left end x " << rest_min_x);
    CHECK(head_drop / double(head_vertices) > 2.0);
    CHECK(head_min_y > tray_y - half_voxel);
    CHECK(head_min_y < tray_y + half_voxel);
    CHECK(head_max_x < rest_min_x);
  }
}
