#include "bench/ccx.h"

#include "engine/options.h"
#include "sim/union_find.h"

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace dvx {
namespace {

namespace fs = std::filesystem;

// Corner c of a cell in CalculiX's C3D8 order: bottom face (z low) counter-clockwise, then top.
constexpr int kCorner[8][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}};

// True when the segment between two cell centres crosses the cut rectangle.
bool crosses(const CcxCut& cut, const Vec3d& a, const Vec3d& b) {
  const double sa = (a - cut.point).dot(cut.normal), sb = (b - cut.point).dot(cut.normal);
  if ((sa < 0.0) == (sb < 0.0)) return false;
  const Vec3d x = a + (sa / (sa - sb)) * (b - a);
  const double eps = 1e-9 * (1.0 + x.norm());  // the rounding of x, not of the (often unbounded) box
  return (x.array() >= cut.box.min.array() - eps).all() && (x.array() <= cut.box.max.array() + eps).all();
}

// A number in a deck (15 significant digits: CalculiX reads 20-character fields).
std::string g17(double v) {
  char text[40];
  std::snprintf(text, sizeof text, "%.15g", v);
  return text;
}

// Node ids as lines of at most 8 (CalculiX reads up to 16 entries per line).
void id_lines(std::ostream& out, const std::vector<uint32_t>& ids) {
  for (size_t i = 0; i < ids.size(); ++i) out << ids[i] + 1 << ((i % 8 == 7 || i + 1 == ids.size()) ? "\n" : ",");
}

}  // namespace

HexMesh make_hex_mesh(const Vec3d& origin, const Vec3d& spacing, const std::array<int, 3>& n,
                      const std::function<bool(const Vec3d&)>& inside, const std::vector<CcxCut>& cuts) {
  HexMesh m;
  m.origin = origin;
  m.spacing = spacing;
  m.nx = n[0];
  m.ny = n[1];
  m.nz = n[2];
  if (m.nx < 1 || m.ny < 1 || m.nz < 1) throw std::runtime_error("ccx: a mesh needs at least one cell per axis");
  const auto centre = [&](int i, int j, int k) {
    return Vec3d(origin.x() + (i + 0.5) * spacing.x(), origin.y() + (j + 0.5) * spacing.y(), origin.z() + (k + 0.5) * spacing.z());
  };
  // Occupied cells become elements.
  m.cell_element.assign(size_t(m.nx) * m.ny * m.nz, -1);
  for (int k = 0; k < m.nz; ++k) {
    for (int j = 0; j < m.ny; ++j) {
      for (int i = 0; i < m.nx; ++i) {
        if (!inside(centre(i, j, k))) continue;
        m.cell_element[m.cell(i, j, k)] = int32_t(m.elements.size());
        m.elements.push_back({});
        m.element_cell.push_back({i, j, k});
      }
    }
  }
  const auto element_at = [&](int i, int j, int k) {
    if (i < 0 || j < 0 || k < 0 || i >= m.nx || j >= m.ny || k >= m.nz) return -1;
    return m.cell_element[m.cell(i, j, k)];
  };
  // Each grid node: its (up to 8) cells, joined where they share a face no cut crosses; one node per group.
  for (int k = 0; k <= m.nz; ++k) {
    for (int j = 0; j <= m.ny; ++j) {
      for (int i = 0; i <= m.nx; ++i) {
        int32_t cell_of[8];  // block position b = dx | dy<<1 | dz<<2 around the node
        bool any = false;
        for (int b = 0; b < 8; ++b) {
          cell_of[b] = element_at(i - 1 + (b & 1), j - 1 + ((b >> 1) & 1), k - 1 + ((b >> 2) & 1));
          any = any || cell_of[b] >= 0;
        }
        if (!any) continue;
        uint8_t parent[8] = {0, 1, 2, 3, 4, 5, 6, 7};
        for (int b = 0; b < 8; ++b) {
          for (int axis = 0; axis < 3; ++axis) {
            const int o = b | (1 << axis);
            if (o == b || cell_of[b] < 0 || cell_of[o] < 0) continue;
            const Vec3d ca = centre(i - 1 + (b & 1), j - 1 + ((b >> 1) & 1), k - 1 + ((b >> 2) & 1));
            const Vec3d cb = centre(i - 1 + (o & 1), j - 1 + ((o >> 1) & 1), k - 1 + ((o >> 2) & 1));
            bool blocked = false;
            for (const CcxCut& cut : cuts) blocked = blocked || crosses(cut, ca, cb);
            if (!blocked) uf_unite<uint8_t>(parent, uint8_t(b), uint8_t(o));
          }
        }
        uint32_t node_of_root[8];
        std::fill(node_of_root, node_of_root + 8, ~0u);
        for (int b = 0; b < 8; ++b) {
          if (cell_of[b] < 0) continue;
          const uint8_t root = uf_find<uint8_t>(parent, uint8_t(b));
          if (node_of_root[root] == ~0u) {
            node_of_root[root] = uint32_t(m.nodes.size());
            m.nodes.push_back(origin + Vec3d(i * spacing.x(), j * spacing.y(), k * spacing.z()));
          }
          // The cell at block position b sees this node as its corner (1-dx, 1-dy, 1-dz).
          const int cx = 1 - (b & 1), cy = 1 - ((b >> 1) & 1), cz = 1 - ((b >> 2) & 1);
          for (int c = 0; c < 8; ++c) {
            if (kCorner[c][0] == cx && kCorner[c][1] == cy && kCorner[c][2] == cz) {
              m.elements[size_t(cell_of[b])][size_t(c)] = node_of_root[root];
            }
          }
        }
      }
    }
  }
  return m;
}

