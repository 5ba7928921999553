#include "engine/mesh_io.h"

#include "engine/errors.h"
#include "engine/resources.h"

#include <assimp/DefaultLogger.hpp>
#include <assimp/Exporter.hpp>
#include <assimp/Importer.hpp>
#include <assimp/ProgressHandler.hpp>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <stdexcept>
#include <string>

// Debian's assimp is built with ASSIMP_BUILD_DEBUG: a failed internal ai_assert (reachable from
// malformed files, e.g. a PLY whose faces TriangulateProcess miscounts) prints a line and aborts.
// This definition interposes the library's (calls from libassimp go through its PLT) and throws
// instead; load_mesh turns that into an InputError naming the file.
namespace Assimp {
void aiAssertViolation(const char* expression, const char* file, int line) {
  throw std::runtime_error(std::string("assimp internal check failed: ") + expression + " (" + file + ":" +
                           std::to_string(line) + ")");
}
}  // namespace Assimp

namespace dvx {
namespace {

// Appends the triangles of every mesh under `node`, transformed to scene coordinates.
void gather_node(const aiScene* scene, const aiNode* node, const aiMatrix4x4& parent, TriMesh& out,
                 const std::string& path) {
  const aiMatrix4x4 transform = parent * node->mTransformation;
  for (unsigned m = 0; m < node->mNumMeshes; ++m) {
    const aiMesh* mesh = scene->mMeshes[node->mMeshes[m]];
    const uint32_t base = uint32_t(out.positions.size());
    for (unsigned v = 0; v < mesh->mNumVertices; ++v) {
      const aiVector3D p = transform * mesh->mVertices[v];
      out.positions.emplace_back(p.x, p.y, p.z);
    }
    for (unsigned f = 0; f < mesh->mNumFaces; ++f) {
      const aiFace& face = mesh->mFaces[f];
      if (face.mNumIndices != 3) continue;  // points and lines carry no surface
      Tri tri;
      for (int c = 0; c < 3; ++c) {
        if (face.mIndices[c] >= mesh->mNumVertices) {
          throw_input(path, "face " + std::to_string(f) + " refers to vertex " +
                                std::to_string(face.mIndices[c]) + " but the mesh has only " +
                                std::to_string(mesh->mNumVertices));
        }
        tri[c] = base + face.mIndices[c];
      }
      out.triangles.push_back(tri);
    }
  }
  for (unsigned c = 0; c < node->mNumChildren; ++c) gather_node(scene, node->mChildren[c], transform, out, path);
}

// Reads the first bytes to tell an empty file from a damaged one.
uint64_t file_size(const std::string& path) {
  std::error_code ec;
  const auto size = std::filesystem::file_size(path, ec);
  return ec ? 0 : uint64_t(size);
}

// assimp 5.2's PLY reader never returns on a header without an `end_header` line (it keeps
// reading at end of file): refuse such files before handing them over. Looks at .ply files
// starting with the "ply" magic (assimp refuses the others itself), at most their first 1 MiB.
void check_ply_header(const std::string& path, const std::string& extension) {
  std::string lower = extension;
  for (char& c : lower) c = char(std::tolower(static_cast<unsigned char>(c)));
  if (lower != ".ply") return;
  std::ifstream in(path, std::ios::binary);
  std::string head(1u << 20, '\0');
  in.read(head.data(), std::streamsize(head.size()));
  head.resize(size_t(in.gcount()));
  if (head.rfind("ply", 0) != 0) return;
  // A line (ends: \n \r \f \0, as assimp's) whose first word is end_header.
  bool at_line_start = true;
  for (size_t i = 0; i < head.size(); ++i) {
    const char c = head[i];
    if (c == '\n' || c == '\r' || c == '\f' || c == '\0') {
      at_line_start = true;
    } else if (at_line_start && (c == ' ' || c == '\t')) {
      continue;
    } else if (at_line_start && head.compare(i, 10, "end_header") == 0 &&
               (i + 10 == head.size() || std::strchr(" \t\n\r\f", head[i + 10]) != nullptr || head[i + 10] == '\0')) {
      return;
    } else {
      at_line_start = false;
    }
  }
  throw_input(path, "PLY header has no end_header line");
}

// Reports assimp's reading progress on stderr in steps of 10 %.
class LoadProgress final : public Assimp::ProgressHandler {
 public:
  explicit LoadProgress(std::string name) : name_(std::move(name)) {}
  bool Update(float percentage) override {
    const int tenth = int(percentage * 10.0f + 1e-3f);
    if (percentage >= 0.0f && tenth > last_tenth_ && tenth <= 10) {
      last_tenth_ = tenth;
      std::fprintf(stderr, "divvox: loading %s: %d %%\n", name_.c_str(), 10 * tenth);
    }
    return true;  // never cancel
  }

