// The session: one simulation stepped by commands. Determinism over worker counts, the blade's
// keep-last-pose rule, cutting only while `cutting`, the scene's PBD parameters.
#include "engine/scene.h"
#include "engine/session.h"
#include "support.h"

#include <doctest/doctest.h>

using namespace dvx;

namespace {

Scene small_bunny() {
  Scene scene = load_scene(dvx_test::source_path("assets/scenes/bunny.json"));
  scene.pbd.resolution = 32;
  scene.pbd.sim_resolution = 4;
  return scene;
}

StepCommands blade_command(double x, bool cutting) {
  StepCommands c;
  c.has_blade = true;
  c.blade = {Vec3d(x, 6.0, -5), Vec3d(x, 6.0, 5)};
  c.cutting = cutting;
  return c;
}

}  // namespace

TEST_SUITE("session") {
  TEST_CASE("the same commands give the same state hash with 1 and with 3 workers, step by step") {
    Session one, three;
    open_session(small_bunny(), 1.0 / 60.0, true, 1, one);
    open_session(small_bunny(), 1.0 / 60.0, true, 3, three);
    CHECK(session_hash(one) == session_hash(three));
    for (int i = 0; i <= 12; ++i) {
      const StepCommands c = blade_command(-6.0 + i, i > 0);
      session_step(one, c);
      session_step(three, c);
      CAPTURE(i);
      REQUIRE(session_hash(one) == session_hash(three));
    }
    CHECK(one.state.step == 13);
    CHECK(one.state.cut.divided.size() > 0);
  }

  TEST_CASE("a step without a blade keeps the last pose and cuts nothing, only a cutting sweep cuts") {
    Session s;
    open_session(small_bunny(), 1.0 / 60.0, false, 1, s);
    const uint64_t uncut = session_hash(s);
    // Moving the blade without cutting changes nothing.
    session_step(s, blade_command(-6.0, false));
    session_step(s, blade_command(6.0, false));
    CHECK(session_hash(s) == uncut);
    CHECK(s.state.cut.divided.empty());
    // Steps without a command keep the pose (and the cutting flag): no sweep, no cut.
    StepReport idle = session_step(s, StepCommands());
    CHECK(s.state.have_blade);
    CHECK(s.state.blade.a.x() == 6.0);
    CHECK(idle.cut.voxels_cut == 0);
    // A cutting sweep back across the body cuts.
    const StepReport cut = session_step(s, blade_command(-6.0, true));
    CHECK(cut.cutting);
    CHECK(cut.cut.voxels_cut > 0);
    CHECK(session_hash(s) != uncut);
    // Holding the blade still while cutting cuts nothing more.
    const uint64_t after = session_hash(s);
    const StepReport still = session_step(s, StepCommands());
    CHECK(still.cutting);
    CHECK(still.cut.voxels_cut == 0);
    CHECK(session_hash(s) == after);
    CHECK(s.state.step == 5);
  }

  TEST_CASE("the PBD parameters come from the scene and the time step") {
    Scene scene = small_bunny();
    scene.pbd.density = 1234;
    scene.pbd.iterations = 7;
    scene.pbd.gravity = Vec3d(0, 0, -1);
    const PbdParams p = pbd_params(scene, 0.02);
    CHECK(p.density == 1234);
    CHECK(p.iterations == 7);
    CHECK(p.dt == 0.02);
    CHECK(p.gravity == Vec3d(0, 0, -1));
    CHECK(p.resolution == 32);
    CHECK(p.sim_resolution == 4);
    CHECK(p.fixed.size() == scene.pbd.fixed.size());
  }
}
