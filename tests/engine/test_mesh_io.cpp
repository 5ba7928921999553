// Mesh loading through assimp: formats, merging, and every kind of bad file.
#include "engine/errors.h"
#include "engine/mesh_io.h"
#include "sim/shapes.h"
#include "sim/surface_metrics.h"
#include "support.h"

#include <doctest/doctest.h>

#include <assimp/Exporter.hpp>
#include <assimp/Importer.hpp>
#include <assimp/scene.h>

#include <cmath>
#include <filesystem>
#include <fstream>

using namespace dvx;
namespace fs = std::filesystem;

namespace {

using dvx_test::TempDir;

std::string load_error(const std::string& path) {
  try {
    load_mesh(path);
  } catch (const InputError& e) {
    return e.what();
  }
  return {};
}

SurfaceMesh as_surface(const TriMesh& mesh) {
  SurfaceMesh s;
  for (const Vec3d& p : mesh.positions) s.positions.push_back(p.cast<float>());
  s.vertex_voxel.assign(mesh.positions.size(), 0);
  s.triangles = mesh.triangles;
  return s;
}

}  // namespace

TEST_SUITE("mesh_io") {
  TEST_CASE("OBJ, PLY, STL and glTF/GLB load to the same closed mesh") {
    TempDir dir;
    const TriMesh box = make_box(Vec3d(0, 0, 0), Vec3d(1, 2, 3), Eigen::Matrix3d::Identity(), 2);
    // PLY written by our exporter.
    const std::string ply = (dir.path / "box.ply").string();
    save_ply(ply, as_surface(box));
    const LoadedMesh from_ply = load_mesh(ply);
    CHECK(from_ply.mesh.triangles.size() == box.triangles.size());
    CHECK(std::abs(signed_volume(from_ply.mesh) - 48.0) < 1e-4);
    CHECK(is_watertight(from_ply.mesh));
    // The same scene exported by assimp to other formats.
    Assimp::Importer importer;
    const aiScene* scene = importer.ReadFile(ply, 0);
    REQUIRE(scene != nullptr);
    Assimp::Exporter exporter;
    for (const auto& entry : {std::pair{"stl", ".stl"}, std::pair{"stlb", ".stl"}, std::pair{"obj", ".obj"},
                              std::pair{"gltf2", ".gltf"}, std::pair{"glb2", ".glb"}}) {
      // Plain variables, not a structured binding: clang < 16 cannot capture one in CAPTURE's lambda.
      const char* const format = entry.first;
      const char* const extension = entry.second;
      CAPTURE(format);
      const std::string path = (dir.path / (std::string("box_") + format + extension)).string();
      REQUIRE(exporter.Export(scene, format, path) == aiReturn_SUCCESS);
      const LoadedMesh loaded = load_mesh(path);
      CHECK(loaded.mesh.triangles.size() == box.triangles.size());
      CHECK(std::abs(signed_volume(loaded.mesh) - 48.0) < 1e-3);
      CHECK(is_watertight(loaded.mesh));  // STL has no shared vertices: the exact weld restores them
    }
  }

  TEST_CASE("quads are triangulated") {
    TempDir dir;
    const std::string path = dir.file("quad.obj",
                                      "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
                                      "f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n");
    const LoadedMesh loaded = load_mesh(path);
    CHECK(loaded.mesh.triangles.size() == 12);
    CHECK(is_watertight(loaded.mesh));
    CHECK(std::abs(signed_volume(loaded.mesh) - 1.0) < 1e-12);
  }

  TEST_CASE("bad files: one-line errors naming the file") {
    TempDir dir;
    const auto expect = [&](const std::string& path, const char* text) {
      const std::string error = load_error(path);
      CAPTURE(error);
      CHECK(error.rfind(path + ": ", 0) == 0);
      CHECK(error.find(text) != std::string::npos);
      CHECK(error.find('\n') == std::string::npos);
    };
    expect((dir.path / "absent.obj").string(), "no such file");
    expect(dir.file("empty.obj", ""), "empty file");
    expect(dir.file("unknown.xyz123", "abc"), "unknown mesh format");
    expect(dir.file("points.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n"), "");
    expect(dir.file("range.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n"), "");
    expect(dir.file("negative.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -9\n"), "");
    expect(dir.file("nan.obj", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n"), "");
    expect(dir.file("zero.obj", "v 1 1 1\nv 1 1 1\nv 1 1 1\nf 1 2 3\n"), "");
    expect(dir.file("garbage.stl", std::string("\x01\x02\x03 not a mesh at all \xff\xfe")), "");
    expect(dir.path.string(), "is a directory");
  }
}
