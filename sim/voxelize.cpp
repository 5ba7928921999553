// Voxelization by exact ray parity along the lattice lines of all three axes.
//
// Outline (everything deterministic, single-threaded):
//  1. Vertices are snapped to fixed point in lattice units (2^-20 voxel, int64).
//  2. Per axis a, every triangle is rasterised over the integer lattice points inside its
//     projection onto the plane of the other two axes (u, v). The hit test uses exact integer
//     edge functions with symbolic perturbation of the ray point by (+eps, +eps^2) in (u, v):
//     a ray through a projected edge or vertex is then a generic line, so it hits a closed
//     mesh an even number of times and a shared edge is counted by exactly one side. The
//     depth along the ray is rounded to the node after the crossing exactly (a crossing at a
//     node lies before it). Each hit is a 12-byte record keyed by that node.
//  3. Hits are radix sorted by key (stable, so ties keep triangle order).
//  4. The lattice is swept slice by slice (k = const): a byte per node holds the x, y and z
//     parities (x by runs between sorted hits, y by a prefix xor over rows, z carried from
//     the previous slice), the majority vote is packed into the `inside` bitset, occupied
//     voxels are counted, and the sign-change edges of the previous slice are emitted in edge
//     id order with their Hermite data looked up in the sorted hits. Memory besides the
//     output and the hits: five slices of bytes.
#include "sim/voxelize.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>

