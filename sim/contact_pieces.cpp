// Contact between pieces of different bodies (sim/contact.h): the bodies, the surface points' cells,
// each point's nearest facing point of another body, and the grouped, coloured contacts they make.
#include "sim/contact.h"

#include "sim/union_find.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace dvx {
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

// Groups (cell << 32 | item) keys by cell, each cell's items in the order given, in O(n) (no sort):
// the cells (distinct, in order of first appearance), their item ranges, and an open-addressing
// table from a cell key to its index (a query looks up 27 cells: a table probe each).
void build_cells(PieceContactScratch& g) {
  const uint32_t n = uint32_t(g.keys.size());
  // A power of two at least twice the keys (so twice the cells); entries are cell index + 1 (0: empty).
  g.table_bits = 1;
  while ((size_t(1) << g.table_bits) < 2 * size_t(n)) ++g.table_bits;
  g.table.assign(size_t(1) << g.table_bits, 0);
  const uint32_t mask = (1u << g.table_bits) - 1;
  g.cells.clear();
  g.cursor.clear();  // items per cell
  g.cell_of.resize(n);
  for (uint32_t i = 0; i < n; ++i) {
    const uint64_t cell = g.keys[i] >> 32 << 32;
    uint32_t slot = uint32_t(cell >> 32) * 0x9E3779B1u >> (32 - g.table_bits);
    while (g.table[slot] != 0 && g.cells[g.table[slot] - 1] != cell) slot = (slot + 1) & mask;
    if (g.table[slot] == 0) {
      g.cells.push_back(cell);
      g.cursor.push_back(0);
      g.table[slot] = uint32_t(g.cells.size());
    }
    g.cell_of[i] = g.table[slot] - 1;
    ++g.cursor[g.cell_of[i]];
  }
  // Ranges, then the items in order.
  const uint32_t cells = uint32_t(g.cells.size());
  g.cell_begin.resize(cells + 1);
  g.cell_begin[0] = 0;
  for (uint32_t c = 0; c < cells; ++c) {
    g.cell_begin[c + 1] = g.cell_begin[c] + g.cursor[c];
    g.cursor[c] = g.cell_begin[c];
  }
  g.cell_items.resize(n);
  for (uint32_t i = 0; i < n; ++i) g.cell_items[g.cursor[g.cell_of[i]]++] = uint32_t(g.keys[i]);
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

}  // namespace

void find_bodies(const uint32_t* corners, const uint8_t* live, uint32_t piece_count, uint32_t particle_count,
                 std::vector<uint32_t>& body, PieceContactScratch& scratch) {
  std::vector<uint32_t>& parent = scratch.parent;
  parent.resize(particle_count);
  for (uint32_t p = 0; p < particle_count; ++p) parent[p] = p;
  for (uint32_t i = 0; i < piece_count; ++i) {
    if (!live[i]) continue;
    for (int c = 1; c < 8; ++c) uf_unite(parent.data(), corners[8 * i], corners[8 * i + c]);
  }
  body.resize(piece_count);
  for (uint32_t i = 0; i < piece_count; ++i) body[i] = live[i] ? uf_find(parent.data(), corners[8 * i]) : ~0u;
}

namespace {

// Sorts (i << 32 | j) pairs and lists each i's js, ascending: js[begin[i] .. begin[i + 1]).
void partner_lists(std::vector<uint64_t>& pairs, uint32_t n, std::vector<uint32_t>& begin, std::vector<uint32_t>& js) {
  std::sort(pairs.begin(), pairs.end());
  begin.assign(n + 1, 0);
  js.resize(pairs.size());
  for (size_t k = 0; k < pairs.size(); ++k) {
    ++begin[(pairs[k] >> 32) + 1];
    js[k] = uint32_t(pairs[k]);
  }
  for (uint32_t i = 0; i < n; ++i) begin[i + 1] += begin[i];
}

// Whether two boxes, grown by reach_a and reach_b, overlap (as find_exposed_pieces tests two pieces).
bool grown_overlap(const Vec3d& lo_a, const Vec3d& hi_a, double reach_a, const Vec3d& lo_b, const Vec3d& hi_b, double reach_b) {
  const Vec3d a = lo_a - Vec3d::Constant(reach_a), b = hi_a + Vec3d::Constant(reach_a);
  return !((lo_b.array() - reach_b > b.array()).any() || (hi_b.array() + reach_b < a.array()).any());
}

}  // namespace

