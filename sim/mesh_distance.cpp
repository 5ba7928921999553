#include "sim/mesh_distance.h"

#include "sim/random.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <limits>

namespace dvx {

namespace {

constexpr uint32_t kLeafSize = 4;
// Deeper than any median-split tree over 2^32 triangles can be (one far child pushed per level).
constexpr int kStackSize = 64;

// Squared distance from p to a box (0 inside).
inline double box_distance2(const Aabb& box, const Vec3d& p) {
  double d2 = 0.0;
  for (int a = 0; a < 3; ++a) {
    const double lo = box.min[a] - p[a];
    const double hi = p[a] - box.max[a];
    const double d = lo > 0.0 ? lo : (hi > 0.0 ? hi : 0.0);
    d2 += d * d;
  }
  return d2;
}

// Closest point on segment [a, b]; a zero-length segment gives a.
inline Vec3d closest_point_on_segment(const Vec3d& p, const Vec3d& a, const Vec3d& b) {
  const Vec3d ab = b - a;
  const double len2 = ab.squaredNorm();
  if (!(len2 > 0.0)) return a;
  const double t = std::clamp((p - a).dot(ab) / len2, 0.0, 1.0);
  return a + t * ab;
}

// Fallback for slivers, needles and degenerate triangles, where Ericson's region tests
// (differences of products of dot products) lose every significant digit: the nearest of the
// three edges and, when the triangle has a normal, the plane projection if it falls inside.
Vec3d closest_point_robust(const Vec3d& p, const Vec3d& a, const Vec3d& b, const Vec3d& c) {
  Vec3d best = closest_point_on_segment(p, a, b);
  double best2 = (p - best).squaredNorm();
  for (const Vec3d& q : {closest_point_on_segment(p, b, c), closest_point_on_segment(p, c, a)}) {
    const double d2 = (p - q).squaredNorm();
    if (d2 < best2) {
      best2 = d2;
      best = q;
    }
  }
  const Vec3d n = (b - a).cross(c - a);
  const double n2 = n.squaredNorm();
  if (n2 > 0.0 && std::isfinite(n2)) {
    const Vec3d q = p - n * ((p - a).dot(n) / n2);
    const bool inside = (b - a).cross(q - a).dot(n) >= 0.0 && (c - b).cross(q - b).dot(n) >= 0.0 &&
                        (a - c).cross(q - c).dot(n) >= 0.0;
    if (inside && q.allFinite() && (p - q).squaredNorm() < best2) best = q;
  }
  return best;
}


// Marks the vertices that triangles use (unreferenced positions are not part of the surface).
std::vector<uint32_t> used_vertices(const TriMesh& mesh) {
  std::vector<uint8_t> used(mesh.positions.size(), 0);
  for (const Tri& t : mesh.triangles)
    for (uint32_t v : t) used[v] = 1;
  std::vector<uint32_t> out;
  for (uint32_t v = 0; v < used.size(); ++v)
    if (used[v]) out.push_back(v);
  return out;
}

}  // namespace

TriangleBvh build_bvh(const TriMesh& mesh) {
  TriangleBvh bvh;
  bvh.mesh = &mesh;
  const uint32_t ntris = static_cast<uint32_t>(mesh.triangles.size());
  if (ntris == 0) return bvh;

  // Per-triangle boxes and centroids (centroids decide the split, boxes the node bounds).
  std::vector<Aabb> tri_box(ntris);
  std::vector<Vec3d> centroid(ntris);
  for (uint32_t t = 0; t < ntris; ++t) {
    const Tri& tri = mesh.triangles[t];
    Aabb b;
    for (uint32_t v : tri) b.grow(mesh.positions[v]);
    tri_box[t] = b;
    centroid[t] = (mesh.positions[tri[0]] + mesh.positions[tri[1]] + mesh.positions[tri[2]]) / 3.0;
  }
  bvh.order.resize(ntris);
  for (uint32_t t = 0; t < ntris; ++t) bvh.order[t] = t;
  bvh.nodes.reserve(2 * ((ntris + kLeafSize - 1) / kLeafSize));

  // Work list of nodes still to split; children are appended in pairs (right = left + 1).
  struct Pending {
    uint32_t node, begin, end;
  };
  std::vector<Pending> work;
  bvh.nodes.push_back({});
  work.push_back({0, 0, ntris});
  while (!work.empty()) {
    const Pending w = work.back();
    work.pop_back();
    // Node box and centroid box over this range.
    Aabb box, cbox;
    for (uint32_t i = w.begin; i < w.end; ++i) {
      const uint32_t t = bvh.order[i];
      box.grow(tri_box[t].min);
      box.grow(tri_box[t].max);
      cbox.grow(centroid[t]);
    }
    bvh.nodes[w.node].box = box;
    const uint32_t count = w.end - w.begin;
    if (count <= kLeafSize) {
      // Leaf: sort by id so the leaf order does not depend on the standard library's partition.
      std::sort(bvh.order.begin() + w.begin, bvh.order.begin() + w.end);
      bvh.nodes[w.node].first = w.begin;
      bvh.nodes[w.node].count = count;
      continue;
    }
    // Median split on the longest axis of the centroid box; ties broken by triangle id so the
    // two halves are the same sets everywhere (strict total order).
    const Vec3d ext = cbox.extent();
    int axis = 0;
    if (ext[1] > ext[axis]) axis = 1;
    if (ext[2] > ext[axis]) axis = 2;
    const uint32_t mid = w.begin + count / 2;
    std::nth_element(bvh.order.begin() + w.begin, bvh.order.begin() + mid, bvh.order.begin() + w.end,
                     [&](uint32_t x, uint32_t y) {
                       const double cx = centroid[x][axis], cy = centroid[y][axis];
                       return cx < cy || (cx == cy && x < y);
                     });
    const uint32_t left = static_cast<uint32_t>(bvh.nodes.size());
    bvh.nodes.push_back({});
    bvh.nodes.push_back({});
    bvh.nodes[w.node].first = left;
    bvh.nodes[w.node].count = 0;
    // Push right first so the left subtree is built first (only affects build order, not the tree).
    work.push_back({left + 1, mid, w.end});
    work.push_back({left, w.begin, mid});
  }
  return bvh;
}

Vec3d closest_point_on_triangle(const Vec3d& p, const Vec3d& a, const Vec3d& b, const Vec3d& c) {
  // Ericson, RTCD 5.1.5: classify p into a Voronoi region of the triangle. Only for
  // well-shaped triangles: when the smallest angle has sin < 1e-4 (2 * area against the two
  // longest edges) the robust path is taken instead.
  const Vec3d ab = b - a;
  const Vec3d ac = c - a;
  {
    const double lab = ab.squaredNorm(), lac = ac.squaredNorm(), lbc = (c - b).squaredNorm();
    const double scale = std::max({lab * lac, lab * lbc, lac * lbc});
    if (!(ab.cross(ac).squaredNorm() > 1e-8 * scale)) return closest_point_robust(p, a, b, c);
  }
  const Vec3d ap = p - a;
  // Vertex region A.
  const double d1 = ab.dot(ap);
  const double d2 = ac.dot(ap);
  if (d1 <= 0.0 && d2 <= 0.0) return a;
  // Vertex region B.
  const Vec3d bp = p - b;
  const double d3 = ab.dot(bp);
  const double d4 = ac.dot(bp);
  if (d3 >= 0.0 && d4 <= d3) return b;
  // Edge region AB (the denominator vanishes only for degenerate triangles: fall back).
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
    const double den = d1 - d3;
    if (!(den > 0.0)) return closest_point_robust(p, a, b, c);
    return a + (d1 / den) * ab;
  }
  // Vertex region C.
  const Vec3d cp = p - c;
  const double d5 = ab.dot(cp);
  const double d6 = ac.dot(cp);
  if (d6 >= 0.0 && d5 <= d6) return c;
  // Edge region AC.
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
    const double den = d2 - d6;
    if (!(den > 0.0)) return closest_point_robust(p, a, b, c);
    return a + (d2 / den) * ac;
  }
  // Edge region BC.
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
    const double den = (d4 - d3) + (d5 - d6);
    if (!(den > 0.0)) return closest_point_robust(p, a, b, c);
    return b + ((d4 - d3) / den) * (c - b);
  }
  // Face region: barycentric (u, v, w) = (va, vb, vc) / sum; the sum is 0 only when degenerate.
  const double sum = va + vb + vc;
  if (!(sum > 0.0) || !std::isfinite(sum)) return closest_point_robust(p, a, b, c);
  const double v = vb / sum;
  const double w = vc / sum;
  const Vec3d q = a + ab * v + ac * w;
  if (!q.allFinite()) return closest_point_robust(p, a, b, c);
  return q;
}

