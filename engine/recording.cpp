#include "engine/recording.h"

#include "engine/errors.h"

#include <fcntl.h>
#include <unistd.h>

#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace dvx {
namespace {

using json = nlohmann::json;

constexpr uint64_t kMaxStep = (uint64_t(1) << 31) - 1;

// Copies `text` with non-finite numbers outside strings (NaN / Infinity tokens, and numbers too
// large for a double such as 1e999) replaced by null, so a line that is only invalid because of
// them can still be read far enough to name its step. Returns whether any was replaced.
bool null_nonfinite_tokens(const std::string& text, std::string& out) {
  out.clear();
  bool found = false;
  bool in_string = false;
  for (size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (in_string) {
      out += c;
      if (c == '\\' && i + 1 < text.size()) out += text[++i];
      else if (c == '"') in_string = false;
      continue;
    }
    if (c == '"') in_string = true;
    // A number: kept unless it overflows a double.
    if (std::isdigit(static_cast<unsigned char>(c)) || c == '-' || c == '+' || c == '.') {
      size_t end = i;
      while (end < text.size() && text[end] != '\0' && std::strchr("0123456789.eE+-", text[end]) != nullptr) ++end;
      const std::string number = text.substr(i, end - i);
      const double x = std::strtod(number.c_str(), nullptr);
      if (!std::isfinite(x)) {
        out += "null";
        found = true;
      } else {
        out += number;
      }
      i = end - 1;
      continue;
    }
    if (!std::isalpha(static_cast<unsigned char>(c))) {
      out += c;
      continue;
    }
    // A bare word: true/false/null stay, NaN/Infinity spellings become null (dropping a sign).
    size_t end = i;
    while (end < text.size() && std::isalpha(static_cast<unsigned char>(text[end]))) ++end;
    std::string word = text.substr(i, end - i);
    for (char& w : word) w = char(std::tolower(static_cast<unsigned char>(w)));
    if (word == "nan" || word == "inf" || word == "infinity") {
      if (!out.empty() && (out.back() == '-' || out.back() == '+')) out.pop_back();
      out += "null";
      found = true;
    } else {
      out += text.substr(i, end - i);
    }
    i = end - 1;
  }
  return found;
}

// One parsed line: the JSON value, or the parser's complaint.
struct ParsedLine {
  bool ok = false;
  bool nonfinite = false;  // parsed only after replacing NaN/Infinity tokens by null
  json value;
  std::string error;
};

ParsedLine parse_line(const std::string& text) {
  ParsedLine p;
  try {
    p.value = json::parse(text);
    p.ok = true;
    return p;
  } catch (const json::exception& e) {  // parse_error, or out_of_range for 1e999
    p.error = e.what();
  }
  // NaN and Infinity are not JSON; read the line without them to report what they broke.
  std::string patched;
  if (null_nonfinite_tokens(text, patched)) {
    try {
      json value = json::parse(patched);
      if (value.is_object()) {
        p.value = std::move(value);
        p.ok = true;
        p.nonfinite = true;
      }
    } catch (const json::exception&) {
    }
  }
  return p;
}

bool is_blank(const std::string& text) {
  for (char c : text) {
    if (c != ' ' && c != '\t' && c != '\r') return false;
  }
  return true;
}

std::string line_prefix(uint32_t line) { return "line " + std::to_string(line) + ": "; }

// Reads the header line into `rec` (scene, dt).
void read_header(const json& h, const std::string& path, uint32_t line, Recording& rec) {
  const std::string at = line_prefix(line);
  if (!h.is_object() || !h.contains("format") || h["format"] != "divvox-recording") {
    throw_input(path, at + "not a divvox recording (the first line must be a header with \"format\": \"divvox-recording\")");
  }

  // Version: refuse what a newer divvox wrote rather than misread it.
  if (!h.contains("version") || !h["version"].is_number_unsigned() || h["version"].get<uint64_t>() == 0) {
    throw_input(path, at + "header: \"version\" must be a positive integer");
  }
  if (h["version"].get<uint64_t>() > uint64_t(kRecordingVersion)) {
    throw_input(path, at + "version " + h["version"].dump() + " is newer than this divvox reads (" +
                          std::to_string(kRecordingVersion) + ")");
  }

  // Scene: relative mesh paths resolve against the recording's folder.
  if (!h.contains("scene") || !h["scene"].is_object()) throw_input(path, at + "header: \"scene\" must be an object");
  try {
    rec.scene = parse_scene(h["scene"], path);
  } catch (const InputError& e) {
    std::string problem = e.what();
    const std::string own = input_message(path, "");
    if (problem.rfind(own, 0) == 0) problem = problem.substr(own.size());
    while (!problem.empty() && (problem.front() == ':' || problem.front() == ' ')) problem.erase(0, 1);
    throw_input(path, at + "scene: " + problem);
  }

  // Time step: the header's dt wins over the scene's solver.dt.
  if (!h.contains("dt") || !h["dt"].is_number() || !std::isfinite(h["dt"].get<double>()) ||
      h["dt"].get<double>() <= 0.0) {
    throw_input(path, at + "header: \"dt\" must be a positive finite number");
  }
  rec.dt = h["dt"].get<double>();
  rec.scene.pbd.dt = rec.dt;
  // Whether the hashes were taken with the physics on (optional; absent: unknown).
  if (h.contains("physics") && h["physics"].is_boolean()) rec.physics = h["physics"].get<bool>() ? 1 : 0;
}

// A finite 3D point from [x, y, z].
bool read_point(const json& j, Vec3d& p) {
  if (!j.is_array() || j.size() != 3) return false;
  for (int i = 0; i < 3; ++i) {
    if (!j[i].is_number()) return false;
    p[i] = j[i].get<double>();
    if (!std::isfinite(p[i])) return false;
  }
  return true;
}

bool is_hex(const std::string& s) {
  if (s.empty() || s.size() > 32) return false;
  for (char c : s) {
    if (!std::isxdigit(static_cast<unsigned char>(c))) return false;
  }
  return true;
}

// Reads one step line (without ordering checks).
RecordedStep read_step(const json& j, const std::string& path, uint32_t line) {
  const std::string at = line_prefix(line);
  if (!j.is_object()) throw_input(path, at + "step line is not a JSON object");
  RecordedStep s;
  s.line = line;

  // Step number: a non-negative integer below 2^31.
  if (!j.contains("step")) throw_input(path, at + "step line without \"step\"");
  const json& step = j["step"];
  if (!step.is_number_unsigned() || step.get<uint64_t>() > kMaxStep) {
    throw_input(path, at + "\"step\" must be an integer in [0, 2^31), got " + step.dump());
  }
  s.step = uint32_t(step.get<uint64_t>());
  const std::string at_step = at + "step " + std::to_string(s.step) + ": ";

  // Blade pose and cutting flag.
  if (j.contains("blade")) {
    const json& blade = j["blade"];
    if (!blade.is_array() || blade.size() != 2 || !read_point(blade[0], s.blade.a) || !read_point(blade[1], s.blade.b)) {
      throw_input(path, at_step + "blade is not two finite 3D points [[ax,ay,az],[bx,by,bz]]");
    }
    s.has_blade = true;
  }
  if (j.contains("cutting")) {
    if (!s.has_blade) throw_input(path, at_step + "\"cutting\" without a \"blade\"");
    if (!j["cutting"].is_boolean()) throw_input(path, at_step + "\"cutting\" must be true or false");
    s.cutting = j["cutting"].get<bool>();
  }

  // State hash (stored in lower case).
  if (j.contains("hash")) {
    if (!j["hash"].is_string() || !is_hex(j["hash"].get<std::string>())) {
      throw_input(path, at_step + "\"hash\" must be a string of 1 to 32 hex digits");
    }
    s.hash = j["hash"].get<std::string>();
    for (char& c : s.hash) c = char(std::tolower(static_cast<unsigned char>(c)));
    s.has_hash = true;
  }

  // Keys for other layers (grab, camera, ...), kept as they are.
  for (auto it = j.begin(); it != j.end(); ++it) {
    if (it.key() == "step" || it.key() == "blade" || it.key() == "cutting" || it.key() == "hash") continue;
    if (s.extra.is_null()) s.extra = json::object();
    s.extra[it.key()] = it.value();
  }
  return s;
}

// Writes all of `text` with write(), retrying on partial writes and interrupts.
bool write_all(int fd, const std::string& text) {
  size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
    if (n < 0) {
      if (errno == EINTR) continue;
      return false;
    }
    done += size_t(n);
  }
  return true;
}