namespace dvx {
namespace {

__extension__ typedef __int128 i128;

constexpr int kFracBits = 20;
constexpr int64_t kUnit = int64_t(1) << kFracBits;
constexpr uint32_t kNegBit = 0x80000000u;   // Hit::tri: normal has a negative ray component
constexpr uint32_t kOnNodeBit = 0x40000000u;  // Hit::tri: the crossing lies exactly on the key node
constexpr uint32_t kTriMask = kOnNodeBit - 1;
// Largest voxel count per axis for which the edge functions fit in int64:
// |E| <= 2 * (n * 2^20)^2 < 2^63.
constexpr int64_t kMaxAxisForInt64 = 2000;

struct Hit {
  uint32_t key;  // node right after the crossing along the ray: the crossing lies in (key-1, key]
  float t;       // position within the lattice edge that ends at `key`, in [0, 1]
  uint32_t tri;  // triangle index | kNegBit | kOnNodeBit
};
static_assert(sizeof(Hit) == 12);

using Fixed3 = std::array<int64_t, 3>;

struct Grid {
  int64_t n[3];        // voxels per axis
  uint32_t stride[3];  // node index stride per axis
};

// ceil(x / 2^20) for any int64 (arithmetic shift floors).
int64_t ceil_unit(int64_t x) { return (x + (kUnit - 1)) >> kFracBits; }

// Rotation that puts the smallest index first (winding preserved): a triangle and its
// reversed copy then start at the same vertex, so their computations agree bit for bit.
Tri canonical(const Tri& t) {
  if (t[1] < t[0] && t[1] <= t[2]) return {t[1], t[2], t[0]};
  if (t[2] < t[0] && t[2] < t[1]) return {t[2], t[0], t[1]};
  return t;
}

// Unit normal of a triangle in its stored winding (zero when degenerate in double).
Vec3d triangle_normal(const TriMesh& mesh, uint32_t ti) {
  const Tri t = canonical(mesh.triangles[ti]);
  const Vec3d& p0 = mesh.positions[t[0]];
  const Vec3d n = (mesh.positions[t[1]] - p0).cross(mesh.positions[t[2]] - p0);
  const double len = n.norm();
  return len > 0.0 ? Vec3d(n / len) : Vec3d::Zero();
}

// Rasterises every triangle along axis a. Int: type of the 2D edge functions.
template <typename Int>
void raster_axis(int a, const TriMesh& mesh, const std::vector<Fixed3>& q, const std::vector<uint32_t>& active,
                 const Grid& g, std::vector<Hit>& hits) {
  const int u = (a + 1) % 3, v = (a + 2) % 3;
  const uint32_t su = g.stride[u], sv = g.stride[v], sa = g.stride[a];
  const int64_t na = g.n[a];
  for (const uint32_t ti : active) {
    const Tri tr = canonical(mesh.triangles[ti]);
    const int64_t* A = q[tr[0]].data();
    const int64_t* B = q[tr[1]].data();
    const int64_t* C = q[tr[2]].data();
    // Twice the projected area: the ray component of the (snapped) triangle normal.
    Int W = Int(B[u] - A[u]) * Int(C[v] - A[v]) - Int(B[v] - A[v]) * Int(C[u] - A[u]);
    if (W == 0) continue;  // degenerate in projection: no hit
    uint32_t tag = ti;
    if (W < 0) {
      std::swap(B, C);  // counter-clockwise in (u, v) from here on
      W = -W;
      tag |= kNegBit;
    }
    // Lattice points whose perturbed position (U + eps, V + eps^2) can lie inside:
    // min <= U * 2^20 < max on both axes.
    const int64_t umin = std::min({A[u], B[u], C[u]}), umax = std::max({A[u], B[u], C[u]});
    const int64_t vmin = std::min({A[v], B[v], C[v]}), vmax = std::max({A[v], B[v], C[v]});
    const int64_t U0 = ceil_unit(umin), U1 = ceil_unit(umax) - 1;
    const int64_t V0 = ceil_unit(vmin), V1 = ceil_unit(vmax) - 1;
    if (U0 > U1 || V0 > V1) continue;

    // Edge functions E_k(X) = orient(P_k, Q_k, X): k = 0 on B->C (weight of A), 1 on C->A
    // (weight of B), 2 on A->B (weight of C). The perturbed point is inside edge k when
    // E_k > 0, or E_k == 0 and the first non-zero perturbation term is positive:
    // orient(P, Q, X + (eps, eps^2)) = E + (Qu - Pu) eps^2 - (Qv - Pv) eps.
    const int64_t* P[3] = {B, C, A};
    const int64_t* Q[3] = {C, A, B};
    Int row[3], du[3], dv[3], thr[3];
    const int64_t x0 = U0 * kUnit, y0 = V0 * kUnit;
    for (int k = 0; k < 3; ++k) {
      const int64_t pu = P[k][u], pv = P[k][v];
      const int64_t eu = Q[k][u] - pu, ev = Q[k][v] - pv;
      row[k] = Int(eu) * Int(y0 - pv) - Int(ev) * Int(x0 - pu);
      du[k] = -Int(ev) * Int(kUnit);
      dv[k] = Int(eu) * Int(kUnit);
      const bool tie_inside = ev != 0 ? ev < 0 : eu > 0;
      thr[k] = tie_inside ? 0 : 1;
    }
    const int64_t az = A[a], dzb = B[a] - A[a], dzc = C[a] - A[a];
    const double inv_w = 1.0 / double(W);
    for (int64_t V = V0; V <= V1; ++V) {
      Int e0 = row[0], e1 = row[1], e2 = row[2];
      for (int64_t U = U0; U <= U1; ++U) {
        if ((e0 >= thr[0]) & (e1 >= thr[1]) & (e2 >= thr[2])) {
          // Depth (fixed point) = az + num / W, with barycentric numerators e1, e2 >= 0.
          const i128 num = i128(e1) * dzb + i128(e2) * dzc;
          const double depth = double(az) + double(num) * inv_w;
          // Node after the crossing: smallest K with depth <= K * 2^20, decided exactly.
          int64_t K = int64_t(std::ceil(depth * (1.0 / double(kUnit))));
          K = std::clamp<int64_t>(K, 0, na);
          auto at_or_before = [&](int64_t k) { return i128(k * kUnit - az) * i128(W) - num >= 0; };
          while (K > 0 && at_or_before(K - 1)) --K;
          while (K < na && !at_or_before(K)) ++K;
          const bool on_node = i128(K * kUnit - az) * i128(W) == num;
          const double t = on_node ? 1.0 : std::clamp(depth * (1.0 / double(kUnit)) - double(K - 1), 0.0, 1.0);
          const uint32_t key = uint32_t(U) * su + uint32_t(V) * sv + uint32_t(K) * sa;
          hits.push_back(Hit{key, float(t), on_node ? (tag | kOnNodeBit) : tag});
        }
        e0 += du[0];
        e1 += du[1];
        e2 += du[2];
      }
      row[0] += dv[0];
      row[1] += dv[1];
      row[2] += dv[2];
    }
  }
}

// Indices (ascending) of the triangles to rasterise: snapped vertices pairwise distinct, and
// the first of each group of same-winding duplicates (equal snapped vertices in equal cyclic order).
std::vector<uint32_t> active_triangles(const TriMesh& mesh, const std::vector<Fixed3>& q) {
  const uint32_t ntri = uint32_t(mesh.triangles.size());
  using Key = std::array<int64_t, 9>;
  auto key_of = [&](uint32_t ti) {
    const Tri& t = mesh.triangles[ti];
    int first = 0;
    for (int i = 1; i < 3; ++i) {
      if (q[t[i]] < q[t[first]]) first = i;
    }
    Key k;
    for (int i = 0; i < 3; ++i) {
      const Fixed3& p = q[t[(first + i) % 3]];
      k[3 * i] = p[0];
      k[3 * i + 1] = p[1];
      k[3 * i + 2] = p[2];
    }
    return k;
  };
  struct Entry {
    uint64_t hash;
    uint32_t tri;
  };
  std::vector<Entry> entries;
  entries.reserve(ntri);
  for (uint32_t ti = 0; ti < ntri; ++ti) {
    const Tri& t = mesh.triangles[ti];
    if (q[t[0]] == q[t[1]] || q[t[1]] == q[t[2]] || q[t[0]] == q[t[2]]) continue;
    const Key k = key_of(ti);
    uint64_t h = 0x9e3779b97f4a7c15ull;
    for (int64_t x : k) {
      h ^= uint64_t(x) + 0x9e3779b97f4a7c15ull + (h << 6) + (h >> 2);
      h *= 0xff51afd7ed558ccdull;
      h ^= h >> 33;
    }
    entries.push_back(Entry{h, ti});
  }
  std::sort(entries.begin(), entries.end(),
            [](const Entry& x, const Entry& y) { return x.hash != y.hash ? x.hash < y.hash : x.tri < y.tri; });
  std::vector<uint8_t> keep(ntri, 0);
  for (size_t i = 0; i < entries.size();) {
    size_t e = i + 1;
    while (e < entries.size() && entries[e].hash == entries[i].hash) ++e;
    if (e == i + 1) {
      keep[entries[i].tri] = 1;
    } else {
      for (size_t j = i; j < e; ++j) {
        const Key kj = key_of(entries[j].tri);
        bool dup = false;
        for (size_t l = i; l < j && !dup; ++l) dup = key_of(entries[l].tri) == kj;
        keep[entries[j].tri] = !dup;
      }
    }
    i = e;
  }
  std::vector<uint32_t> active;
  active.reserve(entries.size());
  for (uint32_t ti = 0; ti < ntri; ++ti) {
    if (keep[ti]) active.push_back(ti);
  }
  return active;
}

// Stable LSD radix sort of hits by key.
void sort_hits(std::vector<Hit>& hits, uint32_t max_key) {
  if (hits.size() < 2) return;
  constexpr int kDigit = 11;
  constexpr uint32_t kBuckets = 1u << kDigit;
  std::vector<Hit> tmp(hits.size());
  const int bits = std::bit_width(max_key);
  std::vector<uint32_t> count(kBuckets + 1);
  for (int shift = 0; shift < bits; shift += kDigit) {
    std::fill(count.begin(), count.end(), 0u);
    for (const Hit& h : hits) ++count[((h.key >> shift) & (kBuckets - 1)) + 1];
    if (count[((hits[0].key >> shift) & (kBuckets - 1)) + 1] == hits.size()) continue;  // one bucket
    for (uint32_t b = 0; b < kBuckets; ++b) count[b + 1] += count[b];
    for (const Hit& h : hits) tmp[count[(h.key >> shift) & (kBuckets - 1)]++] = h;
    hits.swap(tmp);
  }
}

// Appends bits to a bitset at an arbitrary bit offset.
struct BitWriter {
  uint64_t* out;
  uint64_t acc = 0;
  int nacc = 0;
  // nb in [1, 64]; no bits of `bits` above nb.
  void put(uint64_t bits, int nb) {
    acc |= bits << nacc;
    if (nacc + nb >= 64) {
      *out++ = acc;
      const int used = 64 - nacc;
      acc = used < 64 ? bits >> used : 0;
      nacc = nacc + nb - 64;
    } else {
      nacc += nb;
    }
  }
  void flush() {
    if (nacc > 0) *out++ = acc;
    acc = 0;
    nacc = 0;
  }
};

// Eight bytes holding 0/1 -> eight bits (byte i -> bit i).
inline uint64_t pack8(const uint8_t* m) {
  if constexpr (std::endian::native == std::endian::little) {
    uint64_t x;
    std::memcpy(&x, m, 8);
    return (x * 0x0102040810204080ull) >> 56;
  } else {
    uint64_t r = 0;
    for (int i = 0; i < 8; ++i) r |= uint64_t(m[i]) << i;
    return r;
  }
}

// Per-slice byte kernels (free functions with restrict pointers so they vectorise).
void keep_bits(uint8_t* __restrict b, uint32_t n, uint8_t mask) {
  for (uint32_t p = 0; p < n; ++p) b[p] &= mask;
}

void set_bit0(uint8_t* __restrict b, uint32_t s, uint32_t e) {
  for (uint32_t p = s; p < e; ++p) b[p] |= 1;
}

// Prefix xor of bit 1 along y: row j ^= row j-1.
void prefix_y(uint8_t* b, uint32_t R, int32_t ny) {
  for (int32_t j = 1; j <= ny; ++j) {
    uint8_t* __restrict row = b + uint32_t(j) * R;
    const uint8_t* __restrict prev = row - R;
    for (uint32_t i = 0; i < R; ++i) row[i] ^= uint8_t(prev[i] & 2);
  }
}

void majority3(const uint8_t* __restrict b, uint8_t* __restrict m, uint32_t n) {
  for (uint32_t p = 0; p < n; ++p) {
    const uint8_t x = b[p];
    m[p] = uint8_t(((x & (x >> 1)) | (x & (x >> 2)) | ((x >> 1) & (x >> 2))) & 1);
  }
}

// Voxels between two slices of signs with at least one inside corner.
uint64_t count_occupied(const uint8_t* __restrict lo, const uint8_t* __restrict hi, uint8_t* __restrict o,
                        uint32_t P, uint32_t R, int32_t nx, int32_t ny) {
  for (uint32_t p = 0; p < P; ++p) o[p] = uint8_t(lo[p] | hi[p]);
  uint64_t count = 0;
  for (int32_t j = 0; j < ny; ++j) {
    const uint8_t* __restrict r0 = o + uint32_t(j) * R;
    const uint8_t* __restrict r1 = r0 + R;
    uint32_t row_count = 0;
    for (int32_t i = 0; i < nx; ++i) row_count += uint32_t(r0[i] | r0[i + 1] | r1[i] | r1[i + 1]);
    count += row_count;
  }
  return count;
}

// Bit a of d[p]: the lattice edge from node p along axis a joins nodes of different sign.
void sign_changes(const uint8_t* __restrict m, const uint8_t* __restrict next, uint8_t* __restrict d,
                  uint32_t P, uint32_t R, int32_t nx, int32_t ny) {
  if (next) {
    for (uint32_t p = 0; p < P; ++p) d[p] = uint8_t((m[p] ^ next[p]) << 2);
  } else {
    for (uint32_t p = 0; p < P; ++p) d[p] = 0;
  }
  const size_t PR = size_t(P) - R;
  const uint8_t* __restrict mr = m + R;
  for (size_t p = 0; p < PR; ++p) d[p] |= uint8_t((m[p] ^ mr[p]) << 1);
  for (uint32_t p = 0; p + 1 < P; ++p) d[p] |= uint8_t(m[p] ^ m[p + 1]);
  for (int32_t j = 0; j <= ny; ++j) d[uint32_t(j) * R + uint32_t(nx)] &= uint8_t(~1u);  // no x edge at row end
}

// Node count of a lattice without overflow; false when it exceeds kMaxLatticeNodes.
bool checked_node_count(const Lattice& l, uint64_t& nodes) {
  if (l.nx < 1 || l.ny < 1 || l.nz < 1) return false;
  const unsigned __int128 n = (unsigned __int128)(uint64_t(l.nx) + 1) * (uint64_t(l.ny) + 1) *
                              (uint64_t(l.nz) + 1);
  if (n > kMaxLatticeNodes) return false;
  nodes = uint64_t(n);
  return true;
}

// The mesh's indices and used vertices are valid; else `error` says what is not.
bool check_mesh(const TriMesh& mesh, std::string& error) {
  const size_t nv = mesh.positions.size();
  const size_t ntri = mesh.triangles.size();
  if (ntri == 0) {
    error = "voxelize: the mesh has no triangles";
    return false;
  }
  if (ntri > size_t(kTriMask)) {
    error = "voxelize: too many triangles (" + std::to_string(ntri) + ")";
    return false;
  }
  for (size_t i = 0; i < ntri; ++i) {
    for (uint32_t vi : mesh.triangles[i]) {
      if (vi >= nv) {
        error = "voxelize: triangle " + std::to_string(i) + " references vertex " + std::to_string(vi) +
                " of " + std::to_string(nv);
        return false;
      }
      if (!mesh.positions[vi].allFinite()) {
        error = "voxelize: vertex " + std::to_string(vi) + " has a non-finite coordinate";
        return false;
      }
    }
  }
  return true;
}

// Fixed-point vertices in lattice units, clamped into the grid.
std::vector<Fixed3> snap_vertices(const TriMesh& mesh, const Lattice& L, const Grid& g) {
  std::vector<Fixed3> q(mesh.positions.size(), Fixed3{0, 0, 0});
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    const Vec3d& p = mesh.positions[i];
    if (!p.allFinite()) continue;  // unused (used ones were checked)
    for (int a = 0; a < 3; ++a) {
      const double x = (p[a] - L.origin[a]) / L.voxel_size * double(kUnit);
      const double hi = double(g.n[a] * kUnit);
      q[i][a] = std::llround(std::clamp(x, 0.0, hi));
    }
  }
  return q;
}

// The ray parities of slice k's nodes (bit a: the ray along axis a has crossed the surface an odd
// number of times before the node), from the sorted hits; `cursor` advances through each axis's
// hits slice by slice. The z bit carries over from the slice below.
void slice_parities(const std::array<std::vector<Hit>, 3>& hits, size_t cursor[3], uint32_t base, uint32_t P,
                    uint32_t R, int32_t ny, uint8_t* b) {
  const uint32_t end = base + P;
  keep_bits(b, P, 4);
  // z: toggle the nodes after each crossing of this slice.
  {
    const std::vector<Hit>& h = hits[2];
    size_t& c = cursor[2];
    for (; c < h.size() && h[c].key < end; ++c) b[h[c].key - base] ^= 4;
  }
  // y: toggles, then a prefix xor along y (rows of the slice).
  {
    const std::vector<Hit>& h = hits[1];
    size_t& c = cursor[1];
    for (; c < h.size() && h[c].key < end; ++c) b[h[c].key - base] ^= 2;
    prefix_y(b, R, ny);
  }
  // x: runs between consecutive crossings of a row (a row ends the run of an odd ray).
  const std::vector<Hit>& h = hits[0];
  size_t& c = cursor[0];
  bool on = false;
  uint32_t start = 0, row_end = 0;
  for (; c < h.size() && h[c].key < end; ++c) {
    const uint32_t p = h[c].key - base;
    if (on && p >= row_end) {
      set_bit0(b, start, row_end);
      on = false;
    }
    if (!on) {
      on = true;
      start = p;
      row_end = (p / R + 1) * R;
    } else {
      set_bit0(b, start, p);
      on = false;
    }
  }
  if (on) set_bit0(b, start, row_end);
}

// Appends a slice's inside flags (one byte per node, 0 or 1) to the bitset.
void pack_slice(const uint8_t* m, uint32_t P, BitWriter& writer) {
  uint32_t p = 0;
  for (; p + 64 <= P; p += 64) {
    uint64_t w = 0;
    for (int s = 0; s < 8; ++s) w |= pack8(m + p + 8 * s) << (8 * s);
    writer.put(w, 64);
  }
  if (p < P) {
    uint64_t w = 0;
    const int rem = int(P - p);
    for (int s = 0; s < rem; ++s) w |= uint64_t(m[p + uint32_t(s)]) << s;
    writer.put(w, rem);
  }
}

// The Hermite data of the lattice edges whose end nodes differ in sign: each edge's crossing (the hit
// nearest its middle) and the surface normal there, oriented outward. The cursors walk each axis's
// sorted hits in step with the slices.
struct CrossingWriter {
  const TriMesh& mesh;
  const Grid& g;
  const std::array<std::vector<Hit>, 3>& hits;
  std::vector<EdgeCrossing>& crossings;
  size_t end_cursor[3] = {0, 0, 0};    // into hits (the edge's end node)
  size_t first_cursor[3] = {0, 0, 0};  // into hits (the edge's first node)