namespace {

// Traversal shared by closest_point and the batched queries: `hint` (a triangle id, or
// UINT32_MAX) gives a starting upper bound; writes the winning triangle to *tri_out.
// Returns the squared distance.
double closest_point_impl(const TriangleBvh& bvh, const Vec3d& p, uint32_t hint, Vec3d* closest,
                          uint32_t* tri_out) {
  const TriMesh& mesh = *bvh.mesh;
  double best2 = std::numeric_limits<double>::infinity();
  Vec3d best_point = Vec3d::Constant(std::numeric_limits<double>::quiet_NaN());
  uint32_t best_tri = UINT32_MAX;
  if (hint < mesh.triangles.size()) {
    const Tri& t = mesh.triangles[hint];
    best_point = closest_point_on_triangle(p, mesh.positions[t[0]], mesh.positions[t[1]], mesh.positions[t[2]]);
    best2 = (best_point - p).squaredNorm();
    best_tri = hint;
  }

  // Iterative depth-first traversal: nodes with their box distance, near child visited first,
  // anything no nearer than the best so far pruned.
  struct Entry {
    uint32_t node;
    double d2;
  };
  Entry stack[kStackSize];
  int top = 0;
  stack[top++] = {0, box_distance2(bvh.nodes[0].box, p)};
  while (top > 0) {
    const Entry e = stack[--top];
    if (e.d2 >= best2) continue;
    const TriangleBvh::Node& node = bvh.nodes[e.node];
    if (node.count > 0) {
      // Leaf: exact distance to each triangle.
      for (uint32_t i = node.first; i < node.first + node.count; ++i) {
        const uint32_t id = bvh.order[i];
        const Tri& t = mesh.triangles[id];
        const Vec3d q = closest_point_on_triangle(p, mesh.positions[t[0]], mesh.positions[t[1]],
                                                  mesh.positions[t[2]]);
        const double d2 = (q - p).squaredNorm();
        if (d2 < best2) {
          best2 = d2;
          best_point = q;
          best_tri = id;
        }
      }
      continue;
    }
    // Inner: push the far child first so the near one is popped next.
    const uint32_t l = node.first, r = node.first + 1;
    const double dl = box_distance2(bvh.nodes[l].box, p);
    const double dr = box_distance2(bvh.nodes[r].box, p);
    const bool left_near = dl <= dr;
    const Entry near_e = left_near ? Entry{l, dl} : Entry{r, dr};
    const Entry far_e = left_near ? Entry{r, dr} : Entry{l, dl};
    if (far_e.d2 < best2 && top < kStackSize) stack[top++] = far_e;
    if (near_e.d2 < best2 && top < kStackSize) stack[top++] = near_e;
  }
  if (closest) *closest = best_point;
  if (tri_out) *tri_out = best_tri;
  return best2;
}

}  // namespace