uint32_t find_candidate_pieces(const Vec3d* lo, const Vec3d* hi, const double* reach, const uint8_t* live,
                               const uint32_t* body_index, uint32_t bodies, uint32_t piece_count, PieceContactScratch& g) {
  g.candidate.assign(piece_count, 0);
  if (bodies < 2) return 0;
  // The bodies' bounds (each holds its pieces'; so a piece's test against a body's bounds is
  // conservative: rounding is monotonic).
  g.body_lo.assign(bodies, Vec3d::Constant(std::numeric_limits<double>::infinity()));
  g.body_hi.assign(bodies, Vec3d::Constant(-std::numeric_limits<double>::infinity()));
  g.body_reach.assign(bodies, 0.0);
  for (uint32_t i = 0; i < piece_count; ++i) {
    if (!live[i]) continue;
    g.body_lo[body_index[i]] = g.body_lo[body_index[i]].cwiseMin(lo[i]);
    g.body_hi[body_index[i]] = g.body_hi[body_index[i]].cwiseMax(hi[i]);
    g.body_reach[body_index[i]] = std::max(g.body_reach[body_index[i]], reach[i]);
  }
  const std::vector<double>& r = g.body_reach;
  // Sweep along x: the bodies by grown lower bound (a non-finite bound first, so it meets every
  // body); a pair overlaps only while the later one starts before the earlier one ends.
  const auto start = [&](uint32_t b) {
    return std::isnan(g.body_lo[b].x()) ? -std::numeric_limits<double>::infinity() : g.body_lo[b].x() - r[b];
  };
  g.body_order.resize(bodies);
  for (uint32_t b = 0; b < bodies; ++b) g.body_order[b] = b;
  std::sort(g.body_order.begin(), g.body_order.end(), [&](uint32_t a, uint32_t b) {
    return start(a) < start(b) || (start(a) == start(b) && a < b);
  });
  g.body_pairs.clear();
  for (uint32_t m = 0; m < bodies; ++m) {
    const uint32_t a = g.body_order[m];
    for (uint32_t k = m + 1; k < bodies; ++k) {
      const uint32_t b = g.body_order[k];
      if (start(b) > g.body_hi[a].x() + r[a]) break;
      if (!grown_overlap(g.body_lo[a], g.body_hi[a], r[a], g.body_lo[b], g.body_hi[b], r[b])) continue;
      g.body_pairs.push_back((uint64_t(a) << 32) | b);
      g.body_pairs.push_back((uint64_t(b) << 32) | a);
    }
  }
  if (g.body_pairs.empty()) return 0;
  partner_lists(g.body_pairs, bodies, g.body_partner_begin, g.body_partners);
  // A piece is a candidate when it reaches the bounds of a body overlapping its own (with many such
  // bodies, every piece of the body is).
  constexpr uint32_t kMaxTests = 16;
  uint32_t count = 0;
  for (uint32_t i = 0; i < piece_count; ++i) {
    if (!live[i]) continue;
    const uint32_t b = body_index[i], first = g.body_partner_begin[b], last = g.body_partner_begin[b + 1];
    bool near = last - first > kMaxTests;
    for (uint32_t k = first; k < last && !near; ++k) {
      const uint32_t c = g.body_partners[k];
      near = grown_overlap(lo[i], hi[i], reach[i], g.body_lo[c], g.body_hi[c], r[c]);
    }
    g.candidate[i] = near;
    count += near;
  }
  return count;
}

