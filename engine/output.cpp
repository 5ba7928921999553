#include "engine/output.h"

#include "engine/errors.h"

#include <nlohmann/json.hpp>

#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>

namespace dvx {

void make_output_dir(const std::string& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec || !std::filesystem::is_directory(dir)) throw_input(dir, "cannot create output folder: " + ec.message());
}

void write_text_file(const std::string& path, const std::string& text) {
  const std::string temporary = path + ".tmp";
  {
    std::ofstream out(temporary, std::ios::binary | std::ios::trunc);
    out << text;
    out.flush();
    if (!out) throw std::runtime_error(path + ": cannot write");
  }
  std::error_code ec;
  std::filesystem::rename(temporary, path, ec);
  if (ec) throw std::runtime_error(path + ": cannot write: " + ec.message());
}

void write_json_file(const std::string& path, const nlohmann::json& json) { write_text_file(path, json.dump(2) + "\n"); }

void write_cut_mesh_ply(const std::string& path, const CutSurface& surface, const std::vector<Vec3f>* deformed) {
  // Live vertex slots, renumbered.
  std::vector<uint32_t> index(surface.positions.size(), kDeadIndex);
  std::string vertices, faces;
  uint32_t vertex_count = 0, face_count = 0;
  vertices.reserve(surface.positions.size() * 3 * sizeof(float));
  faces.reserve(surface.triangles.size() * (2 + 3 * sizeof(int32_t)));
  for (uint32_t slot = 0; slot < surface.positions.size(); ++slot) {
    if (surface.vertex_piece[slot] == CutSurface::kFreeKey) continue;
    index[slot] = vertex_count++;
    const Vec3f p = deformed && slot < deformed->size() ? (*deformed)[slot] : surface.positions[slot];
    vertices.append(reinterpret_cast<const char*>(p.data()), 3 * sizeof(float));
  }
  for (size_t t = 0; t < surface.triangles.size(); ++t) {
    const Tri& tri = surface.triangles[t];
    if (tri[0] == kDeadIndex) continue;
    const uint8_t three = 3, cut = t < surface.triangle_cut.size() && surface.triangle_cut[t] ? 1 : 0;
    // count, three indices, cut flag: 14 bytes, packed as the header declares.
    char face[2 + 3 * sizeof(int32_t)];
    face[0] = char(three);
    for (int k = 0; k < 3; ++k) {
      const int32_t i = int32_t(index[tri[k]]);
      std::memcpy(face + 1 + k * sizeof(i), &i, sizeof(i));
    }
    face[sizeof(face) - 1] = char(cut);
    faces.append(face, sizeof(face));
    ++face_count;
  }
  const std::string header = "ply\nformat binary_little_endian 1.0\nelement vertex " + std::to_string(vertex_count) +
                             "\nproperty float x\nproperty float y\nproperty float z\nelement face " +
                             std::to_string(face_count) +
                             "\nproperty list uchar int vertex_indices\nproperty uchar cut\nend_header\n";
  write_text_file(path, header + vertices + faces);
}

}  // namespace dvx
