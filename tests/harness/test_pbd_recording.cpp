// The shipped recording with the physics: the severed top of the head is a free body (no particle
// shared with the rest) and falls clear of it.
#include "engine/recording.h"
#include "engine/session.h"
#include "harness/replay_outputs.h"
#include "sim/pbd.h"
#include "sim/shapes.h"
#include "support.h"

#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <numeric>
#include <sstream>

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

// A `replay --meshes` file: the binary PLY engine/output.h writes (float x y z; faces as a uchar 3
// and three int indices, then `uchar cut`). Assimp reads the geometry of such files but drops the
// face property this test needs, so the cut faces are read here. Returns false when the file is not
// in that layout.
struct CutMesh {
  std::vector<Vec3f> vertices;
  std::vector<std::array<int32_t, 3>> faces;
  std::vector<uint8_t> cut;
};

bool read_cut_mesh(const std::string& path, CutMesh& mesh) {
  std::ifstream in(path, std::ios::binary);
  std::string line, header;
  size_t vertices = 0, faces = 0;
  while (std::getline(in, line) && line != "end_header") {
    header += line + "\n";
    std::istringstream words(line);
    std::string a, b;
    size_t count = 0;
    if (words >> a >> b >> count && a == "element") (b == "vertex" ? vertices : faces) = count;
  }
  if (header.find("property list uchar int vertex_indices\nproperty uchar cut") == std::string::npos) return false;
  mesh.vertices.resize(vertices);
  in.read(reinterpret_cast<char*>(mesh.vertices.data()), std::streamsize(vertices * sizeof(Vec3f)));
  for (size_t f = 0; f < faces && in; ++f) {
    char record[14];
    in.read(record, sizeof record);
    if (record[0] != 3) return false;
    std::array<int32_t, 3> face;
    std::memcpy(face.data(), record + 1, sizeof face);
    mesh.faces.push_back(face);
    mesh.cut.push_back(uint8_t(record[13]));
  }
  return bool(in) && mesh.faces.size() == faces;
}

}  // namespace

