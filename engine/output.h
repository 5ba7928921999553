// Writing output files without losing anything: create the folder, write to a temporary
// file beside the target, rename over it (a crash never leaves a half-written file).
#pragma once

#include <nlohmann/json_fwd.hpp>

#include <string>

namespace dvx {

// Creates `dir` (and parents); throws InputError naming it when that is impossible.
void make_output_dir(const std::string& dir);
// Writes text atomically; throws std::runtime_error on I/O failure.
void write_text_file(const std::string& path, const std::string& text);
void write_json_file(const std::string& path, const nlohmann::json& json);

}  // namespace dvx