std::string ccx_deck(const HexMesh& mesh, const CcxProblem& p) {
  if (mesh.elements.empty()) throw std::runtime_error("ccx: the mesh has no element");
  if (!(p.youngs_modulus > 0.0) || !std::isfinite(p.youngs_modulus)) throw std::runtime_error("ccx: Young's modulus must be > 0");
  if (!(p.poisson_ratio > -1.0 && p.poisson_ratio < 0.5)) throw std::runtime_error("ccx: Poisson's ratio must lie in (-1, 0.5)");
  if (!(p.density > 0.0) || !std::isfinite(p.density)) throw std::runtime_error("ccx: density must be > 0");
  std::vector<uint32_t> fixed;
  for (uint32_t v = 0; v < mesh.nodes.size(); ++v) {
    for (const Aabb& box : p.fixed) {
      if ((mesh.nodes[v].array() >= box.min.array()).all() && (mesh.nodes[v].array() <= box.max.array()).all()) {
        fixed.push_back(v);
        break;
      }
    }
  }
  if (fixed.empty()) throw std::runtime_error("ccx: no node lies in a fixed box (the problem has no equilibrium)");

  std::ostringstream d;
  d << "** divvox: elastic reference (bench/ccx.cpp)\n*NODE, NSET=NALL\n";
  for (size_t v = 0; v < mesh.nodes.size(); ++v) {
    d << v + 1 << ", " << g17(mesh.nodes[v].x()) << ", " << g17(mesh.nodes[v].y()) << ", " << g17(mesh.nodes[v].z()) << "\n";
  }
  d << "*ELEMENT, TYPE=C3D8I, ELSET=EALL\n";
  for (size_t e = 0; e < mesh.elements.size(); ++e) {
    d << e + 1;
    for (uint32_t v : mesh.elements[e]) d << ", " << v + 1;
    d << "\n";
  }
  d << "*NSET, NSET=NFIX\n";
  id_lines(d, fixed);
  d << "*MATERIAL, NAME=TISSUE\n";
  const double E = p.youngs_modulus, nu = p.poisson_ratio;
  if (p.neo_hookean) {
    // Abaqus/CalculiX form: W = C10 (I1bar - 3) + (J - 1)^2 / D1, C10 = mu / 2, D1 = 2 / K.
    const double mu = E / (2.0 * (1.0 + nu)), bulk = E / (3.0 * (1.0 - 2.0 * nu));
    d << "*HYPERELASTIC, NEO HOOKE\n" << g17(0.5 * mu) << ", " << g17(2.0 / bulk) << "\n";
  } else {
    d << "*ELASTIC\n" << g17(E) << ", " << g17(nu) << "\n";
  }
  d << "*DENSITY\n" << g17(p.density) << "\n*SOLID SECTION, ELSET=EALL, MATERIAL=TISSUE\n";
  d << "*BOUNDARY\nNFIX, 1, 3, 0.\n";
  if (p.nlgeom) {
    const int n = std::max(1, p.increments);
    d << "*STEP, NLGEOM, INC=" << 50 * n << "\n*STATIC\n" << g17(1.0 / n) << ", 1.0, " << g17(1e-4 / n) << ", "
      << g17(1.0 / n) << "\n";
  } else {
    d << "*STEP\n*STATIC\n";
  }
  const double g = p.gravity.norm();
  if (g > 0.0) {
    const Vec3d dir = p.gravity / g;
    d << "*DLOAD\nEALL, GRAV, " << g17(g) << ", " << g17(dir.x()) << ", " << g17(dir.y()) << ", " << g17(dir.z()) << "\n";
  }
  d << "*NODE PRINT, NSET=NALL\nU\n*END STEP\n";
  return d.str();
}