namespace {

// The pairs (i << 32 | j, i < j) of the pieces marked in `keyed` that belong to different bodies
// and whose boxes [box_lo, box_hi] overlap, each pair with a piece of `queries` (nullptr: every keyed
// piece; `queried` marks the same pieces), in g.pairs in the order met (repeats possible, see
// sort_unique). Cells at least as large as any box: overlapping boxes have their low corners in
// neighbouring cells. Returns false when no keyed piece has a finite, non-empty box. (A box with a
// NaN overlaps every box in its cell, as grown_overlap has it.)
bool box_pairs(const Vec3d* box_lo, const Vec3d* box_hi, const uint8_t* keyed, const uint32_t* body, uint32_t piece_count,
               const std::vector<uint32_t>* queries, const uint8_t* queried, PieceContactScratch& g,
               uint64_t* pairs_tested) {
  g.pairs.clear();
  // The cell size (the largest box) and the widest box in x (the query's runs, below).
  double size = 0.0, widest_x = 0.0;
  for (uint32_t i = 0; i < piece_count; ++i) {
    if (!keyed[i]) continue;
    size = std::max(size, (box_hi[i] - box_lo[i]).maxCoeff());
    widest_x = std::max(widest_x, box_hi[i].x() - box_lo[i].x());
  }
  if (!(size > 0.0) || !std::isfinite(size)) return false;
  g.keys.clear();
  for (uint32_t i = 0; i < piece_count; ++i) {
    if (!keyed[i]) continue;
    g.keys.push_back(cell_key(cell_coord(box_lo[i].x(), size), cell_coord(box_lo[i].y(), size), cell_coord(box_lo[i].z(), size)) | i);
  }
  build_cells(g);
  // Each cell's items by lower x bound (then by piece: a fixed order), so a query reads only the
  // run of a cell whose boxes can reach its x range: a box j overlaps box i in x only if
  // lo_i.x - (widest box in x) <= lo_j.x <= hi_i.x. With cells as large as the largest box, the 27
  // cells span three times that: the runs halved the box tests of a sever step's refresh (bunny
  // at 256, 361 queries: 190 000 -> 95 000).
  const uint32_t cells = uint32_t(g.cells.size());
  for (uint32_t c = 0; c < cells; ++c) {
    // A NaN bound first (a total order: it is never skipped and never ends a run).
    std::sort(g.cell_items.begin() + g.cell_begin[c], g.cell_items.begin() + g.cell_begin[c + 1], [&](uint32_t a, uint32_t b) {
      const double xa = box_lo[a].x(), xb = box_lo[b].x();
      const bool na = std::isnan(xa), nb = std::isnan(xb);
      if (na != nb) return na;
      return (!na && xa < xb) || ((na || xa == xb) && a < b);
    });
  }
  // Each item's body and bounds, in cell order: a query reads its 27 cells' items in a row.
  const uint32_t items = uint32_t(g.cell_items.size());
  g.item_body.resize(items);
  g.cell_lo.resize(items);
  g.cell_hi.resize(items);
  for (uint32_t n = 0; n < items; ++n) {
    const uint32_t j = g.cell_items[n];
    g.item_body[n] = body[j];
    g.cell_lo[n] = box_lo[j];
    g.cell_hi[n] = box_hi[j];
  }
  uint64_t tested = 0;
  const auto query = [&](uint32_t i) {
    const Vec3d a = box_lo[i], b = box_hi[i];
    // A relative sliver below: rounding can never skip a box that reaches i.
    const double from_x = a.x() - widest_x - (std::abs(a.x()) + widest_x) * 1e-12;
    const uint32_t own = body[i];
    for_neighbour_cells(g, cell_coord(a.x(), size), cell_coord(a.y(), size), cell_coord(a.z(), size), [&](uint32_t begin, uint32_t end) {
      uint32_t n = begin;
      while (n < end && g.cell_lo[n].x() < from_x) ++n;  // ends before i starts
      for (; n < end && !(g.cell_lo[n].x() > b.x()); ++n) {
        if (g.item_body[n] == own) continue;  // the same body (and i itself)
        const uint32_t j = g.cell_items[n];
        // A pair of two queried pieces once, from the lower one.
        if ((queries == nullptr || queried[j]) && j < i) continue;
        ++tested;
        if ((g.cell_lo[n].array() > b.array()).any() || (g.cell_hi[n].array() < a.array()).any()) continue;
        g.pairs.push_back(i < j ? (uint64_t(i) << 32) | j : (uint64_t(j) << 32) | i);
      }
    });
  };
  if (queries == nullptr) {
    for (uint32_t i = 0; i < piece_count; ++i) {
      if (keyed[i]) query(i);
    }
  } else {
    for (const uint32_t i : *queries) query(i);
  }
  if (pairs_tested) *pairs_tested += tested;
  return true;
}

// Sorts pairs and drops repeats (two of the 27 cells a query visits may share a hash, and then the
// same cell is met twice). Pairs of pieces below piece_count sort as i * piece_count + j, which
// needs 2 log2(piece_count) bits: a least-significant-digit radix sort of 11-bit digits takes two or
// three passes where std::sort compared ~14 times a pair (a sever step's 15 000 new pairs).
void sort_unique(std::vector<uint64_t>& pairs, uint32_t piece_count, std::vector<uint64_t>& buffer) {
  const size_t n = pairs.size();
  if (n < 256 || piece_count > (1u << 26)) {
    std::sort(pairs.begin(), pairs.end());
  } else {
    const uint64_t count = piece_count;
    for (uint64_t& p : pairs) p = (p >> 32) * count + uint32_t(p);
    const uint64_t largest = count * count;
    constexpr uint32_t kDigit = 11, kBuckets = 1u << kDigit;
    buffer.resize(n);
    for (uint32_t shift = 0; shift < 64 && (largest >> shift) != 0; shift += kDigit) {
      uint32_t start[kBuckets + 1] = {};
      for (const uint64_t p : pairs) ++start[((p >> shift) & (kBuckets - 1)) + 1];
      for (uint32_t b = 0; b < kBuckets; ++b) start[b + 1] += start[b];
      for (const uint64_t p : pairs) buffer[start[(p >> shift) & (kBuckets - 1)]++] = p;
      pairs.swap(buffer);
    }
    for (uint64_t& p : pairs) p = (p / count) << 32 | (p % count);
  }
  pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
}

// Marks both pieces of each pair (i << 32 | j, i < j, ascending) in `pairs` that passes `keep`, and
// lists each piece's partners (g.partner_begin, g.partners), ascending: a piece p meets its partners
// below it in pairs (i, p), ascending in i, before those above it in pairs (p, k), ascending in k.
// Returns how many pieces it marked.
template <typename Keep>
uint32_t mark_exposed(const std::vector<uint64_t>& pairs, uint32_t piece_count, std::vector<uint8_t>& exposed,
                      PieceContactScratch& g, Keep&& keep) {
  exposed.assign(piece_count, 0);
  g.partner_begin.assign(piece_count + 1, 0);
  g.both.clear();
  uint32_t count = 0;
  for (const uint64_t pair : pairs) {
    const uint32_t i = uint32_t(pair >> 32), j = uint32_t(pair);
    if (!keep(i, j)) continue;
    count += !exposed[i] + !exposed[j];
    exposed[i] = exposed[j] = 1;
    ++g.partner_begin[i + 1];
    ++g.partner_begin[j + 1];
    g.both.push_back(pair);
  }
  for (uint32_t i = 0; i < piece_count; ++i) g.partner_begin[i + 1] += g.partner_begin[i];
  g.partners.resize(g.partner_begin[piece_count]);
  g.cursor.assign(g.partner_begin.begin(), g.partner_begin.end() - 1);
  for (const uint64_t pair : g.both) {
    const uint32_t i = uint32_t(pair >> 32), j = uint32_t(pair);
    g.partners[g.cursor[i]++] = j;
    g.partners[g.cursor[j]++] = i;
  }
  return count;
}

}  // namespace