  void emit(uint32_t node, int a, bool first_inside) {
    const uint32_t target = node + g.stride[a];  // the edge's end node = key of its hits
    const std::vector<Hit>& h = hits[a];
    size_t& c = end_cursor[a];
    while (c < h.size() && h[c].key < target) ++c;
    const Hit* best = nullptr;
    float best_d = 2.0f;
    for (size_t i = c; i < h.size() && h[i].key == target; ++i) {
      const float d = std::fabs(h[i].t - 0.5f);
      if (d < best_d) {
        best_d = d;
        best = &h[i];
      }
    }
    float t = best ? best->t : 0.5f;
    if (!best) {
      // The vote flipped a node that lies exactly on the surface: the ray's crossing sits on the
      // edge's first node (it belongs to the edge before by the half-open rule). Use it at t = 0.
      size_t& c0 = first_cursor[a];
      while (c0 < h.size() && h[c0].key < node) ++c0;
      for (size_t i = c0; i < h.size() && h[i].key == node; ++i) {
        if (h[i].tri & kOnNodeBit) {
          best = &h[i];
          t = 0.0f;
          break;
        }
      }
    }
    EdgeCrossing ec;
    ec.edge = 3u * node + uint32_t(a);
    ec.pad = 0;
    const double toward_out = first_inside ? 1.0 : -1.0;  // along +axis when the first node is inside
    Vec3d n = Vec3d::Zero();
    ec.t = t;
    if (best) {
      n = triangle_normal(mesh, best->tri & kTriMask);
      const double s = (best->tri & kNegBit) ? -1.0 : 1.0;  // sign of n[a] (exact, snapped)
      if (s != toward_out) n = -n;
    }  // else: the vote flipped a sign this ray did not see (t = 0.5, axis normal)
    if (n.squaredNorm() == 0.0) n[a] = toward_out;
    encode_normal(n, ec.normal);
    crossings.push_back(ec);
  }