std::string find_ccx() {
  const std::string configured = read_env_options().ccx;  // DIVVOX_CCX
  if (!configured.empty()) return fs::exists(configured) ? configured : "";
  const char* path = std::getenv("PATH");
  std::stringstream dirs(path ? path : "/usr/bin:/bin");
  for (std::string dir; std::getline(dirs, dir, ':');) {
    const fs::path candidate = fs::path(dir.empty() ? "." : dir) / "ccx";
    if (access(candidate.c_str(), X_OK) == 0) return candidate.string();
  }
  return "";
}

bool parse_ccx_displacements(const std::string& dat, size_t node_count, std::vector<Vec3d>& out, std::string& error) {
  // The last table: a header line with "displacements", a blank line, then "id ux uy uz" rows.
  const size_t header = dat.rfind("displacements");
  if (header == std::string::npos) {
    error = "no displacement table in the .dat file";
    return false;
  }
  std::istringstream lines(dat.substr(dat.find('\n', header) + 1));
  std::vector<Vec3d> u(node_count, Vec3d::Constant(std::nan("")));
  size_t read = 0;
  for (std::string line; std::getline(lines, line);) {
    std::istringstream row(line);
    long id = 0;
    double x = 0, y = 0, z = 0;
    if (!(row >> id)) {
      if (read > 0) break;  // the blank line after the table
      continue;
    }
    if (!(row >> x >> y >> z) || id < 1 || size_t(id) > node_count) {
      error = "malformed displacement row: " + line;
      return false;
    }
    u[size_t(id - 1)] = Vec3d(x, y, z);
    ++read;
  }
  for (const Vec3d& v : u) {
    if (!v.allFinite()) {
      error = "the displacement table misses nodes or holds non-finite values (" + std::to_string(read) + " of " +
              std::to_string(node_count) + " rows)";
      return false;
    }
  }
  out = std::move(u);
  return true;
}

