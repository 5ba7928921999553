// The window's tools (ui/tools.h) without a window: a tool switch in the middle of a drag ends the
// drag as its own tool's release (issue 32: a grab stayed pinned after pressing S mid-drag, and its
// release was taken for the end of a scalpel stroke, printing the previous cut's voxel count).
#include "ui/tools.h"

#include "render/camera.h"
#include "ui/sim_runner.h"

#include <doctest/doctest.h>

#include <string>

using namespace dvx;

namespace {

// A cube [-1, 1]^3 as a surface snapshot (outward-facing triangles), framed by the window's camera,
// the cursor at the view's centre (over the cube). The simulation runner is never opened: the tools'
// commands only queue up.
struct ToolScene {
  SimRunner sim;
  Snapshot shot;
  AppState app;
  Eigen::Vector2f centre{320.0f, 240.0f};

  ToolScene() {
    // Each face: its normal axis, the sign, and four corners counter-clockwise seen from outside.
    for (int axis = 0; axis < 3; ++axis) {
      for (float sign : {-1.0f, 1.0f}) {
        const int u = (axis + 1) % 3, v = (axis + 2) % 3;
        const uint32_t b = uint32_t(shot.positions.size());
        const float corners[4][2] = {{-1, -1}, {1, -1}, {1, 1}, {-1, 1}};
        for (const auto& c : corners) {
          Vec3f p;
          p[axis] = sign;
          p[u] = c[0];
          p[v] = sign > 0 ? c[1] : -c[1];
          shot.positions.push_back(p);
        }
        shot.triangles.push_back({b, b + 1, b + 2});
        shot.triangles.push_back({b, b + 2, b + 3});
      }
    }
    shot.triangle_flags.assign(shot.triangles.size(), 0);
    app.sim = &sim;
    app.current = &shot;
    app.status.ready = true;
    app.view.bounds.grow(Vec3d(-1, -1, -1));
    app.view.bounds.grow(Vec3d(1, 1, 1));
    app.view.radius = float(0.5 * app.view.bounds.extent().norm());
    app.view.voxel_size = 0.1f;
    app.tools.cut_depth = 0.5f;
    app.view.viewport = {640, 480};
    app.view.camera = frame_box(app.view.bounds, app.view.viewport.aspect());
    app.tools.cursor = centre;
    app.tools.have_cursor = app.tools.cursor_in_view = true;
  }

  // One frame of the mouse over the view: the button's state and the cursor `offset` pixels from the centre.
  void frame(bool left, float offset = 0.0f) {
    MouseFrame m;
    m.pixel = centre + Eigen::Vector2f(offset, 0.0f);
    m.delta = m.pixel - app.tools.cursor;
    m.left = left;
    m.free_mouse = true;
    app.tools.cursor = m.pixel;
    handle_tools(app, m);
  }
};

}  // namespace

TEST_SUITE("ui") {
  TEST_CASE("tools: S pressed mid-grab lets the tissue go, the held button starts no stroke, no cut is reported") {
    ToolScene s;
    AppState& app = s.app;
    app.tools.tool = Tool::kGrab;
    s.frame(true);
    REQUIRE(app.tools.grabbing);
    REQUIRE(app.tools.left_down);
    s.frame(true, 20.0f);
    const Vec3f pulled = app.tools.grab_target;
    CHECK(pulled != app.tools.grab_anchor);

    // The switch releases the grab (its marker and line are drawn only while `grabbing`).
    select_tool(app, Tool::kScalpel);
    CHECK(app.tools.tool == Tool::kScalpel);
    CHECK_FALSE(app.tools.grabbing);
    CHECK_FALSE(app.tools.left_down);
    CHECK(app.tools.await_release);
    // Still held and moved: no stroke starts (no blade command at all), nothing waits to be reported.
    s.frame(true, 40.0f);
    s.frame(true, 60.0f);
    CHECK_FALSE(app.tools.left_down);
    CHECK_FALSE(app.tools.blade_sent);
    s.frame(false, 60.0f);
    CHECK_FALSE(app.tools.await_release);
    CHECK_FALSE(app.tools.cut_pending);
    app.status.step = 1000;
    app.status.voxels_cut = 2576;  // a previous cut's count must not be reported for a grab
    report_cut(app);
    CHECK(app.panel.message.empty());

    // The next press starts a stroke as usual.
    s.frame(true);
    CHECK(app.tools.left_down);
    CHECK(app.tools.blade_sent);
    CHECK_FALSE(app.tools.last_cutting);
  }

  TEST_CASE("tools: G pressed mid-stroke ends the stroke (its release sent, its cut reported), a grab reports no cut") {
    ToolScene s;
    AppState& app = s.app;
    app.tools.tool = Tool::kScalpel;
    app.status.voxels_cut = 100;
    s.frame(true);
    REQUIRE(app.tools.left_down);
    s.frame(true, 30.0f);
    REQUIRE(app.tools.last_cutting);

    select_tool(app, Tool::kGrab);
    CHECK_FALSE(app.tools.left_down);
    CHECK_FALSE(app.tools.last_cutting);  // the release (cutting off) went out
    CHECK(app.tools.cut_pending);
    CHECK(app.tools.await_release);
    // Reported once the step after the release has run: the voxels cut since the press.
    app.status.voxels_cut = 105;
    app.status.step = app.tools.cut_release_stamp + 1;
    report_cut(app);
    CHECK_FALSE(app.tools.cut_pending);
    CHECK(app.panel.message.find("cut 5 voxels") != std::string::npos);

    // Held, then released, then a grab drag of its own: its release reports nothing.
    s.frame(true, 40.0f);
    CHECK_FALSE(app.tools.grabbing);
    s.frame(false, 40.0f);
    app.panel.message.clear();
    s.frame(true);
    REQUIRE(app.tools.grabbing);
    s.frame(true, 25.0f);
    s.frame(false, 25.0f);
    CHECK_FALSE(app.tools.grabbing);
    CHECK_FALSE(app.tools.cut_pending);
    app.status.step += 100;
    app.status.voxels_cut += 50;
    report_cut(app);
    CHECK(app.panel.message.empty());
  }

  TEST_CASE("tools: selecting the tool already in use, or switching between drags, changes nothing else") {
    ToolScene s;
    AppState& app = s.app;
    app.tools.tool = Tool::kGrab;
    s.frame(true);
    REQUIRE(app.tools.grabbing);
    select_tool(app, Tool::kGrab);
    CHECK(app.tools.grabbing);
    CHECK(app.tools.left_down);
    CHECK_FALSE(app.tools.await_release);
    s.frame(false);
    CHECK_FALSE(app.tools.grabbing);
    select_tool(app, Tool::kScalpel);
    CHECK_FALSE(app.tools.await_release);
    s.frame(true);
    CHECK(app.tools.left_down);
  }
}
