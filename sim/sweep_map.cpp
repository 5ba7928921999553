// The blade's sweep mapped to rest space (sim/world_to_rest.h): the sweep between two steps sampled,
// carried with the material, mapped through the deformed pieces and merged into rest-space quads.
#include "sim/world_to_rest.h"
#include "sim/world_to_rest_internal.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace dvx {

using namespace world_to_rest_internal;

// ---- The blade's sweep ---------------------------------------------------------------------

void reset_sweep(SweepMapper& mapper) {
  mapper.carried.clear();
  mapper.carried_piece.clear();
  mapper.carried_outside.clear();
  mapper.carried_near.clear();
  mapper.ended.clear();
  mapper.ended_begin.clear();
}

namespace {

constexpr uint32_t kMaxSweepPoints = 1u << 21;  // a sweep sampled finer than this is sampled coarser

bool near_point(const Vec3d& a, const Vec3d& b, double tolerance) { return (a - b).squaredNorm() <= tolerance * tolerance; }

// Distance of p from the segment a-b.
double segment_distance(const Vec3d& p, const Vec3d& a, const Vec3d& b) {
  const Vec3d d = b - a;
  const double len2 = d.squaredNorm();
  const double t = len2 > 0.0 ? std::clamp((p - a).dot(d) / len2, 0.0, 1.0) : 0.0;
  return (p - (a + t * d)).norm();
}

// Where the blade's previous samples are now: carried with the material, or where they were.
void sweep_start(const VoxelModel& model, const PbdModel& pbd, const PbdData& data, const BladePose& from, uint32_t nu,
                 SweepMapper& m) {
  m.from_world.resize(nu + 1);
  for (uint32_t i = 0; i <= nu; ++i) {
    const double t = double(i) / nu;
    m.from_world[i] = from.a + t * (from.b - from.a);
    if (m.carried.size() != nu + 1 || !m.carried[i].allFinite()) continue;
    // The piece that held it, while it is live and still spans that rest point; else the material there.
    uint32_t piece = m.carried_piece[i];
    Vec3d u = Vec3d::Constant(-1.0);
    bool live = false;
    if (piece < pbd.pieces.size() && pbd.pieces[piece].sim_voxel != kDeadIndex) {
      u = (m.carried[i] - piece_rest_origin(pbd, piece)) / pbd.sim_size;
      live = true;
    }
    // A sample outside every piece was carried with a neighbour's piece, its map extrapolated: it
    // moves with that piece while the piece lives (so the strip's end in the air follows the tissue
    // as its samples in material do, and the sweep's first row maps back to where the last ended).
    const bool extrapolated = live && m.carried_outside[i];
    if (!extrapolated && !(u.minCoeff() >= -1e-6 && u.maxCoeff() <= 1.0 + 1e-6)) {
      piece = piece_at_rest(model, pbd, m.carried[i]);
      if (piece == kDeadIndex) continue;
      u = (m.carried[i] - piece_rest_origin(pbd, piece)) / pbd.sim_size;
    }
    Vec3d corners[8];
    piece_corners(pbd, data, piece, corners);
    m.from_world[i] = trilinear(corners, u);
  }
}

// The rest point the last step's quads through `piece` ended on at blade sample i (false: none).
bool ended_through(const SweepMapper& m, uint32_t i, uint32_t piece, Vec3d& rest) {
  for (uint32_t x = m.ended_begin[i]; x < m.ended_begin[i + 1]; ++x) {
    if (m.ended[x].piece != piece) continue;
    rest = m.ended[x].rest;
    return true;
  }
  return false;
}

// The rest image through `piece` of grid point k: its hit when it has one, else Newton from `start`.
bool rest_through(const PbdModel& pbd, SweepMapper& m, uint32_t k, uint32_t piece, const Vec3d& start, Vec3d& rest) {
  for (uint32_t h = m.hit_begin[k]; h < m.hit_begin[k + 1]; ++h) {
    if (m.hits[h].piece != piece) continue;
    rest = m.hits[h].rest;
    return true;
  }
  Vec3d u;
  if (!piece_local(pbd, m.grid, piece, m.points[k], start, u)) return false;
  rest = m.grid.piece_origin[piece] + pbd.sim_size * u;
  return true;
}

// How much farther from segment a-c than from segment a-b any point can be, when |c - a| >= |b - a|:
// the nearest point a + t (b - a) of a-b has a + t |b - a| u' on a-c (u' the unit direction of c - a),
// |b - a| |u - u'| away. Infinite when c is nearer to a than b (no bound needed then: strips grow).
double extension_shift(const Vec3d& a, const Vec3d& b, const Vec3d& c) {
  const double lb = (b - a).norm(), lc = (c - a).norm();
  if (!(lc >= lb)) return std::numeric_limits<double>::infinity();
  if (lb == 0.0) return 0.0;
  return lb * ((b - a) / lb - (c - a) / lc).norm();
}

// Appends a cell's quad, merged into a quad of the previous cell of its row (quads[prev_first,
// prev_last) of m.cell_quads) that it continues: the same blade motion edge (joined within 1e-6 h)
// and the merged quad's blade edges still straight (every junction within 0.02 h). Cells through
// several pieces (a piece boundary along the sweep) continue their own strips, each piece's.
// Returns the quad it went to. The junctions are measured again only when the bound of their
// distances (m.joint_bound, grown by each extension's extension_shift) does not show them within
// 0.02 h by a wide margin: a straight strip costs one test per cell, not one per junction, and the
// decisions are those of measuring every junction.
uint32_t emit_quad(const RestQuad& q, double h, SweepMapper& m, size_t prev_first, size_t prev_last) {
  const double join = 1e-6 * h, straight = 0.02 * h, sure = straight * (1.0 - 1e-6);
  for (size_t c = prev_first; c < prev_last; ++c) {
    const uint32_t o = m.cell_quads[c];
    RestQuad& last = m.quads[o];
    if (!near_point(last.from.b, q.from.a, join) || !near_point(last.to.b, q.to.a, join)) continue;
    // Every junction of the strip must stay on the merged strip's edges.
    const double from_new = segment_distance(q.from.a, last.from.a, q.from.b);
    const double to_new = segment_distance(q.to.a, last.to.a, q.to.b);
    bool ok = from_new <= straight && to_new <= straight;
    if (!ok) continue;
    double from_bound = m.joint_bound[2 * o] + extension_shift(last.from.a, last.from.b, q.from.b);
    double to_bound = m.joint_bound[2 * o + 1] + extension_shift(last.to.a, last.to.b, q.to.b);
    if (!(from_bound <= sure && to_bound <= sure)) {
      from_bound = to_bound = 0.0;
      for (uint32_t x = m.joint_head[o]; x != kDeadIndex && ok; x = m.joints[x].next) {
        const double df = segment_distance(m.joints[x].a, last.from.a, q.from.b);
        const double dt = df <= straight ? segment_distance(m.joints[x].b, last.to.a, q.to.b) : 0.0;
        ok = df <= straight && dt <= straight;
        from_bound = std::max(from_bound, df);
        to_bound = std::max(to_bound, dt);
      }
    }
    if (!ok) continue;
    m.joints.push_back({q.from.a, q.to.a, m.joint_head[o]});
    m.joint_head[o] = uint32_t(m.joints.size() - 1);
    m.joint_bound[2 * o] = std::max(from_bound, from_new) * (1.0 + 1e-12);
    m.joint_bound[2 * o + 1] = std::max(to_bound, to_new) * (1.0 + 1e-12);
    last.from.b = q.from.b;
    last.to.b = q.to.b;
    return o;
  }
  m.quads.push_back(q);
  m.joint_head.push_back(kDeadIndex);
  m.joint_bound.resize(2 * m.quads.size(), 0.0);
  return uint32_t(m.quads.size() - 1);
}

// Merges the quads of the row that begins at quads[row_first] into the quads of the row before it
// (m.open) that they continue: the same blade segment (joined within 1e-6 h), and the merged quad
// still flat and straight (every rung, the inner row edges, within 0.02 h of its sides; its corners
// within 0.02 h of one plane), so the two triangles cut_divide sweeps cover the rows' quads. A
// rigidly moved or gently bent piece then gives one quad per strip of the sweep, not one per row: the
// divide and the front run once per quad.
void merge_rows(SweepMapper& m, size_t row_first, double h) {
  const double join = 1e-6 * h, straight = 0.02 * h;
  m.next_open.clear();
  m.merged_away.resize(m.quads.size(), 0);
  m.joint_head.resize(m.quads.size(), kDeadIndex);
  for (size_t x = row_first; x < m.quads.size(); ++x) {
    const RestQuad& q = m.quads[x];
    uint32_t into = kDeadIndex;
    for (uint32_t& o : m.open) {
      if (o == kDeadIndex) continue;
      const RestQuad& p = m.quads[o];
      if (!near_point(p.to.a, q.from.a, join) || !near_point(p.to.b, q.from.b, join)) continue;
      const Vec3d& a0 = p.from.a;
      const Vec3d& b0 = p.from.b;
      bool ok = segment_distance(q.from.a, a0, q.to.a) <= straight && segment_distance(q.from.b, b0, q.to.b) <= straight;
      for (size_t r = 0; r < m.rungs.size() && ok; ++r) {
        if (m.rungs[r].quad != o) continue;
        ok = segment_distance(m.rungs[r].a, a0, q.to.a) <= straight && segment_distance(m.rungs[r].b, b0, q.to.b) <= straight;
      }
      if (ok) {
        const Vec3d n = (b0 - a0).cross(q.to.b - a0);
        const double len = n.norm();
        ok = len > 0.0 && std::abs(n.dot(q.to.a - a0)) <= straight * len;
      }
      if (!ok) continue;
      into = o;
      o = kDeadIndex;  // continued once
      break;
    }
    if (into == kDeadIndex) {
      m.next_open.push_back(uint32_t(x));
      continue;
    }
    m.rungs.push_back({into, q.from.a, q.from.b});
    m.quads[into].to = q.to;
    m.merged_away[x] = 1;
    m.next_open.push_back(into);
  }
  m.open.swap(m.next_open);
}

// The sweep's sampling: nu + 1 samples along the blade, nv + 1 along its motion (fine-voxel spacing);
// `motion` the farthest a sample moves.
struct SweepSize {
  uint32_t nu = 0, nv = 0;
  double motion = 0.0;
  uint32_t row() const { return nu + 1; }
};

// The samples of the sweep from `from` to `to` (the first row where the last step's samples are now)
// and the rest images of each through the pieces near the sweep. False when the poses are not finite.
bool sample_sweep(const VoxelModel& model, const PbdModel& pbd, const PbdData& data, const BladePose& from,
                  const BladePose& to, SweepMapper& m, SweepSize& z, uint32_t& tests) {
  const double h = pbd.fine_size;
  const double length = std::max((from.b - from.a).norm(), (to.b - to.a).norm());
  if (!std::isfinite(length)) return false;
  z.nu = uint32_t(std::clamp(std::ceil(length / h), 1.0, double(kMaxSweepPoints / 2)));
  const uint32_t nu = z.nu;
  sweep_start(model, pbd, data, from, nu, m);
  m.to_world.resize(nu + 1);
  z.motion = 0.0;
  for (uint32_t i = 0; i <= nu; ++i) {
    m.to_world[i] = to.a + (double(i) / nu) * (to.b - to.a);
    z.motion = std::max(z.motion, (m.to_world[i] - m.from_world[i]).norm());
  }
  if (!std::isfinite(z.motion)) return false;
  z.nv = uint32_t(std::clamp(std::ceil(z.motion / h), 1.0, std::max(1.0, double(kMaxSweepPoints / (nu + 1)) - 1.0)));
  // The pieces near the sweep, then the rest images of every sample.
  Aabb region;
  for (uint32_t i = 0; i <= nu; ++i) {
    region.grow(m.from_world[i]);
    region.grow(m.to_world[i]);
  }
  region.min.array() -= h;
  region.max.array() += h;
  build_piece_grid(pbd, data, region, pbd.sim_size, 1e-3 * h, m.grid);
  const uint32_t row = z.row(), count = row * (z.nv + 1);
  m.points.resize(count);
  m.hit_begin.resize(size_t(count) + 1);
  m.hits.clear();
  for (uint32_t j = 0; j <= z.nv; ++j) {
    const double t = double(j) / z.nv;
    for (uint32_t i = 0; i <= nu; ++i) {
      const uint32_t k = j * row + i;
      m.points[k] = m.from_world[i] + t * (m.to_world[i] - m.from_world[i]);
      m.hit_begin[k] = uint32_t(m.hits.size());
      // Newton starts from the previous sample along the blade, else the one of the previous row.
      const uint32_t near = i > 0 ? k - 1 : j > 0 ? k - row : k;
      world_to_rest(model, pbd, m.grid, m.points[k], m.hits, &tests, m.hit_begin[near], near == k ? m.hit_begin[k] : m.hit_begin[near + 1]);
    }
  }
  m.hit_begin[count] = uint32_t(m.hits.size());
  return true;
}

// Cell (i, j) of the sweep: one rest quad per piece holding one of its corners (a neighbour piece
// mapping the cell the same way adds none). The first row starts where the last step's quads
// through each piece ended (`carry`); the last row records where they end.
void cell_quads(const PbdModel& pbd, SweepMapper& m, const SweepSize& z, uint32_t i, uint32_t j, bool carry,
                size_t& prev_first, size_t& prev_last) {
  const double h = pbd.fine_size;
  const uint32_t row = z.row();
  const uint32_t k[4] = {j * row + i, j * row + i + 1, (j + 1) * row + i, (j + 1) * row + i + 1};
  // Distinct pieces of the corners' hits, ascending.
  uint32_t pieces[32];
  Vec3d starts[32];
  int piece_count = 0;
  for (uint32_t corner : k) {
    for (uint32_t x = m.hit_begin[corner]; x < m.hit_begin[corner + 1] && piece_count < 32; ++x) {
      const uint32_t p = m.hits[x].piece;
      if (std::find(pieces, pieces + piece_count, p) != pieces + piece_count) continue;
      starts[piece_count] = (m.hits[x].rest - m.grid.piece_origin[p]) / pbd.sim_size;
      pieces[piece_count++] = p;
    }
  }
  for (int a = 1; a < piece_count; ++a) {  // insertion sort (tiny)
    for (int b = a; b > 0 && pieces[b - 1] > pieces[b]; --b) {
      std::swap(pieces[b - 1], pieces[b]);
      std::swap(starts[b - 1], starts[b]);
    }
  }
  const size_t cell_first = m.cell_quads.size();
  Vec3d own[32][4];  // this cell's quads before merging (corners r[]; left uninitialised)
  int own_count = 0;
  for (int p = 0; p < piece_count; ++p) {
    Vec3d r[4];
    bool ok = true;
    for (int c = 0; c < 4 && ok; ++c) {
      // The first row starts where the last step's quads through this piece ended.
      if (c < 2 && j == 0 && carry && ended_through(m, i + uint32_t(c), pieces[p], r[c])) continue;
      ok = rest_through(pbd, m, k[c], pieces[p], starts[p], r[c]);
    }
    if (!ok) continue;
    if (j + 1 == z.nv) {
      m.ending.push_back({pieces[p], r[2]});
      m.ending_sample.push_back(i);
      m.ending.push_back({pieces[p], r[3]});
      m.ending_sample.push_back(i + 1);
    }
    const RestQuad q{{r[0], r[1]}, {r[2], r[3]}};
    // A neighbour piece sharing the cell's corners maps it the same way: cut it once.
    bool same = false;
    for (int x = 0; x < own_count && !same; ++x) {
      const Vec3d* o = own[x];
      same = near_point(o[3], r[3], 1e-3 * h) && near_point(o[2], r[2], 1e-3 * h) &&
             near_point(o[1], r[1], 1e-3 * h) && near_point(o[0], r[0], 1e-3 * h);
    }
    if (same) continue;
    std::copy(r, r + 4, own[own_count++]);
    m.cell_quads.push_back(emit_quad(q, h, m, prev_first, prev_last));
  }
  prev_first = cell_first;
  prev_last = m.cell_quads.size();
}

// Where this step's quads ended, per sample (a counting sort; lookups take the first entry of a
// (sample, piece)).
void record_ends(SweepMapper& m, uint32_t nu) {
  m.ended_begin.assign(size_t(nu) + 2, 0);
  for (uint32_t x : m.ending_sample) ++m.ended_begin[x + 1];
  for (uint32_t i = 0; i <= nu; ++i) m.ended_begin[i + 1] += m.ended_begin[i];
  m.ended.resize(m.ending.size());
  m.ended_fill.assign(m.ended_begin.begin(), m.ended_begin.end() - 1);
  for (size_t x = 0; x < m.ending.size(); ++x) m.ended[m.ended_fill[m.ending_sample[x]]++] = m.ending[x];
}

// The samples of `to` that are in material, carried to the next step. In a slit or a gap (inside a
// piece's hexahedron, outside its material) a sample is carried with that piece: the material
// closing in on it is then cut by the relative motion. The samples in no piece are carried through
// the piece of the nearest sample along the blade that has one (its map extrapolated, as the cells'
// quads map them), so they move with the tissue too.
void carry_samples(const PbdModel& pbd, SweepMapper& m, const SweepSize& z) {
  const uint32_t nu = z.nu, nv = z.nv, row = z.row();
  m.carried.assign(nu + 1, Vec3d::Constant(std::numeric_limits<double>::quiet_NaN()));
  m.carried_piece.assign(nu + 1, kDeadIndex);
  m.carried_outside.assign(nu + 1, 0);
  m.carried_near.assign(nu + 1, kDeadIndex);
  for (uint32_t i = 0; i <= nu; ++i) {
    const uint32_t k = nv * row + i;
    if (m.hit_begin[k] < m.hit_begin[k + 1]) {
      m.carried[i] = m.hits[m.hit_begin[k]].rest;
      m.carried_piece[i] = m.hits[m.hit_begin[k]].piece;
      continue;
    }
    query_piece_grid(m.grid, m.points[k], [&](uint32_t slot) {
      Vec3d u;
      if (m.carried_piece[i] != kDeadIndex || !in_piece_bounds(m.grid, slot, m.points[k], 1e-5 * pbd.sim_size) ||
          !piece_local(pbd, m.grid, slot, m.points[k], Vec3d::Constant(0.5), u)) {
        return;
      }
      if (u.minCoeff() < 0.0 || u.maxCoeff() > 1.0) return;
      m.carried[i] = m.grid.piece_origin[slot] + pbd.sim_size * u;
      m.carried_piece[i] = slot;
    });
  }
  for (int pass = 0; pass < 2; ++pass) {
    uint32_t near = kDeadIndex;
    for (uint32_t x = 0; x <= nu; ++x) {
      const uint32_t i = pass == 0 ? x : nu - x;
      if (m.carried_piece[i] != kDeadIndex && !m.carried_outside[i]) {
        near = i;
        continue;
      }
      if (near == kDeadIndex) continue;
      const uint32_t slot = m.carried_piece[near];
      const uint32_t distance = near > i ? near - i : i - near;
      // The nearer neighbour wins (the first pass, from below, holds the ties).
      if (m.carried_piece[i] != kDeadIndex) {
        const uint32_t before = m.carried_near[i] > i ? m.carried_near[i] - i : i - m.carried_near[i];
        if (before <= distance) continue;
      }
      const uint32_t k = nv * row + i;
      Vec3d u;
      if (m.grid.jinv_valid.size() <= slot ||
          !piece_local(pbd, m.grid, slot, m.points[k], (m.carried[near] - m.grid.piece_origin[slot]) / pbd.sim_size, u)) {
        continue;
      }
      m.carried[i] = m.grid.piece_origin[slot] + pbd.sim_size * u;
      m.carried_piece[i] = slot;
      m.carried_outside[i] = 1;
      m.carried_near[i] = near;
    }
  }
}

}  // namespace