  // Sign-change edges whose first node lies in slice kk (m: its signs; next: slice kk+1 or null).
  void slice_edges(int32_t kk, const uint8_t* m, const uint8_t* next, uint8_t* d, uint32_t P, uint32_t R,
                   int32_t nx, int32_t ny) {
    sign_changes(m, next, d, P, R, nx, ny);
    const uint32_t base = uint32_t(kk) * P;
    for (uint32_t p0 = 0; p0 < P; p0 += 8) {
      uint64_t w;
      std::memcpy(&w, d + p0, 8);
      if (w == 0) continue;
      const uint32_t pe = std::min(P, p0 + 8);
      for (uint32_t p = p0; p < pe; ++p) {
        const uint8_t bits = d[p];
        if (!bits) continue;
        for (int a = 0; a < 3; ++a) {
          if (bits & (1u << a)) emit(base + p, a, m[p] != 0);
        }
      }
    }
  }
};

bool run_voxelize(const TriMesh& mesh, const VoxelizeParams& params, VoxelModel* model,
                  std::vector<uint8_t>* parities, Lattice& lattice_out, std::string& error) {
  if (!check_mesh(mesh, error)) return false;
  Lattice L;
  if (!make_lattice(mesh_bounds(mesh), params.resolution, params.padding, L)) {
    error = "voxelize: no lattice (degenerate mesh box, resolution " + std::to_string(params.resolution) +
            " < 1 or padding " + std::to_string(params.padding) + " < 0)";
    return false;
  }
  uint64_t node_count = 0;
  if (!checked_node_count(L, node_count)) {
    error = "voxelize: lattice of " + std::to_string(L.nx) + "x" + std::to_string(L.ny) + "x" +
            std::to_string(L.nz) + " voxels has too many nodes to index with 32 bits";
    return false;
  }
  lattice_out = L;

  Grid g;
  g.n[0] = L.nx;
  g.n[1] = L.ny;
  g.n[2] = L.nz;
  const uint32_t R = uint32_t(L.nx) + 1;        // nodes per row (x)
  const uint32_t P = R * (uint32_t(L.ny) + 1);  // nodes per slice (x, y)
  g.stride[0] = 1;
  g.stride[1] = R;
  g.stride[2] = P;

  // 1. Fixed-point vertices. Triangles that can contribute: not degenerate after snapping, and not a
  // same-winding duplicate of an earlier triangle (a double-covered surface would cancel its own
  // parity). Opposite-winding duplicates are kept: they are internal walls (two solids sharing a
  // face) and cancel on purpose.
  std::vector<Fixed3> q = snap_vertices(mesh, L, g);
  std::vector<uint32_t> active = active_triangles(mesh, q);

  // 2-3. Hits per axis, sorted by key.
  std::array<std::vector<Hit>, 3> hits;
  const bool small = std::max({g.n[0], g.n[1], g.n[2]}) <= kMaxAxisForInt64;
  for (int a = 0; a < 3; ++a) {
    if (small) {
      raster_axis<int64_t>(a, mesh, q, active, g, hits[a]);
    } else {
      raster_axis<i128>(a, mesh, q, active, g, hits[a]);
    }
    sort_hits(hits[a], uint32_t(node_count - 1));
  }
  std::vector<Fixed3>().swap(q);
  std::vector<uint32_t>().swap(active);

  // 4. Slice sweep: parities, the majority vote, the inside bitset, the occupied voxels and the
  // crossings of the edges between this slice and the one below.
  std::vector<uint64_t> inside((node_count + 63) / 64, 0);
  std::vector<EdgeCrossing> crossings;
  crossings.reserve(hits[0].size() + hits[1].size() + hits[2].size());
  if (parities) parities->assign(node_count, 0);
  constexpr size_t kPad = 8;  // lets the diff scan read 8 bytes at a time
  std::vector<uint8_t> buf(P + kPad, 0), maj_prev(P + kPad, 0), maj_cur(P + kPad, 0), diff(P + kPad, 0),
      occ(P + kPad, 0);
  BitWriter writer{inside.data()};
  CrossingWriter edges{mesh, g, hits, crossings};
  size_t cursor[3] = {0, 0, 0};  // sign pass cursors into hits
  uint64_t occupied = 0;
  for (int32_t k = 0; k <= L.nz; ++k) {
    const uint32_t base = uint32_t(k) * P;
    slice_parities(hits, cursor, base, P, R, L.ny, buf.data());
    if (parities) std::memcpy(parities->data() + base, buf.data(), P);
    uint8_t* m = maj_cur.data();
    majority3(buf.data(), m, P);
    pack_slice(m, P, writer);
    if (k > 0) {
      // Occupied voxels of layer k-1: any of the 8 corners inside.
      occupied += count_occupied(maj_prev.data(), m, occ.data(), P, R, L.nx, L.ny);
      edges.slice_edges(k - 1, maj_prev.data(), m, diff.data(), P, R, L.nx, L.ny);
    }
    maj_prev.swap(maj_cur);
  }
  edges.slice_edges(L.nz, maj_prev.data(), nullptr, diff.data(), P, R, L.nx, L.ny);
  writer.flush();

  for (std::vector<Hit>& h : hits) std::vector<Hit>().swap(h);
  if (model) {
    if (crossings.capacity() > crossings.size()) crossings.shrink_to_fit();
    model->lattice = L;
    model->inside = std::move(inside);
    model->crossings = std::move(crossings);
    model->index_crossings();
    model->occupied_voxels = uint32_t(occupied);
  }
  return true;
}

}  // namespace