uint32_t find_exposed_pieces(const Vec3d* lo, const Vec3d* hi, const double* reach, const uint8_t* live,
                             const uint32_t* body, uint32_t piece_count, std::vector<uint8_t>& exposed,
                             PieceContactScratch& g, uint64_t* pairs_tested) {
  // The bounds grown by their reach.
  g.box_lo.resize(piece_count);
  g.box_hi.resize(piece_count);
  for (uint32_t i = 0; i < piece_count; ++i) {
    g.box_lo[i] = lo[i] - Vec3d::Constant(reach[i]);
    g.box_hi[i] = hi[i] + Vec3d::Constant(reach[i]);
  }
  if (!box_pairs(g.box_lo.data(), g.box_hi.data(), live, body, piece_count, nullptr, nullptr, g, pairs_tested)) {
    exposed.assign(piece_count, 0);
    return 0;
  }
  sort_unique(g.pairs, piece_count, g.sort_buffer);
  return mark_exposed(g.pairs, piece_count, exposed, g, [](uint32_t, uint32_t) { return true; });
}

uint32_t find_exposed_pieces_cached(const Vec3d* lo, const Vec3d* hi, const double* reach, const uint8_t* candidate, const uint32_t* body, uint32_t piece_count, double margin,
                                    std::vector<uint8_t>& exposed, PieceContactScratch& g, uint64_t* pairs_tested) {
  PairCache& cache = g.pair_cache;
  // The cached bounds of piece i from its bounds now: grown by its reach (as grown_overlap grows
  // them) plus the margin.
  const auto cache_piece = [&](uint32_t i) {
    cache.lo[i] = lo[i] - Vec3d::Constant(reach[i] + margin);
    cache.hi[i] = hi[i] + Vec3d::Constant(reach[i] + margin);
    cache.body[i] = body[i];
    cache.member[i] = 1;
  };
  // A candidate's entry holds while it was one when cached, with the same body, and its grown bounds
  // now lie within the cached ones (NaN never does); the others are stale.
  const auto holds = [&](uint32_t i) {
    if (!cache.member[i] || cache.body[i] != body[i]) return false;
    const Vec3d a = lo[i] - Vec3d::Constant(reach[i]), b = hi[i] + Vec3d::Constant(reach[i]);
    return (cache.lo[i].array() <= a.array()).all() && (b.array() <= cache.hi[i].array()).all();
  };
  std::vector<uint32_t>& stale = g.stale;
  stale.clear();
  uint32_t members = 0;
  bool rebuild = !cache.valid || piece_count < cache.pieces;
  if (!rebuild) {
    // New piece slots join as non-members.
    cache.member.resize(piece_count, 0);
    cache.body.resize(piece_count, ~0u);
    cache.lo.resize(piece_count, Vec3d::Zero());
    cache.hi.resize(piece_count, Vec3d::Zero());
    cache.pieces = piece_count;
    for (uint32_t i = 0; i < piece_count; ++i) {
      members += cache.member[i];
      if (candidate[i] && !holds(i)) stale.push_back(i);
    }
    // Nearly all stale (every body renumbered, everything moved): rebuild.
    rebuild = stale.size() > std::max<size_t>(kPairCachePartialMin, 3 * members / 4);
  }
  if (rebuild) {
    // Over the candidates, grown by the margin.
    ++cache.builds;
    cache.valid = true;
    cache.pieces = piece_count;
    cache.member.assign(piece_count, 0);
    cache.body.assign(piece_count, ~0u);
    cache.lo.resize(piece_count);
    cache.hi.resize(piece_count);
    for (uint32_t i = 0; i < piece_count; ++i) {
      if (!candidate[i]) continue;
      cache_piece(i);
      if (!(cache.lo[i].allFinite() && cache.hi[i].allFinite())) cache.valid = false;  // not kept
    }
    cache.pairs.clear();
    // Every pair has a piece outside the body with the most members: only those query the grid (a
    // sever pairs a slice with the body it left, whose many pieces would mostly meet their own).
    std::vector<uint64_t>& by_body = g.by_body;
    by_body.clear();
    for (uint32_t i = 0; i < piece_count; ++i) {
      if (cache.member[i]) by_body.push_back(uint64_t(cache.body[i]) << 32 | i);
    }
    std::sort(by_body.begin(), by_body.end());
    size_t most = 0, most_begin = 0;
    for (size_t b = 0, e = 0; b < by_body.size(); b = e) {
      for (e = b; e < by_body.size() && by_body[e] >> 32 == by_body[b] >> 32; ++e) {
      }
      if (e - b > most) most = e - b, most_begin = b;
    }
    g.stale.clear();  // scratch here: the pieces that query, as a list and as flags
    g.is_stale.assign(piece_count, 0);
    for (size_t k = 0; k < by_body.size(); ++k) {
      if (k >= most_begin && k < most_begin + most) continue;
      g.stale.push_back(uint32_t(by_body[k]));
      g.is_stale[uint32_t(by_body[k])] = 1;
    }
    if (box_pairs(cache.lo.data(), cache.hi.data(), cache.member.data(), cache.body.data(), piece_count, &g.stale,
                  g.is_stale.data(), g, pairs_tested)) {
      cache.pairs.swap(g.pairs);
    }
    sort_unique(cache.pairs, piece_count, g.sort_buffer);
  } else if (!stale.empty()) {
    // Refresh the stale entries: drop their pairs, cache their bounds now, and pair them with every
    // member whose cached bounds overlap theirs. The cache then again holds every pair of members of
    // different bodies whose cached bounds overlap.
    ++cache.updates;
    g.is_stale.assign(piece_count, 0);
    for (const uint32_t i : stale) {
      g.is_stale[i] = 1;
      cache_piece(i);
      if (!(cache.lo[i].allFinite() && cache.hi[i].allFinite())) {
        // A non-finite piece (a blown-up step): the grid's rules for it, as find_exposed_pieces.
        cache.valid = false;
        return find_exposed_pieces_cached(lo, hi, reach, candidate, body, piece_count, margin, exposed, g, pairs_tested);
      }
    }
    cache.pairs.erase(std::remove_if(cache.pairs.begin(), cache.pairs.end(),
                                     [&](uint64_t pair) { return g.is_stale[pair >> 32] || g.is_stale[uint32_t(pair)]; }),
                      cache.pairs.end());
    if (!box_pairs(cache.lo.data(), cache.hi.data(), cache.member.data(), cache.body.data(), piece_count, &stale,
                   g.is_stale.data(), g, pairs_tested)) {
      cache.valid = false;
      return find_exposed_pieces_cached(lo, hi, reach, candidate, body, piece_count, margin, exposed, g, pairs_tested);
    }
    sort_unique(g.pairs, piece_count, g.sort_buffer);
    // The kept and the new pairs merged (disjoint: every new pair has a stale piece).
    g.sort_buffer.resize(cache.pairs.size() + g.pairs.size());
    std::merge(cache.pairs.begin(), cache.pairs.end(), g.pairs.begin(), g.pairs.end(), g.sort_buffer.begin());
    cache.pairs.swap(g.sort_buffer);
  }
  if (pairs_tested) *pairs_tested += cache.pairs.size();
  return mark_exposed(cache.pairs, piece_count, exposed, g, [&](uint32_t i, uint32_t j) {
    return candidate[i] && candidate[j] && grown_overlap(lo[i], hi[i], reach[i], lo[j], hi[j], reach[j]);
  });
}

