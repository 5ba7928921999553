#include "sim/blade_sweep.h"

#include <Eigen/Geometry>
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <numeric>
#include <random>
#include <set>
#include <vector>

using namespace dvx;

namespace {

using i128 = __int128;
constexpr int64_t F = 65536;  // fixed-point units per voxel (2^-16 voxel snapping)

Lattice grid(int nx, int ny, int nz, Vec3d origin = Vec3d::Zero(), double voxel = 1.0) {
  Lattice l;
  l.origin = origin;
  l.voxel_size = voxel;
  l.nx = nx;
  l.ny = ny;
  l.nz = nz;
  return l;
}

int64_t count_of(const Lattice& l, int a) { return a == 0 ? l.nx : a == 1 ? l.ny : l.nz; }

uint64_t stride_of(const Lattice& l, int a) {
  return a == 0 ? 1 : a == 1 ? uint64_t(l.nx + 1) : uint64_t(l.nx + 1) * uint64_t(l.ny + 1);
}

// Scene position of a point given in fixed-point lattice units (exact for dyadic origin and voxel size).
Vec3d scene(const Lattice& l, const int64_t v[3]) {
  return l.origin + l.voxel_size * Vec3d(double(v[0]) / F, double(v[1]) / F, double(v[2]) / F);
}

// Lattice position (voxel units) -> scene.
Vec3d at(const Lattice& l, const Vec3d& q) { return l.origin + l.voxel_size * q; }

int sgn(i128 v) { return (v > 0) - (v < 0); }

struct RefStats {
  uint64_t boundary_lines = 0;  // lines through a triangle edge or vertex (inclusive cases)
  uint64_t on_plane_nodes = 0;  // crossings decided by the perturbation
  uint64_t flat_axes = 0;       // non-degenerate triangles with a zero-area projection
};

// Brute force over every lattice edge with the documented rules, written as a node-side test:
// an edge is cut iff its line lies in the projected triangle (inclusive) and its two nodes are on
// different sides of the plane, a node on the plane taking the side of its perturbed position
// node + eps (1, eps, eps^2). t = f(lo) / (f(lo) - f(hi)).
std::map<uint32_t, long double> reference_hits(const Lattice& l, const int64_t v[3][3], RefStats* rs = nullptr) {
  std::map<uint32_t, long double> hits;
  i128 e1[3], e2[3];
  for (int a = 0; a < 3; ++a) {
    e1[a] = v[1][a] - v[0][a];
    e2[a] = v[2][a] - v[0][a];
  }
  const i128 n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
  const int perturbed = n[0] != 0 ? sgn(n[0]) : n[1] != 0 ? sgn(n[1]) : sgn(n[2]);
  if (perturbed == 0) return hits;  // degenerate triangle
  auto side = [&](const int64_t node[3], i128* f_out) {
    i128 f = 0;
    for (int a = 0; a < 3; ++a) f += n[a] * (i128(node[a]) * F - v[0][a]);
    *f_out = f;
    return f > 0 ? 1 : f < 0 ? -1 : perturbed;
  };
  for (int a = 0; a < 3; ++a) {
    const int b = (a + 1) % 3, c = (a + 2) % 3;
    auto orient = [&](int p, int q, i128 x, i128 y) {
      return (i128(v[q][b]) - v[p][b]) * (y - v[p][c]) - (i128(v[q][c]) - v[p][c]) * (x - v[p][b]);
    };
    const i128 area = orient(0, 1, v[2][b], v[2][c]);
    if (area == 0 && rs) ++rs->flat_axes;
    for (int64_t k = 0; k <= count_of(l, c); ++k) {
      for (int64_t j = 0; j <= count_of(l, b); ++j) {
        if (area == 0) continue;
        const i128 o[3] = {orient(0, 1, j * F, k * F), orient(1, 2, j * F, k * F), orient(2, 0, j * F, k * F)};
        bool inside = true;
        for (int i = 0; i < 3; ++i) inside = inside && (area > 0 ? o[i] >= 0 : o[i] <= 0);
        if (!inside) continue;
        if (rs && (o[0] == 0 || o[1] == 0 || o[2] == 0)) ++rs->boundary_lines;
        for (int64_t i = 0; i < count_of(l, a); ++i) {
          int64_t lo[3], hi[3];
          lo[a] = i;
          hi[a] = i + 1;
          lo[b] = hi[b] = j;
          lo[c] = hi[c] = k;
          i128 f_lo, f_hi;
          if (side(lo, &f_lo) == side(hi, &f_hi)) continue;
          long double t;
          if (f_lo == 0) {
            t = 0;
          } else if (f_hi == 0) {
            t = 1;
          } else {
            t = (long double)f_lo / ((long double)f_lo - (long double)f_hi);
          }
          if (rs && (f_lo == 0 || f_hi == 0)) ++rs->on_plane_nodes;
          const uint64_t node = uint64_t(lo[0]) + uint64_t(l.nx + 1) * (uint64_t(lo[1]) + uint64_t(l.ny + 1) * uint64_t(lo[2]));
          hits[Lattice::edge(uint32_t(node), a)] = t;
        }
      }
    }
  }
  return hits;
}

// Hits of one triangle as a map; checks the per-triangle invariants (no edge twice, t in [0, 1],
// one unit normal for the whole triangle).
std::map<uint32_t, float> triangle_map(const Lattice& l, const Vec3d& p0, const Vec3d& p1, const Vec3d& p2,
                                       SweepStats* stats = nullptr) {
  std::vector<EdgeHit> hits;
  triangle_edge_hits(l, p0, p1, p2, hits, stats);
  std::map<uint32_t, float> m;
  for (const EdgeHit& h : hits) {
    CHECK(m.count(h.edge) == 0);
    CHECK(h.t >= 0.0f);
    CHECK(h.t <= 1.0f);
    CHECK(std::abs(h.normal.norm() - 1.0f) < 1e-5f);
    CHECK((h.normal - hits.front().normal).norm() == 0.0f);
    m[h.edge] = h.t;
  }
  return m;
}

// Lattice graph minus cut edges: number of connected components (union-find).
struct Components {
  int count = 0;
  std::vector<uint32_t> label;  // component root per node
};

Components components(const Lattice& l, const std::set<uint32_t>& cut) {
  const uint32_t nodes = uint32_t(l.node_count());
  std::vector<uint32_t> parent(nodes);
  std::iota(parent.begin(), parent.end(), 0u);
  auto find = [&](uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  for (int32_t k = 0; k <= l.nz; ++k) {
    for (int32_t j = 0; j <= l.ny; ++j) {
      for (int32_t i = 0; i <= l.nx; ++i) {
        const uint32_t n = l.node(i, j, k);
        const int32_t c[3] = {i, j, k};
        for (int a = 0; a < 3; ++a) {
          if (c[a] + 1 > count_of(l, a) || cut.count(Lattice::edge(n, a))) continue;
          const uint32_t ra = find(n), rb = find(n + uint32_t(stride_of(l, a)));
          if (ra != rb) parent[ra] = rb;
        }
      }
    }
  }
  Components out;
  out.label.resize(nodes);
  for (uint32_t n = 0; n < nodes; ++n) {
    out.label[n] = find(n);
    if (out.label[n] == n) ++out.count;
  }
  return out;
}

// Distinct cut edges per lattice line; key = (axis, node of the line's first node).
std::map<std::pair<int, uint32_t>, int> cuts_per_line(const Lattice& l, const std::set<uint32_t>& cut) {
  std::map<std::pair<int, uint32_t>, int> lines;
  for (uint32_t e : cut) {
    const int a = int(e % 3);
    int32_t c[3];
    l.node_coords(e / 3, c);
    c[a] = 0;
    ++lines[{a, l.node(c[0], c[1], c[2])}];
  }
  return lines;
}

// Sweeps the blade through `poses` (consecutive pairs); returns the distinct cut edges with their t.
std::map<uint32_t, float> sweep_path(const Lattice& l, const std::vector<BladePose>& poses,
                                     SweepStats* stats = nullptr) {
  std::vector<EdgeHit> hits;
  for (size_t i = 0; i + 1 < poses.size(); ++i) sweep_edge_hits(l, poses[i], poses[i + 1], hits, stats);
  std::map<uint32_t, float> m;
  for (const EdgeHit& h : hits) m[h.edge] = h.t;
  return m;
}

std::set<uint32_t> keys(const std::map<uint32_t, float>& m) {
  std::set<uint32_t> s;
  for (const auto& [e, t] : m) s.insert(e);
  return s;
}

// A straight blade (centre c, direction d, half length h) translated along w, from s = -span to
// s = +span in steps of `step` (the last step may be shorter).
std::vector<BladePose> translated_blade(const Lattice& l, const Vec3d& c, const Vec3d& d, double h, const Vec3d& w,
                                        double span, double step) {
  std::vector<BladePose> poses;
  for (double s = -span;; s += step) {
    s = std::min(s, span);
    const Vec3d centre = c + s * w;
    poses.push_back(BladePose{at(l, centre - h * d), at(l, centre + h * d)});
    if (s >= span) break;
  }
  return poses;
}

// Node side of the plane A x + B y + C z = D (integer coefficients, lattice units) with the
// documented perturbation for nodes on the plane.
int plane_side(const int64_t g[4], int64_t i, int64_t j, int64_t k) {
  const int64_t f = g[0] * i + g[1] * j + g[2] * k - g[3];
  if (f != 0) return f > 0 ? 1 : -1;
  return g[0] != 0 ? (g[0] > 0 ? 1 : -1) : g[1] != 0 ? (g[1] > 0 ? 1 : -1) : (g[2] > 0 ? 1 : -1);
}

// Sweeps a sheet lying exactly in the plane g (blade along u through p, moved along w, dyadic
// everything so snapping is exact) and checks the cut against the exact partition of the nodes.
void check_plane_partition(const Lattice& l, const int64_t g[4], const Vec3d& p, const Vec3d& u, const Vec3d& w,
                           double step) {
  const std::vector<BladePose> poses = translated_blade(l, p, u, 64.0, w, 64.0, step);
  const std::map<uint32_t, float> cut = sweep_path(l, poses);
  std::map<uint32_t, float> expected;
  for (int32_t k = 0; k <= l.nz; ++k) {
    for (int32_t j = 0; j <= l.ny; ++j) {
      for (int32_t i = 0; i <= l.nx; ++i) {
        const int32_t c[3] = {i, j, k};
        for (int a = 0; a < 3; ++a) {
          if (c[a] + 1 > count_of(l, a)) continue;
          int32_t d[3] = {i, j, k};
          ++d[a];
          if (plane_side(g, i, j, k) == plane_side(g, d[0], d[1], d[2])) continue;
          const double f_lo = double(g[0] * i + g[1] * j + g[2] * k - g[3]);
          const double f_hi = double(g[0] * d[0] + g[1] * d[1] + g[2] * d[2] - g[3]);
          expected[Lattice::edge(l.node(i, j, k), a)] = float(f_lo == 0 ? 0.0 : f_hi == 0 ? 1.0 : f_lo / (f_lo - f_hi));
        }
      }
    }
  }
  REQUIRE(expected.size() > 0);
  CHECK(keys(cut) == keys(expected));
  for (const auto& [e, t] : expected) {
    auto it = cut.find(e);
    if (it != cut.end()) CHECK(std::abs(it->second - t) < 1e-6);
  }
  // Every line crossing the plane has exactly one cut edge, no line has two.
  std::set<std::pair<int, uint32_t>> crossing_lines;
  for (const auto& [e, t] : expected) {
    const int a = int(e % 3);
    int32_t c[3];
    l.node_coords(e / 3, c);
    c[a] = 0;
    crossing_lines.insert({a, l.node(c[0], c[1], c[2])});
  }
  const auto per_line = cuts_per_line(l, keys(cut));
  CHECK(per_line.size() == crossing_lines.size());
  for (const auto& [line, n] : per_line) {
    CHECK(n == 1);
    CHECK(crossing_lines.count(line) == 1);
  }
  // No material bridge through the sheet and no isolated node: exactly two components.
  CHECK(components(l, keys(cut)).count == 2);
}

}  // namespace

TEST_SUITE("blade_sweep") {
  TEST_CASE("random triangles match a brute force over every lattice edge") {
    std::mt19937_64 rng(0x5eed5eedull);
    auto rnd = [&](int64_t lo, int64_t hi) { return lo + int64_t(rng() % uint64_t(hi - lo + 1)); };
    const Lattice lattices[2] = {grid(7, 6, 5), grid(6, 5, 7, Vec3d(-1.5, 0.25, 2.0), 0.5)};
    RefStats rs;
    uint64_t total_hits = 0, degenerate = 0, mismatched = 0;
    for (int trial = 0; trial < 4000; ++trial) {
      const Lattice& l = lattices[trial % 2];
      int64_t v[3][3];
      const int kind = (trial / 2) % 6;
      for (int p = 0; p < 3; ++p) {
        for (int a = 0; a < 3; ++a) {
          const int64_t n = count_of(l, a);
          switch (kind) {
            case 0: v[p][a] = rnd(-4, 2 * n + 4) * (F / 2); break;   // half voxels: many exact hits
            case 1: v[p][a] = rnd(-8, 4 * n + 8) * (F / 4); break;   // quarter voxels
            case 2: v[p][a] = rnd(-2 * F, (n + 2) * F); break;       // generic fixed point
            case 3: v[p][a] = rnd(-1, n + 1) * F; break;             // lattice nodes as vertices
            default: v[p][a] = (p == 2 ? rnd(-2 * F, (n + 2) * F) : rnd(-2, 2 * n + 2) * (F / 2)); break;
          }
        }
      }
      if (kind == 3 && rnd(0, 1) == 0) {  // axis-parallel triangle (often through nodes)
        const int a = int(rnd(0, 2));
        v[1][a] = v[2][a] = v[0][a];
      }
      if (kind == 5 && rnd(0, 3) == 0) {  // collinear: zero area
        for (int a = 0; a < 3; ++a) v[2][a] = 2 * v[1][a] - v[0][a];
      }
      const auto ref = reference_hits(l, v, &rs);
      const auto got = triangle_map(l, scene(l, v[0]), scene(l, v[1]), scene(l, v[2]));
      if (ref.empty()) ++degenerate;
      total_hits += got.size();
      bool same = ref.size() == got.size();
      for (const auto& [e, t] : ref) {
        auto it = got.find(e);
        if (it == got.end() || std::abs((long double)it->second - t) > 1e-6L) same = false;
      }
      if (!same) {
        ++mismatched;
        if (mismatched <= 3) {
          MESSAGE("trial " << trial << ": reference " << ref.size() << " hits, got " << got.size());
        }
      }
      // The sweep entry point is the two triangles a0 b0 b1 and a0 b1 a1.
      if (trial % 16 == 0) {
        const BladePose from{scene(l, v[0]), scene(l, v[1])};
        const BladePose to{scene(l, v[0]) + (scene(l, v[2]) - scene(l, v[1])), scene(l, v[2])};
        std::vector<EdgeHit> hits;
        sweep_edge_hits(l, from, to, hits);
        std::multiset<uint32_t> got_sweep, want_sweep;
        for (const EdgeHit& h : hits) got_sweep.insert(h.edge);
        for (const auto& [e, t] : triangle_map(l, from.a, from.b, to.b)) want_sweep.insert(e);
        for (const auto& [e, t] : triangle_map(l, from.a, to.b, to.a)) want_sweep.insert(e);
        CHECK(got_sweep == want_sweep);
      }
    }
    CHECK(mismatched == 0);
    // The random set really exercised the degenerate rules.
    MESSAGE("hits " << total_hits << ", boundary lines " << rs.boundary_lines << ", on-plane nodes "
                    << rs.on_plane_nodes << ", flat projections " << rs.flat_axes << ", empty " << degenerate);
    CHECK(total_hits > 20000);
    CHECK(rs.boundary_lines > 1000);
    CHECK(rs.on_plane_nodes > 1000);
    CHECK(rs.flat_axes > 300);
  }

  TEST_CASE("huge triangles (up to and beyond the 2^23-voxel clamp window) match the brute force") {
    // Magnitudes near the window exercise the widest products (about 2^123); coordinates beyond it
    // are clamped onto the window before snapping, which the reference reproduces.
    std::mt19937_64 rng(99);
    auto rnd = [&](int64_t lo, int64_t hi) { return lo + int64_t(rng() % uint64_t(hi - lo + 1)); };
    const Lattice l = grid(6, 7, 5);
    const int64_t limit = (int64_t(1) << 23) * F;
    uint64_t hits = 0, mismatched = 0;
    for (int trial = 0; trial < 1500; ++trial) {
      double in[3][3];
      int64_t v[3][3];
      for (int a = 0; a < 3; ++a) {
        in[0][a] = double(rnd(0, count_of(l, a) * F)) / F;  // one vertex in the lattice
        for (int p = 1; p < 3; ++p) {
          const int kind = int(rnd(0, 3));
          in[p][a] = kind == 0   ? double(rnd(-limit, limit)) / F          // anywhere in the window
                     : kind == 1 ? double(rnd(-limit, limit) / F)          // whole voxels
                     : kind == 2 ? (rnd(0, 1) ? 1.0 : -1.0) * double(int64_t(1) << 23)  // on the window
                                 : (rnd(0, 1) ? 1e9 : -3e12);               // clamped
        }
      }
      for (int p = 0; p < 3; ++p) {
        for (int a = 0; a < 3; ++a) v[p][a] = std::clamp<int64_t>(int64_t(std::llround(std::clamp(in[p][a], -1e13, 1e13) * F)), -limit, limit);
      }
      const auto ref = reference_hits(l, v);
      const auto got = triangle_map(l, Vec3d(in[0][0], in[0][1], in[0][2]), Vec3d(in[1][0], in[1][1], in[1][2]),
                                    Vec3d(in[2][0], in[2][1], in[2][2]));
      hits += got.size();
      bool same = ref.size() == got.size();
      for (const auto& [e, t] : ref) {
        auto it = got.find(e);
        if (it == got.end() || std::abs((long double)it->second - t) > 1e-6L) same = false;
      }
      mismatched += !same;
    }
    CHECK(mismatched == 0);
    CHECK(hits > 5000);
  }

  TEST_CASE("the hit normal is the unit normal of the triangle") {
    const Lattice l = grid(8, 8, 8, Vec3d(1, 2, 3), 0.25);
    const Vec3d p0 = at(l, Vec3d(0.5, 0.25, 1)), p1 = at(l, Vec3d(7, 2, 3.5)), p2 = at(l, Vec3d(2, 7.5, 6));
    std::vector<EdgeHit> hits;
    triangle_edge_hits(l, p0, p1, p2, hits);
    REQUIRE(hits.size() > 10);
    const Vec3d n = (p1 - p0).cross(p2 - p0).normalized();
    for (const EdgeHit& h : hits) CHECK(std::abs(std::abs(h.normal.cast<double>().dot(n)) - 1.0) < 1e-6);
  }

  TEST_CASE("a planar sweep across the lattice cuts every x edge from node 3 to 4 exactly once") {
    const Lattice l = grid(10, 9, 8, Vec3d(-2, 5, 0.5), 0.5);
    for (double step : {20.0, 1.0, 0.3}) {
      CAPTURE(step);
      const auto poses = translated_blade(l, Vec3d(3.37, 4, 4), Vec3d(0, 0, 1), 7.0, Vec3d(0, 1, 0), 7.0, step);
      std::vector<EdgeHit> hits;
      for (size_t i = 0; i + 1 < poses.size(); ++i) sweep_edge_hits(l, poses[i], poses[i + 1], hits);
      std::map<uint32_t, float> cut;
      for (const EdgeHit& h : hits) {
        CHECK(h.edge % 3 == 0);
        cut[h.edge] = h.t;
      }
      CHECK(cut.size() == size_t(l.ny + 1) * size_t(l.nz + 1));
      for (int32_t k = 0; k <= l.nz; ++k) {
        for (int32_t j = 0; j <= l.ny; ++j) {
          auto it = cut.find(Lattice::edge(l.node(3, j, k), 0));
          REQUIRE(it != cut.end());
          CHECK(std::abs(it->second - 0.37) < 1.0 / F);
        }
      }
      CHECK(components(l, keys(cut)).count == 2);
    }
  }

  TEST_CASE("a plane through lattice nodes cuts every crossing line once and splits the lattice in two") {
    const Lattice l = grid(9, 8, 6);
    struct Plane {
      int64_t g[4];
      Vec3d p, u, w;
    };
    const Plane planes[] = {
        {{1, 0, 0, 3}, Vec3d(3, 0, 0), Vec3d(0, 0, 1), Vec3d(0, 1, 0)},      // x = 3
        {{1, 1, 0, 5}, Vec3d(5, 0, 0), Vec3d(0, 0, 1), Vec3d(1, -1, 0)},     // x + y = 5
        {{1, -1, 0, 1}, Vec3d(1, 0, 0), Vec3d(0, 0, 1), Vec3d(1, 1, 0)},     // x - y = 1
        {{0, 1, 1, 4}, Vec3d(0, 4, 0), Vec3d(1, 0, 0), Vec3d(0, 1, -1)},     // y + z = 4 (n_x = 0)
        {{0, 1, -1, 1}, Vec3d(0, 1, 0), Vec3d(1, 0, 0), Vec3d(0, 1, 1)},     // y - z = 1 (n_x = 0, n_y n_z < 0)
        {{0, 0, -1, -2}, Vec3d(0, 0, 2), Vec3d(1, 0, 0), Vec3d(0, 1, 0)},    // z = 2 (only n_z)
        {{1, 2, -1, 3}, Vec3d(3, 0, 0), Vec3d(1, 0, 1), Vec3d(0, 1, 2)},     // x + 2y - z = 3
        {{-2, 1, 3, 4}, Vec3d(0, 1, 1), Vec3d(1, 2, 0), Vec3d(3, 0, 2)},     // -2x + y + 3z = 4
    };
    for (const Plane& p : planes) {
      for (double step : {0.5, 1.75, 16.0}) {
        CAPTURE(p.g[0]);
        CAPTURE(p.g[1]);
        CAPTURE(p.g[2]);
        CAPTURE(p.g[3]);
        CAPTURE(step);
        check_plane_partition(l, p.g, p.p, p.u, p.w, step);
      }
    }
  }

  TEST_CASE("a sweep lying in the lattice plane z = 2 cuts only z edges, consistently") {
    const Lattice l = grid(10, 9, 6);
    // Full sweep of the plane: blade along y, moved along x within z = 2.
    {
      const auto poses = translated_blade(l, Vec3d(5, 4.5, 2), Vec3d(0, 1, 0), 8.0, Vec3d(1, 0, 0), 8.0, 0.75);
      const auto cut = sweep_path(l, poses);
      CHECK(cut.size() == size_t(l.nx + 1) * size_t(l.ny + 1));
      for (const auto& [e, t] : cut) {
        CHECK(e % 3 == 2);
        int32_t c[3];
        l.node_coords(e / 3, c);
        CHECK(c[2] == 1);  // the on-plane node joins the nodes above: edge (1, 2) at t = 1
        CHECK(t == 1.0f);
      }
      const Components comp = components(l, keys(cut));
      CHECK(comp.count == 2);
      CHECK(comp.label[l.node(0, 0, 1)] != comp.label[l.node(0, 0, 2)]);
      CHECK(comp.label[l.node(0, 0, 2)] == comp.label[l.node(10, 9, 6)]);
    }
    // Partial sweep, blade turning within the plane: z edges under the swept region only (boundary
    // lines included), never an x or y edge.
    {
      std::vector<BladePose> poses;
      for (int s = 0; s <= 8; ++s) {
        const double ang = 0.1 * s;
        const Vec3d c(2 + 0.5 * s, 3, 2);
        const Vec3d d(std::sin(ang), std::cos(ang), 0);
        poses.push_back(BladePose{c - 1.5 * d, c + 1.5 * d});
      }
      const auto cut = sweep_path(l, poses);
      CHECK(cut.size() > 10);
      for (const auto& [e, t] : cut) {
        CHECK(e % 3 == 2);
        int32_t c[3];
        l.node_coords(e / 3, c);
        CHECK(c[2] == 1);
      }
    }
    // Exactly the lines under an axis-aligned rectangle [2, 6] x [1, 5], borders included.
    {
      const auto cut = sweep_path(l, {BladePose{Vec3d(2, 1, 2), Vec3d(2, 5, 2)}, BladePose{Vec3d(6, 1, 2), Vec3d(6, 5, 2)}});
      std::set<uint32_t> want;
      for (int32_t j = 1; j <= 5; ++j) {
        for (int32_t i = 2; i <= 6; ++i) want.insert(Lattice::edge(l.node(i, j, 1), 2));
      }
      CHECK(keys(cut) == want);
    }
  }

  TEST_CASE("splitting a planar sweep into steps changes nothing (no hole along shared blade poses)") {
    // Dyadic coordinates: the snapped sheet is exactly the same plane piece either way.
    const Lattice l = grid(12, 11, 10);
    const Vec3d c(6.125, 5.5, 5.0), d = Vec3d(0.5, 0.25, 0.75), w = Vec3d(0.25, -0.5, 0.375);
    const auto one = sweep_path(l, translated_blade(l, c, d, 24.0, w, 32.0, 64.0));
    for (double step : {0.5, 0.125 * 3, 2.0, 8.0}) {
      CAPTURE(step);
      const auto many = sweep_path(l, translated_blade(l, c, d, 24.0, w, 32.0, step));
      CHECK(keys(many) == keys(one));
      for (const auto& [e, t] : one) {
        auto it = many.find(e);
        if (it != many.end()) CHECK(std::abs(it->second - t) < 1e-6);
      }
    }
    CHECK(components(l, keys(one)).count == 2);
  }

  TEST_CASE("an oblique blade swept in many steps separates the lattice into exactly two parts") {
    const Lattice l = grid(20, 18, 16, Vec3d(-3.1, 0.7, 12.9), 0.37);
    const Vec3d centre(10.3, 9.1, 7.7);
    const Vec3d d = Vec3d(0.31, 0.9, -0.27).normalized();
    const Vec3d w0 = Vec3d(0.8, -0.1, 0.55);
    const Vec3d w = (w0 - w0.dot(d) * d).normalized();  // move perpendicular to the blade
    const Vec3d n = d.cross(w);
    for (double step : {0.3, 20.0}) {
      CAPTURE(step);
      const auto cut = sweep_path(l, translated_blade(l, centre, d, 45.0, w, 40.0, step));
      const Components comp = components(l, keys(cut));
      CHECK(comp.count == 2);
      // A plane crosses a lattice line at most once.
      for (const auto& [line, count] : cuts_per_line(l, keys(cut))) CHECK(count == 1);
      // Nodes clearly off the sheet are in the component of their side.
      std::map<uint32_t, int> side_of_label;
      bool consistent = true;
      for (int32_t k = 0; k <= l.nz; ++k) {
        for (int32_t j = 0; j <= l.ny; ++j) {
          for (int32_t i = 0; i <= l.nx; ++i) {
            const double f = n.dot(Vec3d(i, j, k) - centre);
            if (std::abs(f) < 1e-3) continue;
            const int s = f > 0 ? 1 : -1;
            auto [it, fresh] = side_of_label.emplace(comp.label[l.node(i, j, k)], s);
            if (!fresh && it->second != s) consistent = false;
          }
        }
      }
      CHECK(consistent);
      CHECK(side_of_label.size() == 2);
    }
    // A turning blade sweeps a twisted (non-planar) sheet: quads fold along their diagonals and
    // consecutive quads meet at an angle; still no hole and no isolated node.
    for (double step : {0.3, 20.0}) {
      CAPTURE(step);
      std::vector<BladePose> poses;
      for (double s = -40.0;; s += step) {
        s = std::min(s, 40.0);
        const double ang = 0.6 * s / 40.0;  // about 70 degrees in all
        const Vec3d dir = std::cos(ang) * d + std::sin(ang) * n;
        const Vec3d c = centre + s * w;
        poses.push_back(BladePose{at(l, c - 45.0 * dir), at(l, c + 45.0 * dir)});
        if (s >= 40.0) break;
      }
      const auto cut = sweep_path(l, poses);
      const Components comp = components(l, keys(cut));
      CHECK(comp.count == 2);
      std::map<uint32_t, int> sizes;
      for (uint32_t label : comp.label) ++sizes[label];
      for (const auto& [label, size] : sizes) CHECK(size > 500);
    }
  }

  TEST_CASE("no area, no cut: zero-length blade, blade at rest, blade sliding along itself") {
    const Lattice l = grid(8, 8, 8);
    std::vector<EdgeHit> hits;
    const Vec3d p(3, 3, 3), q(4.5, 3, 3);
    sweep_edge_hits(l, BladePose{p, p}, BladePose{q, q}, hits);                        // zero length
    sweep_edge_hits(l, BladePose{p, q}, BladePose{p, q}, hits);                        // at rest
    sweep_edge_hits(l, BladePose{p, q}, BladePose{p + Vec3d(2, 0, 0), q + Vec3d(2, 0, 0)}, hits);  // along x
    // Along a diagonal through lattice nodes (exactly collinear after snapping).
    const Vec3d a(1, 1, 1), b(3, 3, 3), dd(0.25, 0.25, 0.25);
    sweep_edge_hits(l, BladePose{a, b}, BladePose{a + dd, b + dd}, hits);
    sweep_edge_hits(l, BladePose{a, b}, BladePose{a - 8.0 * dd, b + 8.0 * dd}, hits);  // stretching
    triangle_edge_hits(l, a, b, 2.0 * b - a, hits);                                   // collinear triangle
    CHECK(hits.empty());
  }

  TEST_CASE("far, huge and non-finite blades: no crash, no overflow, sane hits") {
    const Lattice l = grid(8, 7, 6, Vec3d(-1, -1, -1), 0.5);
    std::vector<EdgeHit> hits;
    SweepStats stats;
    // Far outside: nothing; a sheet parallel to the lattice covering its whole projection costs
    // one scanline per row and tests no line.
    sweep_edge_hits(l, BladePose{Vec3d(1e6, -1e6, -1e6), Vec3d(1e6, -1e6, 1e6)},
                    BladePose{Vec3d(1e6, 1e6, -1e6), Vec3d(1e6, 1e6, 1e6)}, hits, &stats);
    // An inclined far triangle in the plane x + y/2 + z/3 = 1e5 whose projection along every axis
    // covers the whole lattice: one row per scanline, still no line tested.
    const uint64_t rows_before = stats.rows_scanned;
    triangle_edge_hits(l, Vec3d(1.2e5, -2e4, -3e4), Vec3d(-2e4, 2.6e5, -3e4), Vec3d(-2e4, -2e4, 3.9e5), hits, &stats);
    // Rows run along the shorter of the two projected axes: min(ny, nz) + min(nz, nx) + min(nx, ny) + 3.
    CHECK(stats.rows_scanned - rows_before == uint64_t(6 + 6 + 7 + 3));
    sweep_edge_hits(l, BladePose{Vec3d(-50, 0, 0), Vec3d(-50, 1, 0)}, BladePose{Vec3d(-40, 0, 0), Vec3d(-40, 1, 1)}, hits);
    CHECK(hits.empty());
    CHECK(stats.lines_tested == 0);
    CHECK(stats.rows_scanned > 0);
    CHECK(stats.rows_scanned <= 6 * uint64_t(l.nx + l.ny + l.nz + 3));

    // A huge axis-aligned sheet through the lattice: clamping keeps it the plane z = 3.5 voxels.
    const double z = -1 + 0.5 * 3.5;
    sweep_edge_hits(l, BladePose{Vec3d(-1e9, -1e9, z), Vec3d(1e9, -1e9, z)},
                    BladePose{Vec3d(-1e9, 1e9, z), Vec3d(1e9, 1e9, z)}, hits);
    std::map<uint32_t, float> cut;
    for (const EdgeHit& h : hits) cut[h.edge] = h.t;
    CHECK(cut.size() == size_t(l.nx + 1) * size_t(l.ny + 1));
    for (int32_t j = 0; j <= l.ny; ++j) {
      for (int32_t i = 0; i <= l.nx; ++i) {
        auto it = cut.find(Lattice::edge(l.node(i, j, 3), 2));
        REQUIRE(it != cut.end());
        CHECK(it->second == 0.5f);
      }
    }

    // Random huge, infinite and NaN coordinates: every hit is a valid edge with t in [0, 1].
    hits.clear();
    std::mt19937_64 rng(77);
    const double specials[] = {1e9, -1e9, 1e300, -1e300, std::numeric_limits<double>::infinity(),
                               -std::numeric_limits<double>::infinity(), std::numeric_limits<double>::quiet_NaN(),
                               0.0, 2.0, 1.5e7, -8.4e6};
    auto coord = [&]() {
      const uint64_t r = rng();
      return (r % 3 == 0) ? specials[(r >> 8) % 11] : double(int64_t((r >> 8) % 4000) - 2000) * 1e-2;
    };
    for (int trial = 0; trial < 3000; ++trial) {
      Vec3d p[3];
      for (auto& x : p) x = Vec3d(coord(), coord(), coord());
      triangle_edge_hits(l, p[0], p[1], p[2], hits);
    }
    CHECK(hits.size() > 0);
    const uint64_t edges = 3 * l.node_count();
    for (const EdgeHit& h : hits) {
      CHECK(h.edge < edges);
      CHECK(h.t >= 0.0f);
      CHECK(h.t <= 1.0f);
      CHECK(std::isfinite(h.normal.norm()));
    }
  }

  TEST_CASE("a long thin diagonal triangle costs O(hits + rows), not its bounding box") {
    const Lattice l = grid(64, 64, 64);
    int64_t v[3][3] = {{0, 0, 0}, {60 * F, 60 * F, 60 * F}, {F * 4 / 10, -F * 3 / 10, F / 5}};
    SweepStats stats;
    const auto got = triangle_map(l, scene(l, v[0]), scene(l, v[1]), scene(l, v[2]), &stats);
    const auto ref = reference_hits(l, v);
    CHECK(got.size() == ref.size());
    const uint64_t hits = got.size();
    const uint64_t bbox_lines = 3 * 61 * 61;
    MESSAGE("hits " << hits << ", rows " << stats.rows_scanned << ", lines " << stats.lines_tested << ", bbox lines "
                    << bbox_lines);
    CHECK(hits > 60);
    CHECK(stats.lines_tested <= hits + 3);  // only lines ending exactly on a lattice end node are extra
    CHECK(stats.rows_scanned <= 3 * 62);
    CHECK(stats.rows_scanned + stats.lines_tested < bbox_lines / 20);

    // The same as a blade sweep: a 0.5-voxel blade moved 60 voxels along the diagonal.
    SweepStats sweep_stats;
    std::vector<EdgeHit> sweep_hits;
    sweep_edge_hits(l, BladePose{Vec3d(1, 1, 1), Vec3d(1.3, 0.8, 1.3)},
                    BladePose{Vec3d(61, 61, 61), Vec3d(61.3, 60.8, 61.3)}, sweep_hits, &sweep_stats);
    CHECK(sweep_hits.size() > 60);
    CHECK(sweep_stats.lines_tested <= sweep_hits.size() + 6);
    CHECK(sweep_stats.rows_scanned <= 6 * 62);
  }

  TEST_CASE("a sliver along a lattice axis scans one row per crossed line, not one per voxel") {
    const Lattice l = grid(64, 64, 64);
    for (int axis = 0; axis < 3; ++axis) {
      CAPTURE(axis);
      // Blade along `axis` through the whole lattice, moved 0.25 voxel across x = 10 (or y = 10).
      const int move = axis == 0 ? 1 : 0, other = 3 - axis - move;
      Vec3d a0 = Vec3d::Constant(5.3), b0 = a0, a1, b1;
      a0[axis] = -1.0;
      b0[axis] = 65.0;
      a0[move] = b0[move] = 9.9;
      a1 = a0;
      b1 = b0;
      a1[move] = b1[move] = 10.15;
      SweepStats stats;
      const auto cut = sweep_path(l, {BladePose{a0, b0}, BladePose{a1, b1}}, &stats);
      CHECK(cut.size() == 65);
      for (const auto& [e, t] : cut) {
        CHECK(int(e % 3) == other);
        CHECK(std::abs(t - 0.3f) < 1e-4f);
      }
      CHECK(stats.rows_scanned <= 4);
      CHECK(stats.lines_tested <= 2 * 65);
    }
  }

  TEST_CASE("snapping: coordinates closer than 2^-17 voxel to a lattice plane are on it") {
    const Lattice l = grid(6, 6, 6);
    std::vector<EdgeHit> hits;
    for (double x : {3 + 1e-7, 3 - 1e-7, 3 - 7e-6}) {  // all snap to exactly 3 (nearest, 2^-17 = 7.6e-6)
      sweep_edge_hits(l, BladePose{Vec3d(x, -1, -1), Vec3d(x, -1, 8)}, BladePose{Vec3d(x, 8, -1), Vec3d(x, 8, 8)}, hits);
    }
    std::set<uint32_t> got;
    for (const EdgeHit& h : hits) {
      CHECK(h.t == 1.0f);
      got.insert(h.edge);
    }
    std::set<uint32_t> want;
    for (int32_t k = 0; k <= 6; ++k) {
      for (int32_t j = 0; j <= 6; ++j) want.insert(Lattice::edge(l.node(2, j, k), 0));
    }
    CHECK(got == want);
  }
}