uint64_t estimate_voxelize_bytes(const Aabb& box, uint64_t triangle_count, const VoxelizeParams& params) {
  Lattice L;
  if (!make_lattice(box, params.resolution, params.padding, L)) return 0;
  uint64_t nodes = 0;
  if (!checked_node_count(L, nodes)) return UINT64_MAX;
  const uint64_t nx1 = uint64_t(L.nx) + 1, ny1 = uint64_t(L.ny) + 1, nz1 = uint64_t(L.nz) + 1;
  const uint64_t slice = nx1 * ny1;
  // Hits: up to four surface layers over each axis' cross-section, plus one per triangle.
  const uint64_t hits = 4 * (ny1 * nz1 + nz1 * nx1 + nx1 * ny1) + triangle_count;
  // Peak during the sweep: inside bitset, hits (vector growth slack up to 2x), crossings
  // (about one per hit, up to 2x growth), slice buffers; the vertex and triangle arrays of the
  // raster phase are counted on top to stay conservative.
  uint64_t bytes = 0;
  bytes += (nodes + 63) / 64 * 8;
  bytes += 5 * (slice + 8);
  bytes += hits * (2 * sizeof(Hit) + 2 * sizeof(EdgeCrossing));
  bytes += triangle_count * (3 * sizeof(Fixed3) + 16 + 4 + 1);
  bytes += (ny1 * nz1 + 1) * sizeof(uint32_t);  // VoxelModel::crossing_rows
  bytes += sizeof(VoxelModel);
  return bytes;
}

bool voxelize(const TriMesh& mesh, const VoxelizeParams& params, VoxelModel& out, std::string& error) {
  VoxelModel model;
  Lattice lattice;
  if (!run_voxelize(mesh, params, &model, nullptr, lattice, error)) return false;
  out = std::move(model);
  return true;
}

bool voxelize_parities(const TriMesh& mesh, const VoxelizeParams& params, Lattice& lattice,
                       std::vector<uint8_t>& parities, std::string& error) {
  return run_voxelize(mesh, params, nullptr, &parities, lattice, error);
}

}  // namespace dvx