void map_sweep(const VoxelModel& model, const PbdModel& pbd, const PbdData& data, const BladePose& from,
               const BladePose& to, SweepMapper& m, SweepMapStats* stats) {
  const double h = pbd.fine_size;
  m.quads.clear();
  SweepSize z;
  uint32_t tests = 0;
  if (!sample_sweep(model, pbd, data, from, to, m, z, tests)) return;

  // Cells: one rest quad per piece holding one of the cell's corners; rows merged as they come.
  const bool carry = m.ended_begin.size() == size_t(z.nu) + 2;
  m.ending.clear();
  m.ending_sample.clear();
  m.open.clear();
  m.rungs.clear();
  m.merged_away.clear();
  m.joint_head.clear();
  m.joint_bound.clear();
  if (z.motion > 1e-9 * h) {
    for (uint32_t j = 0; j < z.nv; ++j) {
      const size_t row_first = m.quads.size();
      m.cell_quads.clear();
      m.joints.clear();
      size_t prev_first = 0, prev_last = 0;
      for (uint32_t i = 0; i < z.nu; ++i) cell_quads(pbd, m, z, i, j, carry, prev_first, prev_last);
      merge_rows(m, row_first, h);
    }
    // The quads merged into an earlier row's are dropped (the others keep their order).
    m.merged_away.resize(m.quads.size(), 0);
    size_t kept = 0;
    for (size_t x = 0; x < m.quads.size(); ++x) {
      if (!m.merged_away[x]) m.quads[kept++] = m.quads[x];
    }
    m.quads.resize(kept);
  }
  // A step without motion cut nothing: the strip still ends where it ended.
  if (z.motion > 1e-9 * h || !carry) record_ends(m, z.nu);
  carry_samples(pbd, m, z);
  if (stats) {
    stats->samples += z.row() * (z.nv + 1);
    stats->piece_tests += tests;
    stats->hits += uint32_t(m.hits.size());
    stats->quads += uint32_t(m.quads.size());
  }
}

}  // namespace dvx
