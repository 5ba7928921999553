#include "sim/contact.h"

#include <algorithm>
#include <cmath>

namespace dvx {
namespace {

// x_k += (w_k / m_k) / W * delta for each particle of the contact: moves its relative point by delta.
void move_point(double* x, const double* inv_mass, const ContactPoint& c, double inv_w, const Vec3d& delta) {
  for (uint32_t k = 0; k < c.count; ++k) {
    const double s = c.weights[k] * inv_mass[c.particles[k]] * inv_w;
    if (s == 0.0) continue;
    double* p = x + 3 * size_t(c.particles[k]);
    p[0] += s * delta.x();
    p[1] += s * delta.y();
    p[2] += s * delta.z();
  }
}

}  // namespace

ContactPoint plane_contact(const ContactPlane& plane, const uint32_t particles[8], const double weights[8]) {
  ContactPoint c;
  std::copy(particles, particles + 8, c.particles);
  std::copy(weights, weights + 8, c.weights);
  c.count = 8;
  c.normal = plane.normal;
  c.target = plane.normal.dot(plane.point);
  c.static_friction = plane.static_friction;
  c.kinetic_friction = plane.kinetic_friction;
  return c;
}

void contacts_clear(ContactSet& set) {
  set.points.clear();
  set.group_begin.clear();
  set.batch_begin.clear();
  set.staged.clear();
  set.staged_key.clear();
}

void contacts_add(ContactSet& set, uint32_t batch, uint32_t group, const ContactPoint& point) {
  set.staged.push_back(point);
  set.staged_key.push_back((uint64_t(batch) << 32) | group);
}

void contacts_finish(ContactSet& set) {
  // Sort by (batch, group), stable: a group's points keep the order they were added in.
  const uint32_t n = uint32_t(set.staged.size());
  set.order.resize(n);
  for (uint32_t i = 0; i < n; ++i) set.order[i] = i;
  std::stable_sort(set.order.begin(), set.order.end(),
                   [&](uint32_t a, uint32_t b) { return set.staged_key[a] < set.staged_key[b]; });
  set.points.resize(n);
  set.group_begin.clear();
  set.batch_begin.assign(1, 0);
  for (uint32_t i = 0; i < n; ++i) {
    const uint64_t key = set.staged_key[set.order[i]];
    const bool new_group = i == 0 || key != set.staged_key[set.order[i - 1]];
    if (new_group) {
      // Close the batches before this one (empty batches have no groups).
      while (set.batch_begin.size() <= size_t(key >> 32)) set.batch_begin.push_back(uint32_t(set.group_begin.size()));
      set.group_begin.push_back(i);
    }
    set.points[i] = set.staged[set.order[i]];
  }
  set.group_begin.push_back(n);
  set.batch_begin.push_back(uint32_t(set.group_begin.size() - 1));
}

void contacts_begin_substep(ContactSet& set) {
  for (ContactPoint& c : set.points) {
    c.normal_total = 0.0;
    c.friction_total = Vec3d::Zero();
  }
}

void solve_contact_point(double* x, const double* previous, const double* inv_mass, ContactPoint& c) {
  // The relative point, its motion since the start of the substep, and its generalised inverse mass.
  Vec3d r = Vec3d::Zero(), moved = Vec3d::Zero();
  double w = 0.0, lever = 0.0;
  for (uint32_t k = 0; k < c.count; ++k) {
    const double a = c.weights[k];
    if (a == 0.0) continue;
    const size_t p = 3 * size_t(c.particles[k]);
    const Vec3d xp(x[p], x[p + 1], x[p + 2]);
    r += a * xp;
    moved += a * (xp - Vec3d(previous[p], previous[p + 1], previous[p + 2]));
    const double m = inv_mass[c.particles[k]];
    w += a * a * m;
    lever = std::max(lever, std::abs(a) * m);
  }
  if (!(w > 0.0)) return;
  // The lever cap (sim/contact.h, kMaxLever): W_eff = max(W, max_k |w_k| / m_k / kMaxLever). A
  // requested correction d then moves the point by gain d (gain = W / W_eff: 1 unless the point is
  // nearly anchored, when it barely moves); the totals count what the point actually moved.
  const bool capped = lever > kMaxLever * w;
  const double inv_w = capped ? kMaxLever / lever : 1.0 / w, gain = capped ? w * inv_w : 1.0;
  const Vec3d& n = c.normal;

  // Normal: C = n . r - target >= 0, rigid (alpha = 0): dlambda = -C / W moves r by -C n. The total
  // over the substep stays >= 0 (projected Gauss-Seidel with accumulated clamping): a point pushed out
  // too far by an earlier iteration is pulled back by up to what it was pushed, never further.
  const double request = std::max(c.target - n.dot(r), -c.normal_total / gain);
  if (request != 0.0) {
    move_point(x, inv_mass, c, inv_w, request * n);
    c.normal_total += gain * request;
    moved += (gain * request) * n;
  }
  if (c.normal_total <= 0.0) return;  // not touching in this substep: no friction

  // Friction: the total correction that would stop the tangential motion, clamped by Coulomb's cone.
  const Vec3d slide = moved - n.dot(moved) * n;
  Vec3d total = c.friction_total - slide;
  const double length = total.norm();
  if (length > c.static_friction * c.normal_total) {
    total *= length > 0.0 ? c.kinetic_friction * c.normal_total / length : 0.0;  // sliding
  }
  move_point(x, inv_mass, c, inv_w, total - c.friction_total);
  c.friction_total = capped ? c.friction_total + gain * (total - c.friction_total) : total;
}

void solve_contact_group(double* x, const double* previous, const double* inv_mass, ContactSet& set, uint32_t group) {
  for (uint32_t i = set.group_begin[group]; i < set.group_begin[group + 1]; ++i) {
    solve_contact_point(x, previous, inv_mass, set.points[i]);
  }
}

void project_particles_to_planes(double* x, const double* inv_mass, uint32_t begin, uint32_t end,
                                 const ContactPlane* planes, uint32_t plane_count, double depth) {
  for (uint32_t i = begin; i < end; ++i) {
    if (inv_mass[i] == 0.0) continue;
    double* p = x + 3 * size_t(i);
    for (uint32_t k = 0; k < plane_count; ++k) {
      const ContactPlane& plane = planes[k];
      const double d = plane_distance(plane, Vec3d(p[0], p[1], p[2])) + depth;
      if (d >= 0.0) continue;
      p[0] -= d * plane.normal.x();
      p[1] -= d * plane.normal.y();
      p[2] -= d * plane.normal.z();
    }
  }
}

// ---- Piece against piece ---------------------------------------------------------------------

namespace {

// Grid coordinate of x in cells of `size`, and a 32-bit hash of a cell (Teschner et al. 2003). Two
// cells may share a hash: queries then see extra candidates, which their distance tests reject.
int64_t cell_coord(double x, double size) {
  const double c = std::floor(x / size);
  return int64_t(std::max(-1e15, std::min(1e15, c)));
}
uint64_t cell_key(int64_t i, int64_t j, int64_t k) {
  const uint32_t h = uint32_t(uint64_t(i) * 73856093u) ^ uint32_t(uint64_t(j) * 19349663u) ^ uint32_t(uint64_t(k) * 83492791u);
  return uint64_t(h) << 32;
}

// Sorts (cell << 32 | item) keys and indexes them: cells (distinct, sorted), their item ranges, and
// an open-addressing table from a cell key to its index (a query looks up 27 cells: a table probe
// each, not a binary search).
void build_cells(PieceContactScratch& g) {
  std::sort(g.keys.begin(), g.keys.end());
  g.cells.clear();
  g.cell_begin.clear();
  g.cell_items.resize(g.keys.size());
  for (size_t i = 0; i < g.keys.size(); ++i) {
    const uint64_t cell = g.keys[i] >> 32 << 32;
    if (g.cells.empty() || g.cells.back() != cell) {
      g.cells.push_back(cell);
      g.cell_begin.push_back(uint32_t(i));
    }
    g.cell_items[i] = uint32_t(g.keys[i]);
  }
  g.cell_begin.push_back(uint32_t(g.keys.size()));
  // A power of two at least twice the cells; entries are cell index + 1 (0: empty).
  g.table_bits = 1;
  while ((size_t(1) << g.table_bits) < 2 * g.cells.size()) ++g.table_bits;
  g.table.assign(size_t(1) << g.table_bits, 0);
  const uint32_t mask = (1u << g.table_bits) - 1;
  for (uint32_t c = 0; c < g.cells.size(); ++c) {
    uint32_t slot = uint32_t(g.cells[c] >> 32) * 0x9E3779B1u >> (32 - g.table_bits);
    while (g.table[slot] != 0) slot = (slot + 1) & mask;
    g.table[slot] = c + 1;
  }
}

// The index of a cell in g.cells, or ~0u when it holds nothing.
uint32_t find_cell(const PieceContactScratch& g, uint64_t cell) {
  const uint32_t mask = (1u << g.table_bits) - 1;
  for (uint32_t slot = uint32_t(cell >> 32) * 0x9E3779B1u >> (32 - g.table_bits);; slot = (slot + 1) & mask) {
    const uint32_t c = g.table[slot];
    if (c == 0) return ~0u;
    if (g.cells[c - 1] == cell) return c - 1;
  }
}

// Calls f(begin, end) for the ranges (in cell_items) of the 27 cells around cell (i, j, k).
template <typename F>
void for_neighbour_cells(const PieceContactScratch& g, int64_t i, int64_t j, int64_t k, F&& f) {
  for (int64_t dk = -1; dk <= 1; ++dk) {
    for (int64_t dj = -1; dj <= 1; ++dj) {
      for (int64_t di = -1; di <= 1; ++di) {
        const uint32_t c = find_cell(g, cell_key(i + di, j + dj, k + dk));
        if (c != ~0u) f(g.cell_begin[c], g.cell_begin[c + 1]);
      }
    }
  }
}

// Calls f(n) for each entry n of cell_items in the 27 cells around cell (i, j, k).
template <typename F>
void for_neighbours(const PieceContactScratch& g, int64_t i, int64_t j, int64_t k, F&& f) {
  for_neighbour_cells(g, i, j, k, [&](uint32_t begin, uint32_t end) {
    for (uint32_t n = begin; n < end; ++n) f(n);
  });
}

}  // namespace

void find_bodies(const uint32_t* corners, const uint8_t* live, uint32_t piece_count, uint32_t particle_count,
                 std::vector<uint32_t>& body, PieceContactScratch& scratch) {
  std::vector<uint32_t>& parent = scratch.parent;
  parent.resize(particle_count);
  for (uint32_t p = 0; p < particle_count; ++p) parent[p] = p;
  const auto find = [&](uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  for (uint32_t i = 0; i < piece_count; ++i) {
    if (!live[i]) continue;
    for (int c = 1; c < 8; ++c) {
      const uint32_t a = find(corners[8 * i]), b = find(corners[8 * i + c]);
      if (a != b) parent[std::max(a, b)] = std::min(a, b);
    }
  }
  body.resize(piece_count);
  for (uint32_t i = 0; i < piece_count; ++i) body[i] = live[i] ? find(corners[8 * i]) : ~0u;
}

uint32_t find_exposed_pieces(const Vec3d* lo, const Vec3d* hi, const uint8_t* live, const uint32_t* body,
                             uint32_t piece_count, double reach, std::vector<uint8_t>& exposed,
                             PieceContactScratch& g, uint64_t* pairs_tested) {
  exposed.assign(piece_count, 0);
  // Cells at least as large as any grown piece: overlapping pieces have their low corners in
  // neighbouring cells.
  double size = 0.0;
  for (uint32_t i = 0; i < piece_count; ++i) {
    if (live[i]) size = std::max(size, (hi[i] - lo[i]).maxCoeff());
  }
  size += 2.0 * reach;
  if (!(size > 0.0) || !std::isfinite(size)) return 0;
  g.keys.clear();
  for (uint32_t i = 0; i < piece_count; ++i) {
    if (!live[i]) continue;
    const uint64_t cell = cell_key(cell_coord(lo[i].x() - reach, size), cell_coord(lo[i].y() - reach, size),
                                   cell_coord(lo[i].z() - reach, size));
    g.keys.push_back(cell | i);
  }
  build_cells(g);
  uint32_t count = 0;
  g.pairs.clear();
  for (uint32_t i = 0; i < piece_count; ++i) {
    if (!live[i]) continue;
    const Vec3d a = lo[i] - Vec3d::Constant(reach), b = hi[i] + Vec3d::Constant(reach);
    for_neighbours(g, cell_coord(a.x(), size), cell_coord(a.y(), size), cell_coord(a.z(), size), [&](uint32_t n) {
      const uint32_t j = g.cell_items[n];
      if (j <= i || body[j] == body[i]) return;
      if (pairs_tested) ++*pairs_tested;
      if ((lo[j].array() - reach > b.array()).any() || (hi[j].array() + reach < a.array()).any()) return;
      count += !exposed[i] + !exposed[j];
      exposed[i] = exposed[j] = 1;
      g.pairs.push_back((uint64_t(i) << 32) | j);
      g.pairs.push_back((uint64_t(j) << 32) | i);
    });
  }
  // The partners of each piece, ascending.
  std::sort(g.pairs.begin(), g.pairs.end());
  g.partner_begin.assign(piece_count + 1, 0);
  g.partners.resize(g.pairs.size());
  for (size_t k = 0; k < g.pairs.size(); ++k) {
    ++g.partner_begin[(g.pairs[k] >> 32) + 1];
    g.partners[k] = uint32_t(g.pairs[k]);
  }
  for (uint32_t i = 0; i < piece_count; ++i) g.partner_begin[i + 1] += g.partner_begin[i];
  return count;
}

bool near_partner(const PieceContactScratch& g, const Vec3d* lo, const Vec3d* hi, uint32_t piece, const Vec3d& x,
                  double reach) {
  // A hair of slack: an embedded point may round a few ulps outside its piece's bounds.
  const double r = reach * (1.0 + 1e-9);
  for (uint32_t k = g.partner_begin[piece]; k < g.partner_begin[piece + 1]; ++k) {
    const uint32_t j = g.partners[k];
    if ((lo[j].array() - r <= x.array()).all() && (x.array() <= hi[j].array() + r).all()) return true;
  }
  return false;
}

// Two surface points face each other when their normals are more than ~155 degrees apart: the faces
// of a cut (180), a piece lying on another; not the rims where a cut face meets the old surface (their
// averaged normals are 90 and 135 degrees from the faces'), which would push sideways.
constexpr double kFacing = -0.9;

uint32_t gather_piece_contacts(SurfacePoint* points, uint32_t count, const double* x, uint32_t particle_count,
                               double reach, double max_push, double friction, ContactSet& set, PieceContactScratch& g,
                               uint64_t* pairs_tested) {
  if (count == 0 || !(reach > 0.0)) return 0;
  // Points in cells of size `reach`, each cell's items grouped by body (items are ranks in body
  // order), with the end of each item's body run: a query jumps over its own body's points (most of
  // a cell, where a body lies on another) instead of testing them one by one.
  g.by_body.resize(count);
  for (uint32_t v = 0; v < count; ++v) g.by_body[v] = (uint64_t(points[v].body) << 32) | v;
  std::sort(g.by_body.begin(), g.by_body.end());
  g.keys.clear();
  for (uint32_t rank = 0; rank < count; ++rank) {
    const Vec3d& p = points[uint32_t(g.by_body[rank])].position;
    const uint64_t cell = cell_key(cell_coord(p.x(), reach), cell_coord(p.y(), reach), cell_coord(p.z(), reach));
    g.keys.push_back(cell | rank);
  }
  build_cells(g);
  g.item_body.resize(count);
  g.run_end.resize(count);
  for (uint32_t c = 0; c + 1 < g.cell_begin.size(); ++c) {
    for (uint32_t n = g.cell_begin[c + 1]; n-- > g.cell_begin[c];) {
      const uint64_t entry = g.by_body[g.cell_items[n]];
      g.cell_items[n] = uint32_t(entry);
      g.item_body[n] = uint32_t(entry >> 32);
      const bool last = n + 1 == g.cell_begin[c + 1] || g.item_body[n + 1] != g.item_body[n];
      g.run_end[n] = last ? n + 1 : g.run_end[n + 1];
    }
  }
  g.busy.resize(particle_count, 0);
  std::vector<float>& fresh_allowance = g.allowance;  // written after the pass: pairs read the old values
  fresh_allowance.assign(count, 0.0f);
  const auto point_at = [&](const SurfacePoint& s) {
    Vec3d r = Vec3d::Zero();
    for (int k = 0; k < 8; ++k) r += s.weights[k] * Vec3d(x[3 * size_t(s.particles[k])], x[3 * size_t(s.particles[k]) + 1],
                                                          x[3 * size_t(s.particles[k]) + 2]);
    return r;
  };
  // Each point's nearest point of another body within reach whose normal faces its own.
  g.nearest.assign(count, ~0u);
  for (uint32_t v = 0; v < count; ++v) {
    const SurfacePoint& a = points[v];
    uint32_t best = ~0u;
    double best_d = reach * reach;
    for_neighbour_cells(g, cell_coord(a.position.x(), reach), cell_coord(a.position.y(), reach),
                        cell_coord(a.position.z(), reach), [&](uint32_t begin, uint32_t end) {
                          for (uint32_t n = begin; n < end; ++n) {
                            if (g.item_body[n] == a.body) {
                              n = g.run_end[n] - 1;
                              continue;
                            }
                            if (pairs_tested) ++*pairs_tested;
                            const uint32_t q = g.cell_items[n];
                            const SurfacePoint& b = points[q];
                            if (a.normal.dot(b.normal) > kFacing) continue;
                            const double d = (b.position - a.position).squaredNorm();
                            if (d < best_d || (d == best_d && q < best)) {
                              best_d = d;
                              best = q;
                            }
                          }
                        });
    g.nearest[v] = best;
  }
  uint32_t added = 0;
  for (uint32_t v = 0; v < count; ++v) {
    const uint32_t best = g.nearest[v];
    if (best == ~0u) {
      fresh_allowance[v] = 0.0f;  // out of contact: no overlap allowed from now on
      continue;
    }
    const SurfacePoint& a = points[v];
    const SurfacePoint& b = points[best];
    ContactPoint c;
    c.normal = b.normal;  // q's tangent plane
    // The overlap now (< 0: a gap), and what the pair may keep of it: a fresh pair starts in contact
    // at zero depth where it overlaps (a gap is no allowance: it may close, never be held open); then
    // never more overlap than before. A deeper overlap is pushed out by at most max_push this step.
    const double overlap = -c.normal.dot(point_at(a) - point_at(b));
    const double before = std::max(a.allowance, b.allowance);
    const double kept = std::isinf(before) ? std::max(overlap, 0.0) : std::min(std::max(overlap, 0.0), before);
    const double allowed = std::max(kept, overlap - max_push);
    fresh_allowance[v] = float(kept);
    // Two points each other's nearest (the two faces of a cut, vertex on vertex) are one touching
    // pair: its contact is made once, at the lower index (sim/contact.h, "One contact per pair").
    if (g.nearest[best] == v && best < v) continue;
    std::copy(a.particles, a.particles + 8, c.particles);
    std::copy(b.particles, b.particles + 8, c.particles + 8);
    for (int k = 0; k < 8; ++k) {
      c.weights[k] = a.weights[k];
      c.weights[8 + k] = -b.weights[k];
    }
    c.target = -allowed;
    c.static_friction = c.kinetic_friction = friction;
    // Greedy colour over the 16 particles.
    uint64_t taken = 0;
    for (uint32_t p : c.particles) taken |= g.busy[p];
    uint32_t colour = 0;
    while (colour < kContactOverflow && ((taken >> colour) & 1u)) ++colour;
    if (colour < kContactOverflow) {
      for (uint32_t p : c.particles) {
        if (g.busy[p] == 0) g.touched.push_back(p);
        g.busy[p] |= uint64_t(1) << colour;
      }
    }
    contacts_add(set, colour, added++, c);
  }
  for (uint32_t p : g.touched) g.busy[p] = 0;
  g.touched.clear();
  for (uint32_t v = 0; v < count; ++v) points[v].allowance = fresh_allowance[v];
  return added;
}

}  // namespace dvx