CcxResult run_ccx(const HexMesh& mesh, const std::string& deck, double timeout_seconds, const std::string& keep_dir) {
  CcxResult r;
  const std::string ccx = find_ccx();
  if (ccx.empty()) {
    r.error = "ccx (CalculiX, Debian calculix-ccx) not found: install it with tools/setup.sh";
    return r;
  }
  fs::path dir;
  if (keep_dir.empty()) {
    std::string pattern = (fs::temp_directory_path() / "divvox-ccx-XXXXXX").string();
    if (!mkdtemp(pattern.data())) {
      r.error = "cannot create a temporary folder";
      return r;
    }
    dir = pattern;
  } else {
    dir = keep_dir;
    fs::create_directories(dir);
  }
  std::ofstream(dir / "job.inp") << deck;
  const auto t0 = std::chrono::steady_clock::now();
  // ccx in the folder (it writes job.dat, job.frd, job.sta, spooles.out beside the deck), one thread,
  // killed at the time limit.
  const pid_t pid = fork();
  if (pid == 0) {
    if (chdir(dir.c_str()) != 0) _exit(126);
    if (!freopen("ccx.log", "w", stdout) || !freopen("ccx.log", "a", stderr)) _exit(126);
    setenv("OMP_NUM_THREADS", "1", 1);
    setenv("CCX_NPROC_EQUATION_SOLVER", "1", 1);
    execl(ccx.c_str(), ccx.c_str(), "-i", "job", static_cast<char*>(nullptr));
    _exit(127);
  }
  int status = 0;
  bool done = false;
  while (!done) {
    const pid_t w = waitpid(pid, &status, WNOHANG);
    if (w == pid) {
      done = true;
      break;
    }
    const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (elapsed > timeout_seconds) {
      kill(pid, SIGKILL);
      waitpid(pid, &status, 0);
      r.error = "ccx ran past its time limit of " + std::to_string(int(timeout_seconds)) + " s";
      break;
    }
    usleep(2000);
  }
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (done) {
    std::ifstream dat(dir / "job.dat");
    std::stringstream text;
    text << dat.rdbuf();
    if (!(WIFEXITED(status) && WEXITSTATUS(status) == 0)) {
      r.error = "ccx failed (exit " + std::to_string(WIFEXITED(status) ? WEXITSTATUS(status) : -1) + ", see ccx.log)";
    }
    std::string parse_error;
    if (r.error.empty()) {
      r.ok = parse_ccx_displacements(text.str(), mesh.nodes.size(), r.displacement, parse_error);
      if (!r.ok) r.error = parse_error;
    }
    if (!r.ok && fs::exists(dir / "ccx.log")) {
      // The last lines of ccx's log say why (e.g. no convergence).
      std::ifstream log(dir / "ccx.log");
      std::vector<std::string> tail;
      for (std::string line; std::getline(log, line);) {
        if (line.find_first_not_of(' ') == std::string::npos) continue;
        tail.push_back(line);
        if (tail.size() > 3) tail.erase(tail.begin());
      }
      for (const std::string& line : tail) r.error += " | " + line;
    }
  }
  if (keep_dir.empty()) {
    std::error_code ignored;
    fs::remove_all(dir, ignored);
  }
  return r;
}

bool interpolate_displacement(const HexMesh& mesh, const std::vector<Vec3d>& u, const Vec3d& point, Vec3d& out,
                              int search, const Vec3d& hint) {
  // The cell holding the (hinted) point, else the nearest occupied cell around it.
  const Vec3d probe = point + hint;
  const Vec3d f = (probe - mesh.origin).cwiseQuotient(mesh.spacing);
  const int n[3] = {mesh.nx, mesh.ny, mesh.nz};
  int c[3];
  for (int a = 0; a < 3; ++a) c[a] = std::clamp(int(std::floor(f[a])), 0, n[a] - 1);
  int32_t element = mesh.cell_element[mesh.cell(c[0], c[1], c[2])];
  int best[3] = {c[0], c[1], c[2]};
  if (element < 0) {
    double best_d = 1e300;
    for (int dk = -search; dk <= search; ++dk) {
      for (int dj = -search; dj <= search; ++dj) {
        for (int di = -search; di <= search; ++di) {
          const int q[3] = {c[0] + di, c[1] + dj, c[2] + dk};
          if (q[0] < 0 || q[1] < 0 || q[2] < 0 || q[0] >= n[0] || q[1] >= n[1] || q[2] >= n[2]) continue;
          const int32_t e = mesh.cell_element[mesh.cell(q[0], q[1], q[2])];
          if (e < 0) continue;
          double d = 0.0;  // squared distance from the probe to the cell's box
          for (int a = 0; a < 3; ++a) {
            const double lo = mesh.origin[a] + q[a] * mesh.spacing[a], hi = lo + mesh.spacing[a];
            const double x = std::clamp(probe[a], lo, hi) - probe[a];
            d += x * x;
          }
          if (d < best_d) {
            best_d = d;
            element = e;
            std::copy(q, q + 3, best);
          }
        }
      }
    }
    if (element < 0) return false;
  }
  // Trilinear in that cell at the point itself (clamped to the cell).
  Vec3d t;
  for (int a = 0; a < 3; ++a) {
    t[a] = std::clamp((point[a] - mesh.origin[a]) / mesh.spacing[a] - best[a], 0.0, 1.0);
  }
  out = Vec3d::Zero();
  const std::array<uint32_t, 8>& corners = mesh.elements[size_t(element)];
  for (int k = 0; k < 8; ++k) {
    const double w = (kCorner[k][0] ? t.x() : 1.0 - t.x()) * (kCorner[k][1] ? t.y() : 1.0 - t.y()) *
                     (kCorner[k][2] ? t.z() : 1.0 - t.z());
    out += w * u[corners[size_t(k)]];
  }
  return true;
}

}  // namespace dvx