double closest_point(const TriangleBvh& bvh, const Vec3d& p, Vec3d* closest) {
  if (bvh.nodes.empty() || bvh.mesh == nullptr) return std::numeric_limits<double>::infinity();
  return std::sqrt(closest_point_impl(bvh, p, UINT32_MAX, closest, nullptr));
}

std::vector<Vec3d> sample_surface(const TriMesh& mesh, uint64_t count, uint64_t seed) {
  std::vector<Vec3d> out;
  const size_t ntris = mesh.triangles.size();
  if (ntris == 0 || count == 0) return out;

  // Cumulative triangle areas (a zero-area triangle never owns an interval).
  std::vector<double> cumulative(ntris);
  double total = 0.0;
  size_t last_positive = 0;
  for (size_t t = 0; t < ntris; ++t) {
    const Tri& tri = mesh.triangles[t];
    const Vec3d& a = mesh.positions[tri[0]];
    const double area = 0.5 * (mesh.positions[tri[1]] - a).cross(mesh.positions[tri[2]] - a).norm();
    if (area > 0.0 && std::isfinite(area)) {
      total += area;
      last_positive = t;
    }
    cumulative[t] = total;
  }

  // Each sample: a triangle by binary search on area, then a uniform point in it
  // (square-root warp of two uniforms). Without any area, triangles are picked uniformly.
  SplitMix64 rng{seed};
  out.reserve(count);
  for (uint64_t s = 0; s < count; ++s) {
    const double u0 = rng.uniform();
    size_t t;
    if (total > 0.0) {
      const double r = u0 * total;
      t = static_cast<size_t>(std::upper_bound(cumulative.begin(), cumulative.end(), r) - cumulative.begin());
      if (t >= ntris) t = last_positive;  // r rounded up to the total
    } else {
      t = std::min(static_cast<size_t>(u0 * static_cast<double>(ntris)), ntris - 1);
    }
    const double su = std::sqrt(rng.uniform());
    const double v = rng.uniform();
    const Tri& tri = mesh.triangles[t];
    const Vec3d& a = mesh.positions[tri[0]];
    const Vec3d& b = mesh.positions[tri[1]];
    const Vec3d& c = mesh.positions[tri[2]];
    out.push_back((1.0 - su) * a + (su * (1.0 - v)) * b + (su * v) * c);
  }
  return out;
}

