// The playback module: a recording typed once, next_commands, the hash check and its physics-mode
// rule, and the one session writer whose recordings replay with every hash matching.
#include "engine/errors.h"
#include "engine/playback.h"
#include "engine/scene.h"
#include "sim/state_hash.h"
#include "support.h"

#include <doctest/doctest.h>
#include <nlohmann/json.hpp>

#include <fstream>
#include <limits>
#include <sstream>
#include <string>

using namespace dvx;
using dvx_test::TempDir;

namespace {

const std::string kHeader =
    R"({"format":"divvox-recording","version":1,"scene":{"mesh":"m.obj","resolution":32},"dt":0.01})";

using dvx_test::read_text;

// The shipped bunny at a small resolution (seconds to voxelize), with or without the physics.
void open_small_bunny(Session& session, bool physics) {
  Scene scene = load_scene(dvx_test::source_path("assets/scenes/bunny.json"));
  scene.pbd.resolution = 32;
  scene.pbd.sim_resolution = 4;
  open_session(scene, 1.0 / 60.0, physics, 1, session);
}

// A horizontal blade across the bunny at height y, at x.
BladePose blade_at(double x, double y) { return {Vec3d(x, y, -5), Vec3d(x, y, 5)}; }

}  // namespace

TEST_SUITE("playback") {
  TEST_CASE("a recording is typed once: lines of a step merge, grab and camera are parsed") {
    TempDir dir;
    const std::string file = dir.file(
        "r.jsonl", kHeader + "\n" +
                       R"({"step":0,"camera":{"target":[1,2,3],"distance":9,"yaw":0.5,"pitch":0.25}})" "\n"
                       R"({"step":0,"blade":[[0,0,0],[0,0,1]],"cutting":false})" "\n"
                       R"({"step":3,"grab":{"target":[1,2,3],"compliance":0.5}})" "\n"
                       R"({"step":3,"hash":"ABC"})" "\n"
                       R"({"step":7,"grab":"release","future":1})" "\n"
                       R"({"step":9,"grab":{"target":[1,2,3],"stiffness":500,"radius":0.015,"force_limit":30}})" "\n");
    const Playback p = load_playback(file);
    REQUIRE(p.steps.size() == 4);
    CHECK(p.last_step() == 9);
    const PlaybackStep& s0 = p.steps[0];
    CHECK(s0.step == 0);
    CHECK(s0.line == 2);
    CHECK(s0.commands.has_blade);
    CHECK_FALSE(s0.commands.cutting);
    CHECK(s0.commands.blade.b == Vec3d(0, 0, 1));
    REQUIRE(s0.has_camera);
    CHECK(s0.camera.target == Vec3f(1, 2, 3));
    CHECK(s0.camera.distance == 9.0f);
    CHECK(s0.camera.pitch == 0.25f);
    const PlaybackStep& s3 = p.steps[1];
    CHECK_FALSE(s3.commands.has_blade);
    CHECK(s3.commands.grab.kind == GrabCommand::kTarget);
    CHECK(s3.commands.grab.compliance == 0.5);
    CHECK(s3.commands.grab.stiffness == 0.0);  // the single-particle grab of older recordings
    CHECK(s3.has_hash);
    CHECK(s3.hash == "abc");
    CHECK(p.steps[2].commands.grab.kind == GrabCommand::kRelease);
    // The region grab, and its JSON written back as read.
    const GrabCommand& g = p.steps[3].commands.grab;
    CHECK(g.kind == GrabCommand::kTarget);
    CHECK(g.stiffness == 500.0);
    CHECK(g.radius == 0.015);
    CHECK(g.force_limit == 30.0);
    CHECK(grab_to_json(g) == nlohmann::json::parse(R"({"target":[1,2,3],"stiffness":500,"radius":0.015,"force_limit":30})"));
    CHECK(grab_to_json(s3.commands.grab) == nlohmann::json::parse(R"({"target":[1,2,3],"compliance":0.5})"));
  }

  TEST_CASE("next_commands hands out each recorded step once, in step order") {
    TempDir dir;
    const std::string file = dir.file("r.jsonl", kHeader + "\n" + R"({"step":2,"blade":[[0,0,0],[0,0,1]]})" "\n" +
                                                     R"({"step":5,"blade":[[0,0,0],[0,0,2]],"cutting":true})" "\n");
    const Playback p = load_playback(file);
    PlaybackCursor cursor;
    for (uint32_t step = 0; step <= 6; ++step) {
      const PlaybackStep* s = next_commands(p, cursor, step);
      CAPTURE(step);
      CHECK((s != nullptr) == (step == 2 || step == 5));
      if (s != nullptr) CHECK(s->step == step);
    }
    // A cursor that skips steps never hands out the ones it passed.
    PlaybackCursor late;
    CHECK(next_commands(p, late, 4) == nullptr);
    REQUIRE(next_commands(p, late, 5) != nullptr);
    CHECK(next_commands(p, late, 5) == nullptr);
  }

  TEST_CASE("bad grab or camera values are refused when the recording is loaded, naming the line") {
    TempDir dir;
    const auto refused = [&](const std::string& line) {
      const std::string file = dir.file("bad.jsonl", kHeader + "\n" + R"({"step":0,"blade":[[0,0,0],[0,0,1]]})" "\n" + line + "\n");
      try {
        load_playback(file);
      } catch (const InputError& e) {
        return std::string(e.what());
      }
      return std::string();
    };
    CHECK(refused(R"({"step":4,"grab":{"target":[1,2]}})").find(": line 3: grab must be") != std::string::npos);
    CHECK(refused(R"({"step":4,"grab":{"target":[1,2,3],"compliance":-1}})").find("line 3: grab") != std::string::npos);
    CHECK(refused(R"({"step":4,"grab":"hold"})").find("line 3: grab") != std::string::npos);
    CHECK(refused(R"({"step":4,"grab":{"target":[1,2,3],"stiffness":0}})").find("line 3: grab.stiffness must be") !=
          std::string::npos);
    CHECK(refused(R"({"step":4,"grab":{"target":[1,2,3],"stiffness":5,"radius":-1}})").find("line 3: grab.radius") !=
          std::string::npos);
    CHECK(refused(R"({"step":4,"grab":{"target":[1,2,3],"stiffness":5,"force_limit":"x"}})").find("line 3: grab.force_limit") !=
          std::string::npos);
    CHECK(refused(R"({"step":4,"grab":{"target":[1,2,3],"stiffness":5,"compliance":1}})").find("line 3: grab has both") !=
          std::string::npos);
    CHECK(refused(R"({"step":4,"grab":{"target":[1,2,3],"radius":1}})").find("line 3: grab.radius and") != std::string::npos);
    CHECK(refused(R"({"step":4,"camera":{"target":[1,2,3],"distance":1,"yaw":0}})").find("line 3: camera must be") !=
          std::string::npos);
    CHECK(refused(R"({"step":4,"camera":{"fov":45}})").find("line 3: camera") != std::string::npos);
    CHECK(refused(R"({"step":4,"camera":{"target":[1,2,3],"distance":1,"yaw":0,"pitch":0}})").empty());
  }

  TEST_CASE("hashes taken in the other physics mode are not compared") {
    TempDir dir;
    std::string header = kHeader;
    header.insert(header.size() - 1, R"(,"physics":false)");
    const Playback off = load_playback(dir.file("off.jsonl", header + "\n"));
    const Playback unknown = load_playback(dir.file("unknown.jsonl", kHeader + "\n"));
    std::string warning;
    CHECK(hashes_apply(off, false, warning));
    CHECK(hashes_apply(unknown, true, warning));
    CHECK(warning.empty());
    CHECK_FALSE(hashes_apply(off, true, warning));
    CHECK(warning.find("physics off; not checked") != std::string::npos);
  }

  TEST_CASE("the session recorder's recording replays with every hash matching, a tampered hash is found") {
    TempDir dir;
    const std::string path = (dir.path / "rec.jsonl").string();
    // A session: 5 poses, then 4 steps without commands, then a grab and its release.
    std::string final_hash;
    {
      Session live;
      open_small_bunny(live, true);
      SessionRecorder recorder(path, live.scene, live.dt, true, 3);
      for (uint32_t step = 0; step < 12; ++step) {
        StepCommands c;
        if (step < 5) {
          c.has_blade = true;
          c.blade = blade_at(-6.0 + 3.0 * step, 6.0);
          c.cutting = step > 0;
        }
        if (step == 9) {
          c.grab.kind = GrabCommand::kTarget;
          c.grab.target = Vec3d(0, 4, 0);
        }
        if (step == 10) c.grab.kind = GrabCommand::kRelease;
        session_step(live, c);
        recorder.record(step, c, nullptr, live);
      }
      recorder.finish(live);
      recorder.finish(live);  // idempotent
      final_hash = hash_hex(session_hash(live));
    }
    // One line per step with commands (5 poses, grab, release), hashes at 0, 3, 6, 9 and after step 11.
    const Playback p = load_playback(path);
    CHECK(p.physics == 1);
    uint32_t poses = 0, grabs = 0, hashes = 0;
    for (const PlaybackStep& s : p.steps) {
      poses += s.commands.has_blade;
      grabs += s.commands.grab.kind != GrabCommand::kNone;
      hashes += s.has_hash;
    }
    CHECK(poses == 5);
    CHECK(grabs == 2);
    CHECK(hashes == 5);
    CHECK(p.last_step() == 11);
    CHECK(p.steps.back().hash == final_hash);

    // Replayed through the same functions: every hash matches; then one tampered hash is reported.
    const auto replay = [](const Playback& playback) {
      Session s;
      open_small_bunny(s, true);
      PlaybackCursor cursor;
      HashChecks checks;
      for (uint32_t step = 0; step <= playback.last_step(); ++step) {
        const PlaybackStep* r = next_commands(playback, cursor, step);
        session_step(s, r ? r->commands : StepCommands());
        if (r) check_hash(*r, s, checks);
      }
      return checks;
    };
    const HashChecks good = replay(p);
    CHECK(good.checked == 5);
    CHECK(good.mismatched == 0);
    CHECK(good.first_mismatch_step == -1);
    Playback tampered = p;
    for (PlaybackStep& s : tampered.steps) {
      if (s.step == 6) s.hash[0] = s.hash[0] == '0' ? '1' : '0';
    }
    const HashChecks bad = replay(tampered);
    CHECK(bad.mismatched == 1);
    CHECK(bad.first_mismatch_step == 6);
  }

  TEST_CASE("the recorder writes a step's commands on one line, in the reader's format") {
    TempDir dir;
    const std::string path = (dir.path / "rec.jsonl").string();
    Session s;
    open_small_bunny(s, false);
    SessionRecorder recorder(path, s.scene, s.dt, false);
    StepCommands c;
    c.has_blade = true;
    c.blade = blade_at(-6.0, 6.0);
    CameraCommand camera;
    camera.distance = 4.0f;
    session_step(s, c);
    recorder.record(0, c, &camera, s);
    session_step(s, StepCommands());
    recorder.record(1, StepCommands(), nullptr, s);  // nothing to write but the final hash
    recorder.finish(s);
    std::istringstream lines(read_text(path));
    std::string header, first, hash0, last, extra;
    std::getline(lines, header);
    std::getline(lines, first);
    std::getline(lines, hash0);
    std::getline(lines, last);
    CHECK_FALSE(std::getline(lines, extra));
    CHECK(header.find(R"("physics":false)") != std::string::npos);
    CHECK(first == R"({"blade":[[-6.0,6.0,-5.0],[-6.0,6.0,5.0]],"camera":{"distance":4.0,"pitch":0.0,"target":[0.0,0.0,0.0],"yaw":0.0},"cutting":false,"step":0})");
    CHECK(hash0.find(R"("step":0)") != std::string::npos);
    CHECK(last.find(R"("step":1)") != std::string::npos);
    CHECK(last.find(R"("hash")") != std::string::npos);
    // A non-finite pose is refused (JSON has no NaN).
    c.blade.a.x() = std::numeric_limits<double>::quiet_NaN();
    CHECK_THROWS_AS(recorder.record(2, c, nullptr, s), std::invalid_argument);
  }
}