 private:
  std::string name_;
  int last_tenth_ = 0;
};

}  // namespace

LoadedMesh load_mesh(const std::string& path, bool progress) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::exists(path, ec)) throw_input(path, "no such file");
  if (fs::is_directory(path, ec)) throw_input(path, "is a directory, not a mesh file");
  {
    std::ifstream probe(path, std::ios::binary);
    if (!probe) throw_input(path, "cannot be opened for reading");
  }
  if (file_size(path) == 0) throw_input(path, "empty file");

  Assimp::Importer importer;
  const std::string extension = fs::path(path).extension().string();
  if (extension.empty() || !importer.IsExtensionSupported(extension)) {
    throw_input(path, "unknown mesh format '" + extension + "' (use OBJ, PLY, STL, glTF/GLB)");
  }
  check_ply_header(path, extension);
  const std::string name = fs::path(path).filename().string();
  if (progress) {
    progress_line(true, "loading " + name + " (" + std::to_string(file_size(path) >> 20) + " MiB)");
    importer.SetProgressHandler(new LoadProgress(name));  // the importer owns and deletes it
  }
  // Points and lines are dropped; polygons become triangles; the structure is validated
  // (assimp rejects out-of-range indices there). Vertices are welded by us, exactly.
  importer.SetPropertyInteger(AI_CONFIG_PP_SBP_REMOVE, aiPrimitiveType_POINT | aiPrimitiveType_LINE);
  // Read first, post-process after checking the faces: assimp 5.2's loaders can produce faces
  // without indices (a damaged PLY face list), which SortByPType dereferences out of bounds
  // and TriangulateProcess asserts on; ValidateDataStructure does not catch them.
  const aiScene* scene = nullptr;
  try {
    scene = importer.ReadFile(path, 0);
    if (scene != nullptr) {
      for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
        const aiMesh* mesh = scene->mMeshes[m];
        if (mesh == nullptr) throw_input(path, "mesh " + std::to_string(m) + " is missing");
        for (unsigned f = 0; f < mesh->mNumFaces; ++f) {
          if (mesh->mFaces[f].mNumIndices == 0 || mesh->mFaces[f].mIndices == nullptr) {
            throw_input(path, "face " + std::to_string(f) + " has no vertices");
          }
        }
      }
      scene = importer.ApplyPostProcessing(aiProcess_Triangulate | aiProcess_ValidateDataStructure |
                                           aiProcess_SortByPType);
    }
  } catch (const InputError&) {
    throw;
  } catch (const std::exception& e) {  // aiAssertViolation above, or assimp's own exceptions
    throw_input(path, std::string("cannot be read as a mesh: ") + e.what());
  }
  if (scene == nullptr) {
    std::string reason = importer.GetErrorString();
    if (reason.empty()) reason = "unknown reason";
    throw_input(path, "cannot be read as a mesh: " + reason);
  }

  LoadedMesh loaded;
  if (scene->mRootNode != nullptr) gather_node(scene, scene->mRootNode, aiMatrix4x4(), loaded.mesh, path);
  progress_line(progress, "read " + std::to_string(loaded.mesh.triangles.size()) + " triangles; checking and welding");
  if (loaded.mesh.triangles.empty()) throw_input(path, "the mesh has no triangles");

  // Coordinates must be finite.
  for (size_t v = 0; v < loaded.mesh.positions.size(); ++v) {
    if (!loaded.mesh.positions[v].allFinite()) {
      throw_input(path, "vertex " + std::to_string(v) + " has a NaN or infinite coordinate");
    }
  }
  loaded.dropped_triangles = weld_identical_vertices(loaded.mesh);
  if (loaded.mesh.triangles.empty()) throw_input(path, "every triangle is degenerate");
  const Aabb box = mesh_bounds(loaded.mesh);
  if (!(box.extent().maxCoeff() > 0.0)) throw_input(path, "the bounding box has zero size");
  return loaded;
}

void save_ply(const std::string& path, const SurfaceMesh& surface) {
  // Build a minimal aiScene holding one mesh and export it as binary PLY.
  aiScene scene;
  scene.mRootNode = new aiNode();
  scene.mMaterials = new aiMaterial*[1]{new aiMaterial()};
  scene.mNumMaterials = 1;
  scene.mMeshes = new aiMesh*[1]{new aiMesh()};
  scene.mNumMeshes = 1;
  scene.mRootNode->mMeshes = new unsigned[1]{0};
  scene.mRootNode->mNumMeshes = 1;

  aiMesh* mesh = scene.mMeshes[0];
  mesh->mPrimitiveTypes = aiPrimitiveType_TRIANGLE;
  mesh->mMaterialIndex = 0;
  mesh->mNumVertices = unsigned(surface.positions.size());
  mesh->mVertices = new aiVector3D[mesh->mNumVertices];
  mesh->mNormals = new aiVector3D[mesh->mNumVertices];
  const std::vector<Vec3f> normals = vertex_normals(surface);
  for (unsigned v = 0; v < mesh->mNumVertices; ++v) {
    const Vec3f& p = surface.positions[v];
    mesh->mVertices[v] = aiVector3D(p.x(), p.y(), p.z());
    mesh->mNormals[v] = aiVector3D(normals[v].x(), normals[v].y(), normals[v].z());
  }
  mesh->mNumFaces = unsigned(surface.triangles.size());
  mesh->mFaces = new aiFace[mesh->mNumFaces];
  for (unsigned f = 0; f < mesh->mNumFaces; ++f) {
    aiFace& face = mesh->mFaces[f];
    face.mNumIndices = 3;
    face.mIndices = new unsigned[3]{surface.triangles[f][0], surface.triangles[f][1], surface.triangles[f][2]};
  }

  Assimp::Exporter exporter;
  if (exporter.Export(&scene, "plyb", path) != aiReturn_SUCCESS) {
    std::string reason = exporter.GetErrorString();
    throw std::runtime_error(path + ": cannot write PLY: " + (reason.empty() ? "unknown reason" : reason));
  }
}

}  // namespace dvx
