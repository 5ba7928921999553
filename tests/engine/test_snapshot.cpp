// Snapshots: an incrementally filled slot equals a fully copied one after any sequence of cuts, for
// every slot of the triple buffer; the exchange hands out the newest snapshot once.
#include "engine/scene.h"
#include "engine/session.h"
#include "engine/snapshot.h"
#include "support.h"

#include <doctest/doctest.h>

#include <cmath>

using namespace dvx;

namespace {

// Slot contents equal (NaN positions, the free slots, compare equal to each other).
bool same_surface(const Snapshot& a, const Snapshot& b) {
  if (a.positions.size() != b.positions.size() || a.triangles != b.triangles || a.triangle_flags != b.triangle_flags) {
    return false;
  }
  for (size_t v = 0; v < a.positions.size(); ++v) {
    const bool nan_a = std::isnan(a.positions[v].x()), nan_b = std::isnan(b.positions[v].x());
    if (nan_a != nan_b || (!nan_a && a.positions[v] != b.positions[v])) return false;
  }
  return true;
}

}  // namespace

TEST_SUITE("snapshot") {
  TEST_CASE("only the vertices of live triangles cast the tray's shadow") {
    // Slot 3 keeps a stale position (no live triangle uses it), triangle slot 1 is free.
    Snapshot snap;
    snap.positions = {Vec3f(0, 0, 0), Vec3f(1, 0, 0), Vec3f(0, 1, 0), Vec3f(5, 5, 5), Vec3f(7, 7, 7)};
    snap.triangles = {Tri{0, 1, 2}, Tri{kDeadIndex, kDeadIndex, kDeadIndex}};
    std::vector<Vec3f> casters;
    shadow_casters(snap, casters);
    REQUIRE(casters.size() == 5);
    for (int v = 0; v < 3; ++v) CHECK(casters[v] == snap.positions[v]);
    CHECK(std::isnan(casters[3].x()));
    CHECK(std::isnan(casters[4].x()));
  }

  TEST_CASE("incremental fills equal full copies for slots skipped 0 to 10 publishes") {
    Scene scene = load_scene(dvx_test::source_path("assets/scenes/bunny.json"));
    scene.pbd.resolution = 32;
    Session s;
    open_session(scene, 1.0 / 60.0, false, 1, s);
    // Slot k is refilled every k-th publish (k = 1 .. 10: beyond the 8 ranges kept, a full copy).
    std::vector<Snapshot> slots(11);
    std::vector<uint64_t> slot_sequence(11, 0);
    DirtyHistory history;
    for (uint32_t step = 0; step < 40; ++step) {
      StepCommands c;
      c.has_blade = true;
      c.cutting = step > 0;
      const double x = -6.0 + 0.3 * step, y = step < 20 ? 6.0 : 3.0;
      c.blade = {Vec3d(x, y, -5), Vec3d(x, y, 5)};
      const StepReport r = session_step(s, c);
      const uint64_t sequence = step + 1;
      Snapshot full;
      DirtyHistory fresh;
      fill_snapshot(full, 0, s.state.cut.surface, nullptr, fresh, step, r.timings);
      for (size_t k = 1; k < slots.size(); ++k) {
        if (sequence % k != 0 && step + 1 < 40) continue;
        // Slot 1 adds each publish's range to the shared history; the others fill from a copy without
        // that last range (fill_snapshot adds it back), each as if it were this publish's slot.
        if (k == 1) {
          fill_snapshot(slots[k], slot_sequence[k], s.state.cut.surface, nullptr, history, step, r.timings);
        } else {
          DirtyHistory copy = history;
          copy.ranges.pop_back();
          fill_snapshot(slots[k], slot_sequence[k], s.state.cut.surface, nullptr, copy, step, r.timings);
        }
        slot_sequence[k] = sequence;
        CAPTURE(step);
        CAPTURE(k);
        CHECK(same_surface(slots[k], full));
        CHECK(slots[k].step == step);
      }
      s.state.cut.surface.clear_dirty();
    }
    CHECK(s.state.cut.divided.size() > 0);
  }

  TEST_CASE("the exchange hands out the newest snapshot once, and finished() only when drained") {
    SnapshotExchange exchange;
    CHECK(exchange.take() == nullptr);
    for (uint32_t step = 0; step < 3; ++step) {
      exchange.publish([&](Snapshot& slot, uint64_t) { slot.step = step; }, false);
    }
    exchange.finish();
    CHECK_FALSE(exchange.finished());  // a fresh snapshot is still waiting
    const Snapshot* s = exchange.take();
    REQUIRE(s != nullptr);
    CHECK(s->step == 2);  // the newest; the older ones were overwritten
    CHECK(s->sequence == 3);
    CHECK(exchange.take() == nullptr);
    CHECK(exchange.finished());
  }
}
