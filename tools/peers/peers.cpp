// divvox_peers: command line (CLI11) and the helpers the two peer benchmarks share.
#include "tools/peers/peers.h"

#include "engine/errors.h"
#include "engine/mesh_io.h"

#include <CLI/CLI.hpp>

#include <algorithm>
#include <cstdio>
#include <new>
#include <sstream>

namespace dvx::peers {

TriMesh load_input(const std::string& path) {
  try {
    return load_mesh(path).mesh;
  } catch (const InputError&) {
    throw;
  } catch (const std::bad_alloc&) {
    throw;
  } catch (const std::exception& e) {
    throw_input(path, e.what());
  }
}

double median(std::vector<double> values) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  const size_t n = values.size();
  return n % 2 == 1 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

void CsvRow::add(const std::string& name, double value) {
  char text[64];
  std::snprintf(text, sizeof text, "%.9g", value);
  add(name, std::string(text));
}

std::string csv_text(const std::vector<CsvRow>& rows) {
  // One cell, quoted when it holds a separator or a quote.
  auto cell = [](const std::string& s) {
    if (s.find_first_of(",\"\n") == std::string::npos) return s;
    std::string quoted = "\"";
    for (char c : s) quoted += c == '"' ? std::string("\"\"") : std::string(1, c);
    return quoted + "\"";
  };
  std::ostringstream out;
  if (rows.empty()) return {};
  // Header from the first row's column names.
  for (size_t i = 0; i < rows[0].cells.size(); ++i) out << (i ? "," : "") << cell(rows[0].cells[i].first);
  out << '\n';
  for (const CsvRow& row : rows) {
    for (size_t i = 0; i < row.cells.size(); ++i) out << (i ? "," : "") << cell(row.cells[i].second);
    out << '\n';
  }
  return out.str();
}

namespace {

// "64,128,256" -> integers in [low, high] (resolutions, iteration counts).
}  // namespace
}  // namespace dvx::peers

int main(int argc, char** argv) {
  using namespace dvx;
  using namespace dvx::peers;

  // Subcommands and their flags.
  CLI::App app{"divvox_peers: divvox's benchmark inputs through CGAL (clip), OpenVDB (level set) and Bullet (soft body)"};
  app.require_subcommand(1);

  ClipOptions clip;
  CLI::App* clip_cmd = app.add_subcommand(
      "clip", "CGAL remeshing cut: clip the mesh by the bench-cut plane (y at --height of the box), keep both\n"
              "sides; medians of the clip times, output triangles and their angle quality -> peers_clip.json/.csv");
  clip_cmd->add_option("--mesh,-m", clip.mesh, "Input mesh")->required();
  clip_cmd->add_option("--height", clip.height, "Plane height as a fraction of the box's y extent")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  clip_cmd->add_option("--repeats", clip.repeats, "Timed repeats (medians)")->check(CLI::Range(1, 1000))->capture_default_str();
  clip_cmd->add_option("--out,-o", clip.out_dir, "Output folder")->required();

  VdbOptions vdb;
  std::string resolutions = "64,128,256";
  CLI::App* vdb_cmd = app.add_subcommand(
      "vdb", "OpenVDB static extraction at divvox's voxel size: meshToLevelSet + volumeToMesh per resolution,\n"
             "medians of the times, error to the input in voxels, grid memory -> peers_vdb.json/.csv");
  vdb_cmd->add_option("--mesh,-m", vdb.mesh, "Input mesh")->required();
  vdb_cmd->add_option("--resolutions", resolutions, "Comma-separated resolutions")->capture_default_str();
  vdb_cmd->add_option("--repeats", vdb.repeats, "Timed repeats (medians)")->check(CLI::Range(1, 1000))->capture_default_str();
  vdb_cmd->add_option("--threads", vdb.threads, "TBB threads (0 = TBB default)")->check(CLI::Range(0, 1024))->capture_default_str();
  vdb_cmd->add_option("--error-samples", vdb.error_samples, "Area samples per side for the error (0 = none)")
      ->capture_default_str();
  vdb_cmd->add_option("--out,-o", vdb.out_dir, "Output folder")->required();

  BulletOptions bullet;
  std::string bullet_iterations = "5,10,20";
  CLI::App* bullet_cmd = app.add_subcommand(
      "bullet", "Bullet soft body (btSoftBody) on divvox's PBD particles and links of a scene, at the same\n"
                "iterations, dt, damping and gravity: time per step against divvox's pbd_step, sag under gravity\n"
                "against a converged reference (divvox at many iterations) -> peers_bullet.json/.csv");
  bullet_cmd->add_option("--scene,-s", bullet.scene, "Scene file")->required();
  bullet_cmd->add_option("--iterations", bullet_iterations, "Comma-separated iteration counts")->capture_default_str();
  bullet_cmd->add_option("--reference-iterations", bullet.reference_iterations, "Iterations of the converged reference")
      ->check(CLI::Range(1, 100000))
      ->capture_default_str();
  bullet_cmd->add_option("--seconds", bullet.seconds, "Simulated time from rest")->check(CLI::Range(0.01, 60.0))->capture_default_str();
  bullet_cmd->add_option("--out,-o", bullet.out_dir, "Output folder")->required();

  // Bad flags: one line, exit 2.
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "divvox_peers: error: %s (see divvox_peers --help)\n", e.what());
    return kExitBadInput;
  }

  // Run the chosen benchmark; bad input -> "divvox_peers: error: FILE: problem", exit 2.
  try {
    std::string written;
    if (clip_cmd->parsed()) {
      written = run_clip(clip);
    } else if (bullet_cmd->parsed()) {
      bullet.iterations = parse_int_list("--iterations", bullet_iterations, 1, 100000);
      written = run_bullet(bullet);
    } else {
      vdb.resolutions = parse_int_list("--resolutions", resolutions, 1, 4096);
      written = run_vdb(vdb);
    }
    std::printf("wrote %s\n", written.c_str());
    return kExitOk;
  } catch (...) {
    return exit_for_current_exception("divvox_peers");
  }
}