void partner_regions(const PieceContactScratch& g, const Vec3d* lo, const Vec3d* hi, const double* reach, uint32_t piece,
                     std::vector<Vec3d>& region_lo, std::vector<Vec3d>& region_hi) {
  region_lo.clear();
  region_hi.clear();
  for (uint32_t k = g.partner_begin[piece]; k < g.partner_begin[piece + 1]; ++k) {
    const uint32_t j = g.partners[k];
    // The pair's reach; a hair of slack: an embedded point may round a few ulps outside its piece's bounds.
    const double r = std::max(reach[piece], reach[j]) * (1.0 + 1e-9);
    region_lo.push_back(lo[j].array() - r);
    region_hi.push_back(hi[j].array() + r);
  }
}

bool in_regions(const std::vector<Vec3d>& region_lo, const std::vector<Vec3d>& region_hi, const Vec3d& x) {
  for (size_t k = 0; k < region_lo.size(); ++k) {
    if ((region_lo[k].array() <= x.array()).all() && (x.array() <= region_hi[k].array()).all()) return true;
  }
  return false;
}

bool near_partner(const PieceContactScratch& g, const Vec3d* lo, const Vec3d* hi, const double* reach, uint32_t piece,
                  const Vec3d& x) {
  std::vector<Vec3d> region_lo, region_hi;
  partner_regions(g, lo, hi, reach, piece, region_lo, region_hi);
  return in_regions(region_lo, region_hi, x);
}

// Two surface points face each other when their normals are more than ~155 degrees apart: the faces
// of a cut (180), a piece lying on another; not the rims where a cut face meets the old surface (their
// averaged normals are 90 and 135 degrees from the faces'), which would push sideways.
constexpr double kFacing = -0.9;