// The scene's mesh path as seen from the recording's folder (relative when possible), so the
// header's scene resolves wherever the recording is written.
std::string mesh_for_recording(const Scene& scene, const std::string& path) {
  if (scene.mesh_path.empty()) return scene.mesh;
  std::error_code ec;
  const std::filesystem::path mesh = std::filesystem::absolute(scene.mesh_path, ec);
  if (ec) return scene.mesh_path;
  const std::filesystem::path dir = std::filesystem::absolute(path, ec).parent_path();
  if (ec) return mesh.string();
  const std::filesystem::path rel = std::filesystem::relative(mesh, dir, ec);
  if (ec || rel.empty()) return mesh.string();
  return rel.string();
}

}  // namespace

Recording read_recording(const std::string& path) {
  // The whole file (recordings are small: tens of bytes per step line).
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) throw_input(path, "no such file");
  if (std::filesystem::is_directory(path, ec)) throw_input(path, "is a directory, not a recording");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw_input(path, "cannot be opened for reading");
  std::ostringstream buffer;
  buffer << in.rdbuf();
  const std::string text = buffer.str();

  Recording rec;
  rec.file = path;
  bool have_header = false;
  uint32_t blade_line = 0;  // line of the blade pose of the current step (0: none yet)
  uint32_t hash_line = 0;   // line of the hash of the current step (0: none yet)

  // Line by line; the last one may lack its '\n' (a recording being written, or a crash).
  uint32_t line = 0;
  for (size_t pos = 0; pos < text.size();) {
    ++line;
    const size_t end = text.find('\n', pos);
    const bool terminated = end != std::string::npos;
    const std::string content = text.substr(pos, (terminated ? end : text.size()) - pos);
    pos = terminated ? end + 1 : text.size();
    if (is_blank(content)) continue;

    // Parse; an unterminated last line that does not parse was cut short while being written.
    const ParsedLine parsed = parse_line(content);
    if (!parsed.ok) {
      if (!terminated && have_header) {
        rec.warnings.push_back(input_message(path, line_prefix(line) + "truncated last line ignored"));
        break;
      }
      if (!have_header) {
        throw_input(path, line_prefix(line) + "not a divvox recording (the header is not valid JSON: " + parsed.error + ")");
      }
      throw_input(path, line_prefix(line) + "malformed JSON: " + parsed.error);
    }

    // The first line is the header.
    if (!have_header) {
      read_header(parsed.value, path, line, rec);
      if (parsed.nonfinite) throw_input(path, line_prefix(line) + "header holds NaN or Infinity (not valid JSON)");
      have_header = true;
      continue;
    }

    // A step line: valid by itself, then in order with the lines before it.
    RecordedStep s = read_step(parsed.value, path, line);
    const std::string at_step = line_prefix(line) + "step " + std::to_string(s.step) + ": ";
    if (parsed.nonfinite) throw_input(path, at_step + "holds NaN or Infinity (not valid JSON)");
    if (!rec.steps.empty()) {
      const RecordedStep& prev = rec.steps.back();
      if (s.step < prev.step) {
        throw_input(path, line_prefix(line) + "step " + std::to_string(s.step) + " comes after step " +
                              std::to_string(prev.step) + " (line " + std::to_string(prev.line) +
                              "); steps must not decrease");
      }
      if (s.step != prev.step) blade_line = hash_line = 0;
    }
    if (s.has_blade && blade_line != 0) {
      throw_input(path, line_prefix(line) + "step " + std::to_string(s.step) + " has two blade poses (first on line " +
                            std::to_string(blade_line) + ")");
    }
    if (s.has_hash && hash_line != 0) {
      throw_input(path, line_prefix(line) + "step " + std::to_string(s.step) + " has two hashes (first on line " +
                            std::to_string(hash_line) + ")");
    }
    if (s.has_blade) blade_line = line;
    if (s.has_hash) hash_line = line;
    rec.steps.push_back(std::move(s));
  }

  if (!have_header) throw_input(path, "empty file (no header)");
  return rec;
}

