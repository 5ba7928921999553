// divvox_peers: the same inputs divvox uses, through two peer libraries, so the report can set
// them side by side: CGAL's remeshing cut (clip by a plane, paper Fig. 13), OpenVDB's static
// surface extraction (mesh -> narrow-band level set -> mesh) at divvox's voxel size, and Bullet's
// soft body on divvox's own PBD particles and links.
// Only clip_cgal.cpp sees CGAL, only vdb.cpp OpenVDB, only bullet.cpp Bullet.
#pragma once

#include "sim/mesh.h"

#include <chrono>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace dvx::peers {

struct ClipOptions {
  std::string mesh;
  double height = 0.55;  // plane height as a fraction of the box's y extent (bench cut's blade)
  int repeats = 5;
  std::string out_dir;
};

struct VdbOptions {
  std::string mesh;
  std::vector<int> resolutions{64, 128, 256};  // voxels along the longest axis (as divvox)
  int repeats = 3;
  int threads = 1;                 // TBB threads; 0 = TBB's default
  uint64_t error_samples = 100000;  // area samples per side for the two-sided error
  std::string out_dir;
};

struct BulletOptions {
  std::string scene;                            // divvox scene file (its PBD model is given to Bullet)
  std::vector<int> iterations{5, 10, 20};       // solver iterations compared
  int reference_iterations = 100;               // divvox at this many iterations is the converged reference
  double seconds = 1.0;                         // simulated time from rest
  std::string out_dir;
};

// Each writes DIR/peers_<name>.json and .csv and returns the JSON path. Throw InputError on bad
// input; a peer library failing is measured, not thrown (the JSON's "status" says so).
std::string run_clip(const ClipOptions& options);
std::string run_vdb(const VdbOptions& options);
std::string run_bullet(const BulletOptions& options);

// Loads a mesh; every failure becomes an InputError naming the file.
TriMesh load_input(const std::string& path);

// Median of a sample (0 when empty).
double median(std::vector<double> values);

inline double ms_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
}

// One CSV table: a header and rows of already formatted cells, in column order.
struct CsvRow {
  std::vector<std::pair<std::string, std::string>> cells;  // (column name, value)
  void add(const std::string& name, const std::string& value) { cells.emplace_back(name, value); }
  void add(const std::string& name, double value);
  void add(const std::string& name, uint64_t value) { add(name, std::to_string(value)); }
  void add(const std::string& name, bool value) { add(name, std::string(value ? "true" : "false")); }
};
// Header from the first row, one line per row; cells with commas or quotes are quoted.
std::string csv_text(const std::vector<CsvRow>& rows);

}  // namespace dvx::peers