namespace {

// Spreads the low 21 bits of x to every third bit (for 63-bit Morton codes).
inline uint64_t spread_bits(uint64_t x) {
  x &= 0x1FFFFFull;
  x = (x | (x << 32)) & 0x1F00000000FFFFull;
  x = (x | (x << 16)) & 0x1F0000FF0000FFull;
  x = (x | (x << 8)) & 0x100F00F00F00F00Full;
  x = (x | (x << 4)) & 0x10C30C30C30C30C3ull;
  x = (x | (x << 2)) & 0x1249249249249249ull;
  return x;
}

// Distance sums of one kind of query point.
struct Accum {
  double max = 0.0, sum = 0.0, sum2 = 0.0;
  uint64_t n = 0;
  void add(double d) {
    max = std::max(max, d);
    sum += d;
    sum2 += d * d;
    ++n;
  }
};

// Distances from `samples` and then `vertices` (ids into `from`) to the tree. Queries run in
// Morton order of the points so consecutive ones are close: each starts from the previous
// winner's triangle as an upper bound (and the tree stays in cache). Ties in the order are
// broken by index, so the summation order (hence the result) is the same everywhere.
void distances_to(const TriangleBvh& bvh, const std::vector<Vec3d>& samples, const TriMesh& from,
                  const std::vector<uint32_t>& vertices, Accum& area, Accum& vert) {
  const uint32_t ns = static_cast<uint32_t>(samples.size());
  const uint32_t n = ns + static_cast<uint32_t>(vertices.size());
  auto point = [&](uint32_t i) -> const Vec3d& { return i < ns ? samples[i] : from.positions[vertices[i - ns]]; };
  Aabb box;
  for (uint32_t i = 0; i < n; ++i) box.grow(point(i));
  const Vec3d ext = box.extent();
  const double scale = 2097151.0 / std::max({ext.x(), ext.y(), ext.z(), 1e-300});
  // (code, index) pairs sorted: a strict total order, so std::sort's result is unique.
  std::vector<std::pair<uint64_t, uint32_t>> keys(n);
  for (uint32_t i = 0; i < n; ++i) {
    const Vec3d q = ((point(i) - box.min) * scale).cwiseMax(0.0).cwiseMin(2097151.0);
    if (!q.allFinite()) {
      keys[i] = {0, i};
      continue;
    }
    keys[i] = {spread_bits(static_cast<uint64_t>(q.x())) | (spread_bits(static_cast<uint64_t>(q.y())) << 1) |
                   (spread_bits(static_cast<uint64_t>(q.z())) << 2),
               i};
  }
  std::sort(keys.begin(), keys.end());
  uint32_t hint = UINT32_MAX;
  for (const auto& [code, i] : keys) {
    const double d = std::sqrt(closest_point_impl(bvh, point(i), hint, nullptr, &hint));
    (i < ns ? area : vert).add(d);
  }
}

}  // namespace

// max: over the area samples of both sides and every used vertex of both meshes.
// mean / rms / samples: over the area samples of both sides only (area-weighted estimates;
// vertices would bias them towards finely tessellated regions). Without area samples the
// vertices stand in for them. One mesh empty and the other not: every statistic is +inf.
ErrorStats two_sided_error(const TriMesh& a, const TriMesh& b, uint64_t samples_per_side, uint64_t seed) {
  ErrorStats stats;
  const bool a_empty = a.triangles.empty(), b_empty = b.triangles.empty();
  if (a_empty && b_empty) return stats;
  if (a_empty || b_empty) {
    const double inf = std::numeric_limits<double>::infinity();
    stats.max = stats.mean = stats.rms = inf;
    return stats;
  }
  const TriangleBvh bvh_a = build_bvh(a);
  const TriangleBvh bvh_b = build_bvh(b);
  // Different streams per side (so a == b does not sample the same points twice).
  const std::vector<Vec3d> samples_a = sample_surface(a, samples_per_side, seed);
  const std::vector<Vec3d> samples_b = sample_surface(b, samples_per_side, seed ^ 0xA5A5A5A5DEADBEEFull);

  // a against b, then b against a, pooled.
  Accum area, vert;
  distances_to(bvh_b, samples_a, a, used_vertices(a), area, vert);
  distances_to(bvh_a, samples_b, b, used_vertices(b), area, vert);

  stats.max = std::max(area.max, vert.max);
  const Accum& avg = area.n > 0 ? area : vert;
  stats.samples = avg.n;
  if (avg.n > 0) {
    stats.mean = avg.sum / static_cast<double>(avg.n);
    stats.rms = std::sqrt(avg.sum2 / static_cast<double>(avg.n));
  }
  return stats;
}

}  // namespace dvx