RecordingWriter::RecordingWriter(const std::string& path, const Scene& scene, double dt, int physics)
    : path_(path) {
  // Header first: the scene inline, its mesh path re-anchored at the recording's folder.
  json scene_json = scene_to_json(scene);
  scene_json["mesh"] = mesh_for_recording(scene, path);
  json header = {{"format", "divvox-recording"}, {"version", kRecordingVersion}, {"scene", scene_json}, {"dt", dt}};
  if (physics >= 0) header["physics"] = physics != 0;

  fd_ = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd_ < 0) throw_input(path, std::string("cannot create recording: ") + std::strerror(errno));
  if (!write_all(fd_, header.dump() + "\n")) {
    const int err = errno;
    ::close(fd_);
    fd_ = -1;
    throw_input(path, std::string("cannot write recording: ") + std::strerror(err));
  }
}

RecordingWriter::~RecordingWriter() {
  if (fd_ >= 0) ::close(fd_);
}

json blade_line(uint32_t step, const BladePose& blade, bool cutting) {
  // JSON has no NaN: a non-finite pose would make the file unreadable from here on.
  if (!blade.a.allFinite() || !blade.b.allFinite()) {
    throw std::invalid_argument("recording: non-finite blade pose at step " + std::to_string(step));
  }
  return {{"step", step},
          {"blade", {{blade.a.x(), blade.a.y(), blade.a.z()}, {blade.b.x(), blade.b.y(), blade.b.z()}}},
          {"cutting", cutting}};
}

void RecordingWriter::write_blade(uint32_t step, const BladePose& blade, bool cutting) {
  write_line(blade_line(step, blade, cutting));
}

void RecordingWriter::write_hash(uint32_t step, const std::string& hash) {
  write_line({{"step", step}, {"hash", hash}});
}

void RecordingWriter::write_line(const json& line) {
  // One write() per line: a crash leaves at most a partial last line.
  if (!line.is_object() || !line.contains("step") || !line["step"].is_number_integer() ||
      (!line["step"].is_number_unsigned() && line["step"].get<int64_t>() < 0) ||
      line["step"].get<uint64_t>() > kMaxStep) {
    throw std::invalid_argument("recording: a step line must be an object with \"step\" in [0, 2^31)");
  }
  if (!write_all(fd_, line.dump() + "\n")) {
    throw_input(path_, std::string("cannot write recording: ") + std::strerror(errno));
  }
}

}  // namespace dvx