namespace {

// The cells the points lie in: a dense grid over the cells they span (cells by linear index, x
// fastest) where those are few, else hashed cells. nx = 0: hashed.
struct ContactCells {
  bool dense = false;
  uint32_t nx = 0, ny = 0, nz = 0;
};

// Points in body order (counting sort; bodies are small numbers), stable: g.by_body holds
// body << 32 | point.
void sort_points_by_body(const SurfacePoint* points, uint32_t count, PieceContactScratch& g) {
  uint32_t bodies = 0;
  for (uint32_t v = 0; v < count; ++v) bodies = std::max(bodies, points[v].body + 1);
  g.by_body.resize(count);
  if (bodies <= 4 * count + 1024) {
    g.cursor.assign(bodies + 1, 0);
    for (uint32_t v = 0; v < count; ++v) ++g.cursor[points[v].body + 1];
    for (uint32_t b = 0; b < bodies; ++b) g.cursor[b + 1] += g.cursor[b];
    for (uint32_t v = 0; v < count; ++v) g.by_body[g.cursor[points[v].body]++] = (uint64_t(points[v].body) << 32) | v;
  } else {
    for (uint32_t v = 0; v < count; ++v) g.by_body[v] = (uint64_t(points[v].body) << 32) | v;
    std::sort(g.by_body.begin(), g.by_body.end());
  }
}

// The points' cells of size `reach`, each cell's items grouped by body (items are ranks in body
// order), with the end of each item's body run: a query jumps over its own body's points (most of a
// cell, where a body lies on another) instead of testing them one by one. The items' positions and
// normals are copied in cell order, so a query reads them in sequence. Where the cells the points
// span are few (a contact zone: a few per point), a dense grid over them: the cells of a row are
// neighbours in cell_items and a query's 13 cells are 5 ranges found by arithmetic. Otherwise hashed
// cells (build_cells: a table probe per neighbouring cell). Either way the same pairs are met.
ContactCells build_contact_cells(const SurfacePoint* points, uint32_t count, double reach, PieceContactScratch& g) {
  g.point_cell.resize(3 * size_t(count));
  int64_t low[3] = {INT64_MAX, INT64_MAX, INT64_MAX}, high[3] = {INT64_MIN, INT64_MIN, INT64_MIN};
  for (uint32_t rank = 0; rank < count; ++rank) {
    const Vec3d& p = points[uint32_t(g.by_body[rank])].position;
    for (int a = 0; a < 3; ++a) {
      const int64_t c = cell_coord(p[a], reach);
      g.point_cell[3 * size_t(rank) + a] = c;
      low[a] = std::min(low[a], c);
      high[a] = std::max(high[a], c);
    }
  }
  const uint64_t span[3] = {uint64_t(high[0] - low[0]) + 1, uint64_t(high[1] - low[1]) + 1, uint64_t(high[2] - low[2]) + 1};
  const uint64_t dense_limit = std::max<uint64_t>(4096, 32 * uint64_t(count));
  ContactCells cells;
  cells.dense = span[0] <= dense_limit && span[1] <= dense_limit && span[2] <= dense_limit &&
                span[0] * span[1] <= dense_limit && span[0] * span[1] * span[2] <= dense_limit;
  if (cells.dense) {
    cells.nx = uint32_t(span[0]);
    cells.ny = uint32_t(span[1]);
    cells.nz = uint32_t(span[2]);
    const uint32_t nx = cells.nx, ny = cells.ny;
    // Counting sort by linear index, stable (ranks ascending: a cell's items in body order).
    const uint32_t total = nx * ny * cells.nz;
    g.cell_begin.assign(size_t(total) + 1, 0);
    g.cell_of.resize(count);
    for (uint32_t rank = 0; rank < count; ++rank) {
      const int64_t* c = &g.point_cell[3 * size_t(rank)];
      g.cell_of[rank] = uint32_t(c[0] - low[0]) + nx * (uint32_t(c[1] - low[1]) + ny * uint32_t(c[2] - low[2]));
      ++g.cell_begin[g.cell_of[rank]];
    }
    for (uint32_t c = 1; c < total; ++c) g.cell_begin[c] += g.cell_begin[c - 1];  // ends
    g.cell_items.resize(count);
    for (uint32_t rank = count; rank-- > 0;) g.cell_items[--g.cell_begin[g.cell_of[rank]]] = rank;  // begins
    g.cell_begin[total] = count;
  } else {
    g.keys.clear();
    for (uint32_t rank = 0; rank < count; ++rank) {
      const int64_t* c = &g.point_cell[3 * size_t(rank)];
      g.keys.push_back(cell_key(c[0], c[1], c[2]) | rank);
    }
    build_cells(g);
  }
  g.item_body.resize(count);
  g.run_end.resize(count);
  g.item_rank.resize(count);
  g.item_position.resize(count);
  g.item_normal.resize(count);
  g.item_reach.resize(count);
  for (uint32_t c = 0; c + 1 < g.cell_begin.size(); ++c) {
    for (uint32_t n = g.cell_begin[c + 1]; n-- > g.cell_begin[c];) {
      const uint64_t entry = g.by_body[g.cell_items[n]];
      g.item_rank[n] = g.cell_items[n];
      g.cell_items[n] = uint32_t(entry);
      g.item_body[n] = uint32_t(entry >> 32);
      g.item_position[n] = points[uint32_t(entry)].position;
      g.item_normal[n] = points[uint32_t(entry)].normal;
      g.item_reach[n] = double(points[uint32_t(entry)].reach) * double(points[uint32_t(entry)].reach);
      const bool last = n + 1 == g.cell_begin[c + 1] || g.item_body[n + 1] != g.item_body[n];
      g.run_end[n] = last ? n + 1 : g.run_end[n + 1];
    }
  }
  return cells;
}

// Each point's nearest point of another body within reach whose normal faces its own: the least
// (distance, index), the same whatever the order in which pairs are met. So each pair is met once
// and updates both points: from the earlier item of a cell to the later ones, and from a cell to
// the 13 cells after it (in z, y, x order) of the 26 around it. The points of a cell share those
// ranges (recomputed where two cells share a hash; a pair met twice through a shared hash changes
// nothing). Leaves g.best by point (~0u: none); returns the pairs tested.
uint64_t nearest_facing(uint32_t count, double reach, const ContactCells& cells, PieceContactScratch& g) {
  const bool dense = cells.dense;
  const uint32_t nx = cells.nx, ny = cells.ny, nz = cells.nz;
  g.best.assign(count, ~0u);  // by item here, by point below
  g.best_d.assign(count, reach * reach);
  uint64_t tested = 0;
  const auto meet = [&](uint32_t n, uint32_t m, double d) {  // item n met item m at squared distance d
    const uint32_t q = g.cell_items[m];
    if (d < g.best_d[n] || (d == g.best_d[n] && q < g.best[n])) {
      g.best_d[n] = d;
      g.best[n] = q;
    }
  };
  for (uint32_t c = 0; c + 1 < g.cell_begin.size(); ++c) {
    const uint32_t cell_end = g.cell_begin[c + 1];
    if (g.cell_begin[c] == cell_end) continue;  // an empty cell of the dense grid
    // The 13 cells after this one: in a dense grid, the next cell of the row (scanned with this
    // cell's own items), the row above in y, and the three rows above in z; hashed, one probe each
    // (the points of a cell share them, recomputed where two cells share a hash).
    uint32_t own_end = cell_end;
    int64_t have[3] = {0, 0, 0};
    bool ready = false;
    if (dense) {
      const uint32_t cx = c % nx, cy = c / nx % ny, cz = c / nx / ny;
      const uint32_t left = cx > 0, right = cx + 1 < nx;
      if (right) own_end = g.cell_begin[c + 2];
      g.ranges.resize(8);  // at most 4 rows
      uint32_t rows = 0;
      const auto row = [&](uint32_t middle) {  // the cells middle - 1 .. middle + 1 of one row
        g.ranges[rows++] = g.cell_begin[middle - left];
        g.ranges[rows++] = g.cell_begin[middle + right + 1];
      };
      if (cy + 1 < ny) row(c + nx);
      if (cz + 1 < nz) {
        for (int dj = -1; dj <= 1; ++dj) {
          if ((dj < 0 && cy == 0) || (dj > 0 && cy + 1 == ny)) continue;
          row(uint32_t(int64_t(c) + int64_t(nx) * ny + int64_t(dj) * nx));
        }
      }
      g.ranges.resize(rows);
    }
    for (uint32_t item = g.cell_begin[c]; item < cell_end; ++item) {
      const Vec3d& position = g.item_position[item];
      const Vec3d& normal = g.item_normal[item];
      const double reach2 = g.item_reach[item];
      const uint32_t body = g.item_body[item];
      const int64_t* at = &g.point_cell[3 * size_t(g.item_rank[item])];
      if (!dense && (!ready || at[0] != have[0] || at[1] != have[1] || at[2] != have[2])) {
        g.ranges.clear();
        for (int64_t dk = 0; dk <= 1; ++dk) {
          for (int64_t dj = dk == 0 ? 0 : -1; dj <= 1; ++dj) {
            for (int64_t di = dk == 0 && dj == 0 ? 1 : -1; di <= 1; ++di) {
              const uint32_t found = find_cell(g, cell_key(at[0] + di, at[1] + dj, at[2] + dk));
              if (found == ~0u) continue;
              g.ranges.push_back(g.cell_begin[found]);
              g.ranges.push_back(g.cell_begin[found + 1]);
            }
          }
        }
        std::copy(at, at + 3, have);
        ready = true;
      }
      const auto scan = [&](uint32_t begin, uint32_t end) {
        for (uint32_t n = begin; n < end; ++n) {
          if (g.item_body[n] == body) {
            n = g.run_end[n] - 1;
            continue;
          }
          ++tested;
          if (normal.dot(g.item_normal[n]) > kFacing) continue;
          const double d = (g.item_position[n] - position).squaredNorm();
          if ((d > g.best_d[item] && d > g.best_d[n]) || (d > reach2 && d > g.item_reach[n])) continue;
          meet(item, n, d);
          meet(n, item, d);
        }
      };
      scan(item + 1, own_end);
      for (size_t r = 0; r < g.ranges.size(); r += 2) scan(g.ranges[r], g.ranges[r + 1]);
    }
  }
  // From items to points.
  for (uint32_t n = 0; n < count; ++n) g.by_body[g.cell_items[n]] = g.best[n];  // scratch: by point
  for (uint32_t v = 0; v < count; ++v) g.best[v] = uint32_t(g.by_body[v]);
  return tested;
}

// The contacts of the paired points (a mutual pair makes one), in groups, one per pair of pieces,
// coloured greedily over their particles; the points' allowances updated. Returns the contacts added.
uint32_t add_piece_contacts(SurfacePoint* points, uint32_t count, const double* x, uint32_t particle_count,
                            double max_push, double friction, ContactSet& set, PieceContactScratch& g) {
  g.busy.resize(particle_count, 0);
  std::vector<float>& fresh_allowance = g.allowance;  // written after the pass: pairs read the old values
  fresh_allowance.assign(count, 0.0f);
  const auto point_at = [&](const SurfacePoint& s) {
    Vec3d r = Vec3d::Zero();
    for (int k = 0; k < 8; ++k) r += s.weights[k] * Vec3d(x[3 * size_t(s.particles[k])], x[3 * size_t(s.particles[k]) + 1],
                                                          x[3 * size_t(s.particles[k]) + 2]);
    return r;
  };
  // Each paired point's allowance and the target of its contact. The two points of a mutual pair
  // (each the other's nearest) make one contact, the earlier one's: their constraints are the same
  // up to the normals' angle (within 25 degrees of opposite), and a fresh cut pairs its faces so.
  g.pending.clear();
  g.allowed.resize(count);
  for (uint32_t v = 0; v < count; ++v) {
    const SurfacePoint& a = points[v];
    const uint32_t best = g.best[v];
    if (best == ~0u) {
      fresh_allowance[v] = 0.0f;  // out of contact: no overlap allowed from now on
      continue;
    }
    const SurfacePoint& b = points[best];
    // The overlap now (< 0: a gap) against q's tangent plane, and what the pair may keep of it: a
    // fresh pair starts in contact at zero depth where it overlaps (a gap is no allowance: it may
    // close, never be held open); then never more overlap than before. A deeper overlap is pushed
    // out by at most max_push this step.
    const double overlap = -b.normal.dot(point_at(a) - point_at(b));
    const double before = std::max(a.allowance, b.allowance);
    const double kept = std::isinf(before) ? std::max(overlap, 0.0) : std::min(std::max(overlap, 0.0), before);
    g.allowed[v] = std::max(kept, overlap - max_push);
    fresh_allowance[v] = float(kept);
    if (g.best[best] == v && best < v) continue;  // the mutual pair's contact is best's
    const uint32_t lo = std::min(a.piece, b.piece), hi = std::max(a.piece, b.piece);
    g.pending.emplace_back((uint64_t(lo) << 32) | hi, v);
  }
  // Contacts in groups, one per pair of pieces (in pair order; a group's contacts in point order),
  // each group solved in order by one worker: the contacts of two pieces all share their 16
  // particles. Groups are coloured greedily over all their contacts' particles (63 colours, a
  // 64-bit mask per particle); a group that finds every colour taken goes to the overflow batch.
  std::sort(g.pending.begin(), g.pending.end());
  uint32_t added = 0, groups = 0;
  for (size_t first = 0; first < g.pending.size();) {
    size_t last = first;
    while (last < g.pending.size() && g.pending[last].first == g.pending[first].first) ++last;
    uint64_t taken = 0;
    for (size_t k = first; k < last; ++k) {
      const SurfacePoint& a = points[g.pending[k].second];
      const SurfacePoint& b = points[g.best[g.pending[k].second]];
      for (int i = 0; i < 8; ++i) taken |= g.busy[a.particles[i]] | g.busy[b.particles[i]];
    }
    const uint64_t free_bits = ~taken & ((uint64_t(1) << kContactOverflow) - 1);
    const uint32_t colour = free_bits == 0 ? kContactOverflow : uint32_t(__builtin_ctzll(free_bits));
    for (size_t k = first; k < last; ++k) {
      const uint32_t v = g.pending[k].second;
      const SurfacePoint& a = points[v];
      const SurfacePoint& b = points[g.best[v]];
      ContactPoint c;
      c.normal = b.normal;  // q's tangent plane
      std::copy(a.particles, a.particles + 8, c.particles);
      std::copy(b.particles, b.particles + 8, c.particles + 8);
      for (int i = 0; i < 8; ++i) {
        c.weights[i] = a.weights[i];
        c.weights[8 + i] = -b.weights[i];
      }
      c.target = -g.allowed[v];
      c.static_friction = c.kinetic_friction = friction;
      if (colour < kContactOverflow) {
        for (uint32_t p : c.particles) {
          if (g.busy[p] == 0) g.touched.push_back(p);
          g.busy[p] |= uint64_t(1) << colour;
        }
      }
      contacts_add(set, colour, groups, c);
      ++added;
    }
    ++groups;
    first = last;
  }
  for (uint32_t p : g.touched) g.busy[p] = 0;
  g.touched.clear();
  for (uint32_t v = 0; v < count; ++v) points[v].allowance = fresh_allowance[v];
  return added;
}

}  // namespace

uint32_t gather_piece_contacts(SurfacePoint* points, uint32_t count, const double* x, uint32_t particle_count,
                               double max_push, double friction, ContactSet& set, PieceContactScratch& g,
                               uint64_t* pairs_tested) {
  // Cells of the largest reach: a pair within its reach (the larger of its points') lies in
  // neighbouring cells.
  double reach = 0.0;
  for (uint32_t v = 0; v < count; ++v) reach = std::max(reach, double(points[v].reach));
  if (count == 0 || !(reach > 0.0) || !std::isfinite(reach)) return 0;
  sort_points_by_body(points, count, g);
  const ContactCells cells = build_contact_cells(points, count, reach, g);
  const uint64_t tested = nearest_facing(count, reach, cells, g);
  if (pairs_tested) *pairs_tested += tested;
  return add_piece_contacts(points, count, x, particle_count, max_push, friction, set, g);
}

}  // namespace dvx