TEST_SUITE("pbd_recording") {
  TEST_CASE("replay --meshes: a blade through a bar bent 90 degrees by the grab tool cuts it where the blade is") {
    // The bar (3 x 0.5 x 0.5, anchored at x < -1.3, no gravity) as a scene and a recording: the grab
    // takes its free end along the ends of circular arcs of the bar's free length, bending it by 90
    // degrees; after it settles a horizontal blade sweeps across it in one step. The replay's last
    // --meshes file holds the deformed surface in world space with the cut faces marked.
    dvx_test::TempDir dir;
    const TriMesh bar = make_box(Vec3d(0.0013, 0.0021, 0.0007), Vec3d(1.5, 0.25, 0.25), Eigen::Matrix3d::Identity(), 1);
    std::ostringstream obj;
    obj.precision(17);
    for (const Vec3d& v : bar.positions) obj << "v " << v.x() << ' ' << v.y() << ' ' << v.z() << '\n';
    for (const auto& t : bar.triangles) obj << "f " << t[0] + 1 << ' ' << t[1] + 1 << ' ' << t[2] + 1 << '\n';
    const std::string mesh = dir.file("bar.obj", obj.str());
    const nlohmann::json scene = {{"mesh", mesh},
                                  {"resolution", 48},
                                  {"sim_resolution", 12},
                                  {"material", {{"shape_stiffness", 0.2}, {"stretch_compliance", 1e-4}}},
                                  {"solver", {{"damping", 0.05}}},
                                  {"gravity", {0, 0, 0}},
                                  {"fixed", {{{"box", {{-5, -5, -5}, {-1.3, 5, 5}}}}}}};
    std::ostringstream rec;
    rec << nlohmann::json{{"format", "divvox-recording"}, {"version", 1}, {"scene", scene}, {"dt", 1.0 / 60.0}}.dump() << '\n';
    const double length = 2.8, plane = 1.0137;
    const int bend = 150, settle = 60;
    rec << nlohmann::json{{"step", 0}, {"grab", {{"target", {1.5, 0.0, 0.0}}, {"compliance", 1e-7}}}}.dump() << '\n';
    for (int i = 1; i <= bend; ++i) {
      const double angle = 0.5 * M_PI * i / bend, radius = length / angle;
      const Vec3d end = Vec3d(-1.3, 0.0, 0.0) + radius * Vec3d(std::sin(angle), 1.0 - std::cos(angle), 0.0);
      rec << nlohmann::json{{"step", i}, {"grab", {{"target", {end.x(), end.y(), end.z()}}, {"compliance", 1e-7}}}}.dump() << '\n';
    }
    const uint32_t cut_step = uint32_t(bend + settle);
    rec << blade_line(cut_step - 1, {Vec3d(-2, plane, -1), Vec3d(-2, plane, 1)}, false).dump() << '\n';
    rec << blade_line(cut_step, {Vec3d(2, plane, -1), Vec3d(2, plane, 1)}, true).dump() << '\n';
    ReplayOptions options;
    options.recording = dir.file("bar.jsonl", rec.str());
    options.out_dir = (dir.path / "out").string();
    options.workers = 1;
    options.meshes_every = 50;
    const ReplayResult result = run_replay(options);
    REQUIRE(result.steps == cut_step + 1);
    char name[32];
    std::snprintf(name, sizeof name, "mesh_%05u.ply", cut_step);
    // final.ply is the last step's mesh, in the same format (world space, cut faces marked).
    CHECK(dvx_test::read_text(dir.path / "out" / "final.ply") == dvx_test::read_text(dir.path / "out" / "meshes" / name));
    CutMesh m;
    REQUIRE(read_cut_mesh((dir.path / "out" / "meshes" / name).string(), m));
    // Bent: the far end of the bar points up.
    float top = -1e30f;
    for (const Vec3f& v : m.vertices) top = std::max(top, v.y());
    REQUIRE(top > 1.2f);
    // Cut faces, in world space, lie on the blade's plane.
    const double fine = 3.0 / 48.0;  // the bar's longest side over the resolution
    std::vector<double> distance;
    for (size_t f = 0; f < m.faces.size(); ++f) {
      if (!m.cut[f]) continue;
      double y = 0.0;
      for (int32_t v : m.faces[f]) y += double(m.vertices[size_t(v)].y()) / 3.0;
      distance.push_back(std::abs(y - plane) / fine);
    }
    REQUIRE(distance.size() > 20);
    std::sort(distance.begin(), distance.end());
    const double p95 = distance[size_t(0.95 * double(distance.size() - 1))];
    MESSAGE("bent bar, " << name << ": " << distance.size() << " cut faces, distance from the blade plane p95 " << p95
                         << " fine voxels, max " << distance.back());
    CHECK(p95 <= 1.0);
  }

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
    const PbdState& pbd = *s.state.pbd;
    std::string error;
    REQUIRE_MESSAGE(check_pbd_state(s.world.voxels, s.state.cut, pbd.model, pbd.data, error), error);
    // Surface components (vertex slots joined by triangles).
    const CutSurface& surface = s.state.cut.surface;
    std::vector<uint32_t> component(surface.positions.size());
    std::iota(component.begin(), component.end(), 0u);
    for (const Tri& t : surface.triangles) {
      if (t[0] == kDeadIndex) continue;
      unite(component, t[0], t[1]);
      unite(component, t[0], t[2]);
    }
    // Particle components (particles joined by the pieces using them).
    std::vector<uint32_t> body(pbd.model.rest.size());
    std::iota(body.begin(), body.end(), 0u);
    for (const SimPiece& piece : pbd.model.pieces) {
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
      const uint32_t piece = vertex_sim_piece(pbd.model, v);
      if (piece == kDeadIndex) {
        ++unembedded;
        continue;
      }
      const bool is_head = find(component, v) == head;
      for (uint32_t p : pbd.model.pieces[piece].particles)
        (is_head ? head_bodies : rest_bodies).push_back(find(body, p));
      if (is_head) {
        head_min_y = std::min(head_min_y, double(pbd.data.deformed[v].y()));
        head_max_x = std::max(head_max_x, double(pbd.data.deformed[v].x()));
        head_drop += double(surface.positions[v].y() - pbd.data.deformed[v].y());
        ++head_vertices;
      } else {
        rest_min_x = std::min(rest_min_x, double(pbd.data.deformed[v].x()));
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
    REQUIRE(recording.scene.pbd.planes.size() == 1);
    const double tray_y = recording.scene.pbd.planes[0].point.y();
    const double half_voxel = 0.5 * s.world.voxels.lattice.voxel_size;
    MESSAGE("head top: mean drop " << head_drop / double(head_vertices) << ", lowest point " << head_min_y
                                   << " (tray at " << tray_y << "), right end x " << head_max_x
                                   << "; body's left end x " << rest_min_x);
    CHECK(head_drop / double(head_vertices) > 2.0);
    CHECK(head_min_y > tray_y - half_voxel);
    CHECK(head_min_y < tray_y + half_voxel);
    CHECK(head_max_x < rest_min_x);
  }
}
