// Recordings (JSON Lines): exact round trips, truncated last lines, and every kind of bad line.
#include "engine/errors.h"
#include "engine/recording.h"
#include "engine/scene.h"
#include "support.h"

#include <doctest/doctest.h>
#include <nlohmann/json.hpp>

#include <unistd.h>

#include <atomic>
#include <bit>
#include <cfloat>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>
#include <vector>

using namespace dvx;
using nlohmann::json;
namespace fs = std::filesystem;

namespace {

// A fresh folder under the system temp folder, removed with everything in it.
struct TempDir {
  fs::path path;
  TempDir() {
    static std::atomic<int> counter{0};
    path = fs::temp_directory_path() /
           ("divvox_recording_test_" + std::to_string(::getpid()) + "_" + std::to_string(counter++));
    fs::remove_all(path);
    fs::create_directories(path);
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
  std::string file(const std::string& name) const { return (path / name).string(); }
};

void write_text(const std::string& file, const std::string& text) {
  std::ofstream out(file, std::ios::binary);
  out << text;
}

void append_text(const std::string& file, const std::string& text) {
  std::ofstream out(file, std::ios::binary | std::ios::app);
  out << text;
}

uint64_t bits(double x) { return std::bit_cast<uint64_t>(x); }

const std::string kHeader =
    R"({"format":"divvox-recording","version":1,"scene":{"mesh":"m.obj","resolution":32},"dt":0.01})";

// Message of the InputError that reading `text` as a recording throws ("" when none).
std::string read_error(const std::string& text) {
  TempDir dir;
  const std::string file = dir.file("rec.jsonl");
  write_text(file, text);
  try {
    read_recording(file);
  } catch (const InputError& e) {
    const std::string message = e.what();
    // Every message names the file first, on one line.
    CHECK(message.rfind(file + ": ", 0) == 0);
    CHECK(message.find('\n') == std::string::npos);
    return message;
  }
  return {};
}

// A header followed by the given step lines, each terminated.
std::string with_header(const std::vector<std::string>& lines) {
  std::string text = kHeader + "\n";
  for (const std::string& l : lines) text += l + "\n";
  return text;
}

bool contains(const std::string& haystack, const std::string& needle) {
  return haystack.find(needle) != std::string::npos;
}

Scene test_scene() {
  Scene scene;
  scene.mesh = "m.obj";
  scene.pbd.resolution = 64;
  scene.pbd.sim_resolution = 8;
  scene.pbd.gravity = Vec3d(0.1, -9.81, 1.0 / 3.0);
  scene.pbd.fixed.push_back({Vec3d(-1, -1, -1), Vec3d(1.0 / 7.0, 0, 1)});
  return scene;
}

}  // namespace

TEST_SUITE("recording") {
  TEST_CASE("a written recording reads back bit for bit: poses, flags, hashes, extra keys") {
    TempDir dir;
    const std::string file = dir.file("session.jsonl");
    const double awkward[] = {1.0 / 3.0,         1e-300, -0.0, 123456.789, 4.9406564584124654e-324,
                              DBL_MAX,           0.1 + 0.2, -2.5e17, std::nextafter(1.0, 2.0),
                              3.141592653589793, -1e-7,  2.0};
    const size_t n = sizeof(awkward) / sizeof(awkward[0]);
    const double dt = 1.0 / 60.0;

    std::vector<BladePose> poses;
    std::vector<std::string> hashes;
    {
      RecordingWriter writer(file, test_scene(), dt);
      for (uint32_t i = 0; i < 100; ++i) {
        BladePose p;
        p.a = Vec3d(awkward[i % n], awkward[(i + 1) % n] / (i + 1), -awkward[(i + 2) % n]);
        p.b = Vec3d(awkward[(i + 3) % n] * 0.5, awkward[(i + 5) % n] / 3.0, awkward[(i + 7) % n]);
        poses.push_back(p);
        writer.write_blade(2 * i, p, i % 3 == 1);
        if (i % 10 == 9) {
          hashes.push_back("0123456789abcdef" + std::to_string(1000 + i));
          writer.write_hash(2 * i, hashes.back());
        }
        if (i == 50) writer.write_line({{"step", 2 * i}, {"grab", {{"particle", 17}, {"target", {0.25, -1.0 / 3.0, 7.0}}}}});
      }
    }

    const Recording rec = read_recording(file);
    CHECK(rec.file == file);
    CHECK(rec.warnings.empty());
    CHECK(bits(rec.dt) == bits(dt));
    CHECK(bits(rec.scene.pbd.dt) == bits(dt));
    CHECK(rec.scene.pbd.resolution == 64);
    CHECK(rec.scene.pbd.sim_resolution == 8);
    CHECK(bits(rec.scene.pbd.gravity.z()) == bits(1.0 / 3.0));
    REQUIRE(rec.scene.pbd.fixed.size() == 1);
    CHECK(bits(rec.scene.pbd.fixed[0].max.x()) == bits(1.0 / 7.0));
    // The mesh resolves against the recording's folder.
    CHECK(fs::path(rec.scene.mesh_path) == (dir.path / "m.obj").lexically_normal());

    size_t pose = 0, hash = 0, grabs = 0;
    uint32_t last_step = 0;
    for (const RecordedStep& s : rec.steps) {
      CHECK(s.step >= last_step);
      last_step = s.step;
      if (s.has_blade) {
        REQUIRE(pose < poses.size());
        CHECK(s.step == 2 * pose);
        for (int k = 0; k < 3; ++k) {
          CHECK(bits(s.blade.a[k]) == bits(poses[pose].a[k]));
          CHECK(bits(s.blade.b[k]) == bits(poses[pose].b[k]));
        }
        CHECK(s.cutting == (pose % 3 == 1));
        CHECK(s.extra.is_null());
        ++pose;
      } else if (s.has_hash) {
        REQUIRE(hash < hashes.size());
        CHECK(s.hash == hashes[hash]);
        CHECK(s.step == 2 * (10 * hash + 9));
        ++hash;
      } else {
        REQUIRE(s.extra.is_object());
        CHECK(s.step == 100);
        CHECK(s.extra["grab"]["particle"] == 17);
        CHECK(bits(s.extra["grab"]["target"][1].get<double>()) == bits(-1.0 / 3.0));
        ++grabs;
      }
      CHECK(s.line >= 2);
    }
    CHECK(pose == 100);
    CHECK(hash == 10);
    CHECK(grabs == 1);
    CHECK(rec.last_step() == 198);
    // -0.0 keeps its sign (pose 2 starts at awkward[2] = -0.0).
    REQUIRE(rec.steps[2].has_blade);
    CHECK(std::signbit(rec.steps[2].blade.a.x()));
  }

  TEST_CASE("each line reaches the file as soon as it is written (no user-space buffering)") {
    TempDir dir;
    const std::string file = dir.file("live.jsonl");
    RecordingWriter writer(file, test_scene(), 0.01);
    CHECK(read_recording(file).steps.empty());
    BladePose p;
    p.b = Vec3d(1, 2, 3);
    writer.write_blade(0, p, false);
    writer.write_blade(1, p, true);
    const Recording rec = read_recording(file);
    REQUIRE(rec.steps.size() == 2);
    CHECK(rec.steps[1].cutting);
    CHECK(rec.steps[1].blade.b == Vec3d(1, 2, 3));
  }

  TEST_CASE("the writer re-anchors the scene's mesh at the recording's folder, the header dt wins") {
    TempDir dir;
    fs::create_directories(dir.path / "a" / "scenes");
    fs::create_directories(dir.path / "recs");
    Scene scene = parse_scene(json{{"mesh", "../meshes/m.obj"}, {"solver", {{"dt", 0.01}}}}, dir.file("a/scenes/s.json"));
    const std::string file = dir.file("recs/r.jsonl");
    { RecordingWriter writer(file, scene, 0.005); }
    const Recording rec = read_recording(file);
    CHECK(fs::path(rec.scene.mesh_path) == (dir.path / "a" / "meshes" / "m.obj").lexically_normal());
    CHECK(rec.dt == 0.005);
    CHECK(rec.scene.pbd.dt == 0.005);
  }

  TEST_CASE("a truncated last line is dropped with a warning, everything before it is kept") {
    TempDir dir;
    const std::string file = dir.file("crash.jsonl");
    {
      RecordingWriter writer(file, test_scene(), 0.01);
      BladePose p;
      for (uint32_t i = 0; i < 5; ++i) writer.write_blade(i, p, true);
      writer.write_hash(4, "abc");
    }
    append_text(file, R"({"step":5,"blade":[[0.1,0.2,0.)");
    const Recording rec = read_recording(file);
    CHECK(rec.steps.size() == 6);
    CHECK(rec.last_step() == 4);
    REQUIRE(rec.warnings.size() == 1);
    CHECK(rec.warnings[0] == file + ": line 8: truncated last line ignored");

    // An unterminated last line that is complete is kept.
    append_text(file, "3],[1,1,1]]}");
    const Recording whole = read_recording(file);
    CHECK(whole.warnings.empty());
    REQUIRE(whole.steps.size() == 7);
    CHECK(whole.steps.back().step == 5);
    CHECK(whole.steps.back().blade.a.z() == 0.3);
  }

  TEST_CASE("a malformed line before the last one is an error naming its line") {
    const std::string e = read_error(with_header({R"({"step":0})", R"({"step":1,"blade":[[0,0,)", R"({"step":2})"}));
    CHECK(contains(e, ": line 3: malformed JSON"));
    // Terminated by a newline, it was not cut short: an error too.
    CHECK(contains(read_error(with_header({R"({"step":0})", R"({"step":1,)"})), ": line 3: malformed JSON"));
    // Blank lines are skipped but still counted.
    CHECK(contains(read_error(kHeader + "\n\n\n" + "garbage\n" + R"({"step":2})" + "\n"), ": line 4:"));
  }

  TEST_CASE("NaN or Infinity in a blade is an error naming the step") {
    for (const char* value : {"NaN", "-NaN", "Infinity", "-Infinity", "1e999", "-1e999", "nan", "inf"}) {
      CAPTURE(value);
      const std::string bad = std::string(R"({"step":5,"blade":[[0,)") + value + R"(,0],[1,1,1]],"cutting":true})";
      const std::string e = read_error(with_header({R"({"step":0,"blade":[[0,0,0],[1,1,1]]})", bad, R"({"step":6})"}));
      CHECK(contains(e, ": line 3: step 5: blade is not two finite 3D points"));
      // Also as the unterminated last line: complete, so not mistaken for a truncation.
      const std::string last = read_error(kHeader + "\n" + bad);
      CHECK(contains(last, ": line 2: step 5: blade is not two finite"));
    }
    // NaN elsewhere in a step line still names the step.
    CHECK(contains(read_error(with_header({R"({"step":9,"grab":{"x":NaN}})"})), ": line 2: step 9: holds NaN"));
    // A "NaN" inside a string is just text.
    const std::string ok = with_header({R"({"step":9,"note":"NaN Infinity"})"});
    CHECK(read_error(ok).empty());
  }

  TEST_CASE("steps out of order, a second pose or hash for one step are errors") {
    CHECK(contains(read_error(with_header({R"({"step":9})", R"({"step":5})"})),
                   ": line 3: step 5 comes after step 9 (line 2)"));
    const std::string pose = R"("blade":[[0,0,0],[1,1,1]])";
    CHECK(contains(read_error(with_header({"{\"step\":12," + pose + "}", R"({"step":12,"hash":"ab"})",
                                           "{\"step\":12," + pose + ",\"cutting\":true}"})),
                   ": line 4: step 12 has two blade poses (first on line 2)"));
    CHECK(contains(read_error(with_header({R"({"step":3,"hash":"ab"})", R"({"step":3,"hash":"ab"})"})),
                   ": line 3: step 3 has two hashes"));
    // The same step may carry a pose, a hash and other commands on separate lines; the next step may
    // have its own pose.
    CHECK(read_error(with_header({"{\"step\":12," + pose + "}", R"({"step":12,"hash":"ab"})",
                                  R"({"step":12,"grab":{}})", "{\"step\":13," + pose + "}"}))
              .empty());
  }

  TEST_CASE("headers: not a recording, newer version, bad dt or scene") {
    CHECK(contains(read_error(""), "empty file (no header)"));
    CHECK(contains(read_error("\n  \n"), "empty file (no header)"));
    CHECK(contains(read_error(R"({"mesh":"m.obj"})" "\n"), ": line 1: not a divvox recording"));
    CHECK(contains(read_error("{\n  \"mesh\": \"m.obj\"\n}\n"), ": line 1: not a divvox recording"));
    CHECK(contains(read_error(R"({"format":"other","version":1})" "\n"), ": line 1: not a divvox recording"));
    CHECK(contains(read_error(R"({"format":"divvox-recording","version":2,"scene":{"mesh":"m.obj"},"dt":0.01})" "\n"),
                   ": line 1: version 2 is newer than this divvox reads (1)"));
    CHECK(contains(read_error(R"({"format":"divvox-recording","version":"1","scene":{"mesh":"m.obj"},"dt":0.01})"),
                   ": line 1: header: \"version\" must be"));
    CHECK(contains(read_error(R"({"format":"divvox-recording","version":1,"dt":0.01})"),
                   ": line 1: header: \"scene\" must be an object"));
    CHECK(contains(read_error(R"({"format":"divvox-recording","version":1,"scene":{"mesh":"m.obj","resolutoin":8},"dt":0.01})"),
                   ": line 1: scene: resolutoin: unknown key"));
    for (const char* dt : {"0", "-0.01", "\"0.01\"", "1e999", "null"}) {
      CAPTURE(dt);
      CHECK(contains(read_error(std::string(R"({"format":"divvox-recording","version":1,"scene":{"mesh":"m.obj"},"dt":)") +
                                dt + "}"),
                     ": line 1: header: \"dt\" must be a positive finite number"));
    }
    CHECK(contains(read_error(R"({"format":"divvox-recording","version":1,"scene":{"mesh":"m.obj"}})"), "\"dt\""));
    // Unknown header keys are ignored (a later version may add some).
    CHECK(read_error(R"({"format":"divvox-recording","version":1,"scene":{"mesh":"m.obj"},"dt":0.01,"app":"x"})").empty());
  }

  TEST_CASE("wrong types in step lines are errors naming the file and line") {
    const std::vector<std::pair<std::string, std::string>> cases = {
        {R"({"step":1,"blade":[[0,0],[1,1,1]]})", "line 2: step 1: blade is not two finite 3D points"},
        {R"({"step":1,"blade":[[0,0,0]]})", "line 2: step 1: blade is not two finite 3D points"},
        {R"({"step":1,"blade":[[0,0,0],[1,1,"1"]]})", "line 2: step 1: blade is not two finite 3D points"},
        {R"({"step":1,"blade":null})", "line 2: step 1: blade is not two finite 3D points"},
        {R"({"step":1,"blade":[[0,0,0],[1,1,1]],"cutting":"yes"})", "line 2: step 1: \"cutting\" must be true or false"},
        {R"({"step":1,"cutting":true})", "line 2: step 1: \"cutting\" without a \"blade\""},
        {R"({"step":-1})", "line 2: \"step\" must be an integer in [0, 2^31), got -1"},
        {R"({"step":1.5})", "line 2: \"step\" must be an integer"},
        {R"({"step":2.0})", "line 2: \"step\" must be an integer"},
        {R"({"step":"3"})", "line 2: \"step\" must be an integer"},
        {R"({"step":2147483648})", "line 2: \"step\" must be an integer"},
        {R"({"blade":[[0,0,0],[1,1,1]]})", "line 2: step line without \"step\""},
        {R"([1,2])", "line 2: step line is not a JSON object"},
        {R"({"step":1,"hash":"xyz"})", "line 2: step 1: \"hash\" must be a string of 1 to 32 hex digits"},
        {R"({"step":1,"hash":""})", "line 2: step 1: \"hash\""},
        {R"({"step":1,"hash":"0123456789abcdef0123456789abcdef0"})", "line 2: step 1: \"hash\""},
        {R"({"step":1,"hash":12})", "line 2: step 1: \"hash\""},
    };
    for (const auto& entry : cases) {
      // Plain variables, not a structured binding: clang < 16 cannot capture one in CAPTURE's lambda.
      const auto& line = entry.first;
      const auto& expected = entry.second;
      CAPTURE(line);
      CHECK(contains(read_error(with_header({line})), expected));
    }
    // The largest step is fine.
    CHECK(read_error(with_header({R"({"step":2147483647})"})).empty());
  }

  TEST_CASE("unknown keys in step lines are kept in extra, hashes are read in lower case") {
    TempDir dir;
    const std::string file = dir.file("extra.jsonl");
    write_text(file, with_header({R"({"step":0,"blade":[[0,0,0],[1,1,1]],"camera":{"fov":45},"future":[1,2]})",
                                  R"({"step":0,"hash":"9F0CE1"})", R"({"step":2})"}));
    const Recording rec = read_recording(file);
    REQUIRE(rec.steps.size() == 3);
    CHECK(rec.steps[0].has_blade);
    CHECK_FALSE(rec.steps[0].cutting);
    CHECK(rec.steps[0].extra == json{{"camera", {{"fov", 45}}}, {"future", {1, 2}}});
    CHECK(rec.steps[1].has_hash);
    CHECK(rec.steps[1].hash == "9f0ce1");
    CHECK(rec.steps[1].extra.is_null());
    CHECK_FALSE(rec.steps[2].has_blade);
    CHECK_FALSE(rec.steps[2].has_hash);
    CHECK(rec.steps[2].line == 4);
  }

  TEST_CASE("missing files, folders and unwritable paths are input errors naming the file") {
    TempDir dir;
    const std::string missing = dir.file("nope.jsonl");
    CHECK_THROWS_WITH_AS(read_recording(missing), (missing + ": no such file").c_str(), InputError);
    CHECK_THROWS_AS(read_recording(dir.path.string()), InputError);
    const std::string bad = dir.file("no/such/folder/r.jsonl");
    try {
      RecordingWriter writer(bad, test_scene(), 0.01);
      FAIL("expected an InputError");
    } catch (const InputError& e) {
      CHECK(std::string(e.what()).rfind(bad + ": cannot create recording: ", 0) == 0);
    }
  }

  TEST_CASE("the writer refuses lines the reader would reject") {
    TempDir dir;
    const std::string file = dir.file("w.jsonl");
    RecordingWriter writer(file, test_scene(), 0.01);
    BladePose p;
    p.a.x() = std::nan("");
    CHECK_THROWS_AS(writer.write_blade(3, p, true), std::invalid_argument);
    CHECK_THROWS_AS(writer.write_line(json{{"grab", 1}}), std::invalid_argument);
    CHECK_THROWS_AS(writer.write_line(json{{"step", -1}}), std::invalid_argument);
    writer.write_line(json{{"step", 4}, {"grab", 1}});
    const Recording rec = read_recording(file);
    REQUIRE(rec.steps.size() == 1);
    CHECK(rec.steps[0].extra == json{{"grab", 1}});
  }
}
