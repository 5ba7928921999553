// Writing output files without losing anything: create the folder, write to a temporary
// file beside the target, rename over it (a crash never leaves a half-written file).
#pragma once

#include <nlohmann/json_fwd.hpp>

#include "sim/cut.h"

#include <string>
#include <vector>

namespace dvx {

// Creates `dir` (and parents); throws InputError naming it when that is impossible.
void make_output_dir(const std::string& dir);
// Writes text atomically; throws std::runtime_error on I/O failure.
void write_text_file(const std::string& path, const std::string& text);
void write_json_file(const std::string& path, const nlohmann::json& json);

// The surface's live slots as a binary PLY (float x y z; faces with a `uchar cut` property, 1 on cut
// faces), at the `deformed` positions when given (world space), else the rest positions.
void write_cut_mesh_ply(const std::string& path, const CutSurface& surface, const std::vector<Vec3f>* deformed);

}  // namespace dvx
