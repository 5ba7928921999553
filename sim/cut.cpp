#include "sim/cut.h"
#include "sim/cut_internal.h"

#include "sim/surface_metrics.h"
#include "sim/union_find.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <numbers>
#include <bit>

namespace dvx {

using namespace cut_internal;

namespace {

// The same for a vector whose first `sorted` elements are sorted and unique already (the pending
// voxels of earlier cut_divide calls in a step, one call per rest quad): the tail is sorted, its
// repeats and the values the prefix holds already (binary search) dropped, and only a tail left
// non-empty is merged: O(tail log n), plus O(n) when the tail brings new values. Mostly it brings
// none (a rest quad's voxels are pending from its neighbours), so the step's many calls stay cheap.
void merge_sorted_unique(std::vector<uint32_t>& v, size_t sorted) {
  if (v.size() == sorted) return;
  const auto prefix_end = v.begin() + std::ptrdiff_t(sorted);
  std::sort(prefix_end, v.end());
  size_t kept = sorted;
  for (size_t i = sorted; i < v.size(); ++i) {
    const uint32_t x = v[i];
    if ((kept > sorted && v[kept - 1] == x) || std::binary_search(v.begin(), prefix_end, x)) continue;
    v[kept++] = x;
  }
  v.resize(kept);
  if (kept == sorted || sorted == 0 || v[sorted - 1] < v[sorted]) return;
  std::inplace_merge(v.begin(), v.begin() + std::ptrdiff_t(sorted), v.end());
}

// Pieces of a voxel with its partial mask (uncut voxels: one implicit piece, never partial).
void pieces_of(const VoxelModel& model, const CutState& state, uint32_t voxel, uint8_t corner_piece[8],
               uint8_t& piece_count, uint8_t& partial_mask) {
  const uint32_t d = state.divided_of.get(voxel);
  if (d != kDeadIndex) {
    const DividedVoxel& dv = state.divided[d];
    std::copy(dv.corner_piece, dv.corner_piece + 8, corner_piece);
    piece_count = dv.piece_count;
    partial_mask = dv.partial_mask;
    return;
  }
  int32_t vc[3];
  model.lattice.voxel_coords(voxel, vc);
  piece_count = 0;
  partial_mask = 0;
  for (int c = 0; c < 8; ++c) {
    corner_piece[c] = model.is_inside(corner_node(model.lattice, vc, c)) ? 0 : kNoPiece;
    if (corner_piece[c] == 0) piece_count = 1;
  }
}

}  // namespace

// ---- Public API ----------------------------------------------------------------------------

bool half_edge(const VoxelModel& model, const CutState& state, uint32_t edge, int side, Vec3d& point,
               Vec3d& normal) {
  double t = 0.0;
  if (!half_edge_param(model, find_cut(state, edge), edge, side, t, normal)) return false;
  const Lattice& l = model.lattice;
  int32_t c[3];
  l.node_coords(edge / 3, c);
  point = l.node_position(c[0], c[1], c[2]);
  point[edge % 3] += t * l.voxel_size;
  return true;
}

bool half_edge_sharing(const VoxelModel& model, const CutState& state, uint32_t edge, int side,
                       uint32_t voxels[4], uint8_t pieces[4]) {
  uint8_t lower_corner[4];
  voxels_around_edge(model.lattice, edge, voxels, lower_corner);
  uint32_t divided[4];
  divided_around(state, voxels, divided);
  return sharing_pieces(model, state, edge, side, voxels, lower_corner, divided, pieces);
}

bool sharing_pieces(const VoxelModel& model, const CutState& state, uint32_t edge, int side,
                    const uint32_t voxels[4], const uint8_t lower_corner[4], const uint32_t divided[4],
                    uint8_t pieces[4]) {
  const int axis = int(edge % 3);
  const uint32_t node = side ? edge / 3 + node_stride(model.lattice, axis) : edge / 3;
  const bool node_inside = model.is_inside(node);
  for (int q = 0; q < 4; ++q) {
    if (voxels[q] == kDeadIndex) return false;
    // Uncut voxels are one piece of all their inside corners; divided ones say which piece.
    const uint32_t d = divided[q];
    const int corner = side ? (lower_corner[q] | (1 << axis)) : lower_corner[q];
    pieces[q] = d == kDeadIndex ? (node_inside ? 0 : kNoPiece) : state.divided[d].corner_piece[corner];
    if (pieces[q] == kNoPiece) return false;
  }
  return true;
}

void voxel_pieces(const VoxelModel& model, const CutState& state, uint32_t voxel, uint8_t corner_piece[8],
                  uint8_t& piece_count) {
  uint8_t partial = 0;
  pieces_of(model, state, voxel, corner_piece, piece_count, partial);
}

const uint8_t kVoxelFaceCorners[6][4] = {{0, 2, 6, 4}, {1, 3, 7, 5}, {0, 4, 5, 1},
                                         {2, 6, 7, 3}, {0, 1, 3, 2}, {4, 5, 7, 6}};

uint8_t voxel_material_joins(uint8_t corner_inside, uint16_t cut_edges) {
  uint8_t faces = 0;
  for (int f = 0; f < 6; ++f) {
    const uint8_t* k = kVoxelFaceCorners[f];
    const bool i0 = (corner_inside >> k[0]) & 1u, i1 = (corner_inside >> k[1]) & 1u;
    const bool i2 = (corner_inside >> k[2]) & 1u, i3 = (corner_inside >> k[3]) & 1u;
    const bool ambiguous = i0 == i2 && i1 == i3 && i0 != i1;
    if (ambiguous && (cut_edges & kFaceEdges.mask[f]) == 0) faces = uint8_t(faces | (1u << f));
  }
  return faces;
}

void init_cut_state(const VoxelModel& model, CutState& state, const ContourParams& params, const TaskRunner& tasks) {
  state = CutState{};
  state.contour = params;
  state.lattice = model.lattice;
  // Every voxel around a sign-change edge holds a surface vertex.
  // (marked in a bitset and read back in order: no sort of four entries per crossing).
  std::vector<uint64_t> marked((model.lattice.voxel_count() + 63) / 64, 0);
  for (const EdgeCrossing& c : model.crossings) {
    uint32_t around[4];
    uint8_t corners[4];
    voxels_around_edge(model.lattice, c.edge, around, corners);
    for (uint32_t v : around) {
      if (v != kDeadIndex) marked[v >> 6] |= uint64_t(1) << (v & 63);
    }
  }
  std::vector<uint32_t> voxels;
  voxels.reserve(model.crossings.size() * 2);
  for (size_t w = 0; w < marked.size(); ++w) {
    for (uint64_t bits = marked[w]; bits; bits &= bits - 1) voxels.push_back(uint32_t(64 * w) + uint32_t(std::countr_zero(bits)));
  }
  // Headroom for cuts, so a step rarely pays for growing a table (a p99 spike otherwise). The maps
  // are written across their whole table, so their headroom is memory: 1.5 times the surface. The
  // arrays are written only up to their size, and their untouched capacity is address space, not
  // memory (its pages are mapped as the surface grows into them, a few a step): 4 times the surface.
  // At 1.5 times, four through-cuts of the bunny at 256 outgrew them in one step of 30 ms (a copy
  // of every slot of eight arrays into fresh pages, and the embedding's arrays with them).
  const uint32_t vertices = uint32_t(voxels.size()), quads = uint32_t(model.crossings.size());
  state.surface.vertex_of_patch.reserve(vertices + vertices / 2 + 1024);
  state.surface.quad_of_half_edge.reserve(quads + quads / 2 + 1024);
  const size_t vertex_slots = 4 * size_t(vertices) + 1024, quad_slots = 4 * size_t(quads) + 1024;
  state.surface.positions.reserve(vertex_slots);
  state.surface.vertex_piece.reserve(vertex_slots);
  state.surface.vertex_patch.reserve(vertex_slots);
  state.surface.vertex_half_edges.reserve(vertex_slots);
  state.surface.quad_half_edge.reserve(quad_slots);
  state.surface.triangles.reserve(2 * quad_slots);
  state.surface.triangle_cut.reserve(2 * quad_slots);
  // The cut's maps and the arrays they index start at about two cross-sections of the model (1/8
  // of its surface vertices): a rehash or a reallocation inside a cut step copies the whole map or
  // array into fresh pages (a p99 spike: at 512 the edge cuts' array doubling at 65 536 cost 8 ms in
  // the bunny, 579 page faults, and the liver's cut, larger than 1/32 of its vertices, rehashed
  // its maps and doubled its arrays in four steps of 10-26 ms; at 256 one planar cut across the
  // armadillo along z divides 17 800 voxels, a ninth of its 161 000 surface vertices, and 1/16
  // rehashed the divided voxels' and the edge cuts' maps in its two slowest steps, +0.17 ms each).
  const uint32_t cut_expected = vertices / 8 + 1024;
  state.edge_cut_of.reserve(cut_expected);
  state.divided_of.reserve(cut_expected);
  state.front_of.reserve(cut_expected);
  state.edge_cuts.reserve(state.edge_cut_of.capacity());
  state.divided.reserve(state.divided_of.capacity());
  state.fronts.reserve(state.front_of.capacity());

  CutStepStats stats;
  refresh_voxels(model, state, voxels, stats, nullptr, nullptr, tasks);  // the whole surface is new: no list of changes
  state.surface.clear_dirty();
}

namespace {

// Records one crossed edge's cut and queues the voxels around it for dividing (new divided voxels
// start with the pieces of the uncut voxel; the reshaped list keeps their pieces before the step).
void divide_at(const VoxelModel& model, CutState& state, const EdgeHit& hit, CutStepStats& stats) {
  const Lattice& l = model.lattice;
  std::vector<uint32_t>& voxels = state.pending_voxels;
  const EdgeChange change = record_cut(model, state, hit);
  if (change == EdgeChange::kNone) return;
  stats.edges_cut += change == EdgeChange::kCut;
  uint32_t around[4];
  uint8_t corners[4];
  voxels_around_edge(l, hit.edge, around, corners);
  const int axis = int(hit.edge % 3);
  for (int q = 0; q < 4; ++q) {
    const uint32_t v = around[q];
    if (v == kDeadIndex) continue;
    voxels.push_back(v);
    uint32_t d = state.divided_of.get(v);
    if (d == kDeadIndex) {
      d = uint32_t(state.divided.size());
      state.divided_of.set(v, d);
      DividedVoxel dv{};
      dv.voxel = v;
      dv.piece_count = 8;  // unknown until refreshed: visit every piece slot once
      // Its pieces until refreshed: those of the uncut voxel (one of all inside corners).
      int32_t vc[3];
      l.voxel_coords(v, vc);
      const uint8_t inside = corner_inside_bits(model, vc);
      for (int c = 0; c < 8; ++c) dv.corner_piece[c] = (inside >> c) & 1u ? 0 : kNoPiece;
      state.divided.push_back(dv);
    }
    const uint16_t bit = uint16_t(1u << voxel_edge_index(axis, corners[q]));
    DividedVoxel& dv = state.divided[d];
    uint16_t& edges = change == EdgeChange::kCut ? dv.cut_edges : dv.air_edges;
    if (!(edges & bit)) {
      // Its pieces before the step (not refreshed yet within it), 4 bits per corner.
      uint32_t before = 0;
      for (int c = 0; c < 8; ++c) before |= uint32_t(dv.corner_piece[c] == kNoPiece ? 0xF : dv.corner_piece[c] & 7) << (4 * c);
      state.pending_reshaped.push_back(uint64_t(v) << 32 | before);
    }
    edges |= bit;
  }
}

}  // namespace

void cut_divide(const VoxelModel& model, CutState& state, const BladePose& from, const BladePose& to,
                CutStepStats& stats) {
  const Lattice& l = model.lattice;

  // Edges the swept quad crosses.
  std::vector<EdgeHit>& hits = state.scratch.hits;
  hits.clear();
  sweep_edge_hits(l, from, to, hits);
  stats.edges_hit = uint32_t(hits.size());

  // Divide: record the cuts; the voxels around each changed edge are (re)divided.
  std::vector<uint32_t>& voxels = state.pending_voxels;
  const size_t pending_before = voxels.size();  // sorted and unique (several calls per step with physics)
  for (const EdgeHit& hit : hits) divide_at(model, state, hit, stats);
  merge_sorted_unique(voxels, pending_before);
  stats.voxels_cut = uint32_t(voxels.size());

  // The cut front moved: partly cut voxels on it get new vertex positions.
  std::vector<uint32_t>& front_changed = state.scratch.voxels;
  front_changed.clear();
  update_front(model, state, from, to, front_changed);
  const size_t divided_end = voxels.size();
  for (uint32_t v : front_changed) {
    const uint32_t d = state.divided_of.get(v);
    if (d != kDeadIndex && state.divided[d].partial_mask != 0) voxels.push_back(v);
  }
  merge_sorted_unique(voxels, divided_end);
  stats.voxels_divided = uint32_t(state.divided.size());
  ++state.steps;
}

namespace {

// The least angle around a hole's edge that the stroke's crossings must leave no gap of (below: the
// edge lies inside the cut, not beyond its rim, where the crossings lie on one side: a gap of at
// least half a turn).
constexpr double kHoleMaxGap = 0.75 * std::numbers::pi;

// After the partly cut voxels are closed: holes in the stroke's cut surface a voxel or two wide
// that no voxel's own cuts reach (where the tissue turned as it was cut, strips of different
// directions leave ragged gaps; the closing above cuts into them from their rims and leaves them
// joined). Each uncut material edge of the voxels around the partly cut ones and the ones the
// closing touched (`state.pending_voxels` from `first`), that crosses the plane of the cut crossings
// near it (within 1.5 voxels of its middle: through their mean, normal to their mean normal) inside
// them (the crossings around the crossing point leave no angular gap over kHoleMaxGap) is cut there.
void close_holes(const VoxelModel& model, CutState& state, const std::vector<uint32_t>& stroke, size_t first,
                 CutStepStats& stats) {
  const Lattice& l = model.lattice;
  const double h = l.voxel_size;
  const int32_t voxels_along[3] = {l.nx, l.ny, l.nz};
  const auto in_lattice = [&](const int32_t c[3]) {
    return c[0] >= 0 && c[1] >= 0 && c[2] >= 0 && c[0] < l.nx && c[1] < l.ny && c[2] < l.nz;
  };
  const auto middle_t = [](const EdgeCut& cut) { return double(0.5f * (cut.t_lo + cut.t_hi)); };
  // The core: the stroke's partly cut voxels and those the closing touched; their edges and their
  // neighbours' edges are the candidates.
  std::vector<uint32_t> core(state.pending_voxels.begin() + std::ptrdiff_t(first), state.pending_voxels.end());
  for (const uint32_t v : stroke) {
    const uint32_t d = state.divided_of.get(v);
    if (d != kDeadIndex && state.divided[d].partial_mask != 0) core.push_back(v);
  }
  sorted_unique(core);
  std::vector<uint32_t> edges;
  for (const uint32_t v : core) {
    int32_t vc[3];
    l.voxel_coords(v, vc);
    for (int dz = -1; dz <= 1; ++dz) {
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          const int32_t c[3] = {vc[0] + dx, vc[1] + dy, vc[2] + dz};
          if (!in_lattice(c)) continue;
          for (int e = 0; e < 12; ++e) edges.push_back(voxel_edge_id(l, c, e));
        }
      }
    }
  }
  sorted_unique(edges);
  std::vector<uint32_t> near;  // cut edges near a candidate
  std::vector<Vec3d> points;   // their crossings within 1.5 voxels of its middle
  std::vector<double> angles;
  for (const uint32_t edge : edges) {
    if (find_cut(state, edge) != nullptr) continue;
    const uint32_t n0 = edge / 3;
    const int axis = int(edge % 3);
    int32_t a[3];
    l.node_coords(n0, a);
    int32_t b[3] = {a[0], a[1], a[2]};
    if (++b[axis] > voxels_along[axis]) continue;
    const uint32_t n1 = n0 + node_stride(l, axis);
    if (!model.is_inside(n0) || !model.is_inside(n1)) continue;
    const Vec3d x0 = l.node_position(a[0], a[1], a[2]), x1 = l.node_position(b[0], b[1], b[2]);
    const Vec3d middle = 0.5 * (x0 + x1);
    // The cut edges of the voxels within two of the edge's lower node.
    near.clear();
    int32_t c[3];
    for (c[2] = a[2] - 2; c[2] <= a[2] + 1; ++c[2]) {
      for (c[1] = a[1] - 2; c[1] <= a[1] + 1; ++c[1]) {
        for (c[0] = a[0] - 2; c[0] <= a[0] + 1; ++c[0]) {
          if (!in_lattice(c)) continue;
          const uint32_t d = state.divided_of.get(l.voxel(c[0], c[1], c[2]));
          if (d == kDeadIndex) continue;
          const uint16_t cut = state.divided[d].cut_edges;
          for (int e = 0; e < 12; ++e) {
            if ((cut >> e) & 1u) near.push_back(voxel_edge_id(l, c, e));
          }
        }
      }
    }
    sorted_unique(near);
    // Their crossings within 1.5 voxels: the local plane.
    Vec3d centre = Vec3d::Zero(), normal = Vec3d::Zero(), reference = Vec3d::Zero();
    points.clear();
    for (const uint32_t cut_edge : near) {
      const EdgeCut* cut = find_cut(state, cut_edge);
      if (cut == nullptr) continue;
      int32_t p0[3];
      l.node_coords(cut_edge / 3, p0);
      const Vec3d p = l.node_position(p0[0], p0[1], p0[2]) + middle_t(*cut) * h * Vec3d::Unit(int(cut_edge % 3));
      if ((p - middle).squaredNorm() > 2.25 * h * h) continue;
      Vec3d n = cut->normal_lo.cast<double>();
      if (points.empty()) reference = n;
      if (n.dot(reference) < 0.0) n = -n;
      normal += n;
      centre += p;
      points.push_back(p);
    }
    if (points.empty() || !(normal.squaredNorm() > 0.0)) continue;
    normal.normalize();
    // Where the cut runs within a few tenths of a voxel of a plane of nodes, its strips pass on either
    // side of them, node by node, or overlap there with those nodes between them (the liver tip's last
    // hairline: two strips 0.3 voxel apart), and its crossings' plane does not show it between two of
    // them. So along the axis nearest its normal: a node whose edge down that axis is cut lies above
    // the cut (between two strips: above the lower, so it goes with the upper side), one whose edge
    // up alone is cut lies below it; an edge across that axis between a node below and a node above
    // is cut. Where the cut ends inside the tissue, the nodes beyond its edge have no cut along the
    // axis and are left joined.
    int k = 0;
    for (int q = 1; q < 3; ++q) k = std::abs(normal[q]) > std::abs(normal[k]) ? q : k;
    if (k != axis) {
      // The distance from a node to the cut along k, in voxels: positive above, negative below; 0:
      // neither edge along k cut.
      const auto height = [&](const int32_t n[3]) -> double {
        const uint32_t node = l.node(n[0], n[1], n[2]);
        const EdgeCut* down = n[k] > 0 ? find_cut(state, Lattice::edge(node - node_stride(l, k), k)) : nullptr;
        if (down != nullptr) return 1.0 - middle_t(*down);
        const EdgeCut* up = n[k] < voxels_along[k] ? find_cut(state, Lattice::edge(node, k)) : nullptr;
        return up != nullptr ? -middle_t(*up) : 0.0;
      };
      const double s0 = height(a), s1 = height(b);
      if (s0 * s1 < 0.0) {
        divide_at(model, state, EdgeHit{edge, float(std::clamp(s0 / (s0 - s1), 0.0, 1.0)), normal.cast<float>()}, stats);
        ++stats.hole_edges;
        continue;
      }
    }
    if (points.size() < 4) continue;
    centre /= double(points.size());
    const double d0 = normal.dot(x0 - centre), d1 = normal.dot(x1 - centre);
    if ((d0 > 0.0) == (d1 > 0.0) || d0 == d1) continue;
    const double t = std::clamp(d0 / (d0 - d1), 0.0, 1.0);
    const Vec3d q = x0 + t * (x1 - x0);
    // Inside the crossings: no angular gap around q over kHoleMaxGap (in the plane).
    const Vec3d u = normal.unitOrthogonal(), w = normal.cross(u);
    angles.clear();
    for (const Vec3d& p : points) {
      const double ru = (p - q).dot(u), rw = (p - q).dot(w);
      if (ru * ru + rw * rw >= 0.01 * h * h) angles.push_back(std::atan2(rw, ru));
    }
    if (angles.size() < 3) continue;
    std::sort(angles.begin(), angles.end());
    double gap = angles.front() + 2.0 * std::numbers::pi - angles.back();
    for (size_t i = 1; i < angles.size(); ++i) gap = std::max(gap, angles[i] - angles[i - 1]);
    if (gap > kHoleMaxGap) continue;
    divide_at(model, state, EdgeHit{edge, float(t), normal.cast<float>()}, stats);
    ++stats.hole_edges;
  }
}

}  // namespace

void cut_close_seams(const VoxelModel& model, CutState& state, std::vector<uint32_t>& stroke, CutStepStats& stats) {
  const Lattice& l = model.lattice;
  sorted_unique(stroke);
  std::vector<uint32_t>& voxels = state.pending_voxels;
  const size_t pending_before = voxels.size();
  for (const uint32_t v : stroke) {
    const uint32_t d = state.divided_of.get(v);
    if (d == kDeadIndex || state.divided[d].partial_mask == 0) continue;
    const DividedVoxel dv = state.divided[d];  // a copy: divide_at may grow state.divided
    int32_t vc[3];
    l.voxel_coords(v, vc);
    const auto corner_node = [&](int c) { return l.node(vc[0] + (c & 1), vc[1] + ((c >> 1) & 1), vc[2] + ((c >> 2) & 1)); };
    const auto corner_position = [&](int c) {
      return l.node_position(vc[0] + (c & 1), vc[1] + ((c >> 1) & 1), vc[2] + ((c >> 2) & 1));
    };
    // The plane of the voxel's cuts: through their crossings, normal to their mean blade normal (each
    // oriented along the first). Whether or not the cuts lie in one plane: where the tissue turned as
    // the stroke cut it (a hanging lobe swings), its strips' normals in rest space differ by up to
    // ~70 degrees in one voxel, and those voxels were the hairline that kept the lobe's tip on
    // (docs/cutting.md). Until 2026-12-08 a voxel whose normals differed by more than ~37 degrees
    // was left alone.
    Vec3d centre = Vec3d::Zero(), normal = Vec3d::Zero();
    int points = 0;
    Vec3d first = Vec3d::Zero();
    for (int e = 0; e < 12; ++e) {
      if (!((dv.cut_edges >> e) & 1u)) continue;
      const uint32_t edge = Lattice::edge(corner_node(kVoxelEdges[e].c0), kVoxelEdges[e].axis);
      const uint32_t i = state.edge_cut_of.get(edge);
      if (i == kDeadIndex) continue;
      const EdgeCut& cut = state.edge_cuts[i];
      const Vec3d p0 = corner_position(kVoxelEdges[e].c0);
      const Vec3d along = l.voxel_size * Vec3d::Unit(kVoxelEdges[e].axis);
      for (int side = 0; side < 2; ++side) {
        Vec3d n = (side ? cut.normal_hi : cut.normal_lo).cast<double>();
        if (points == 0) first = n;
        if (n.dot(first) < 0.0) n = -n;
        normal += n;
        centre += p0 + double(side ? cut.t_hi : cut.t_lo) * along;
        ++points;
      }
    }
    if (points == 0 || !(normal.squaredNorm() > 0.0)) continue;
    centre /= points;
    normal.normalize();
    // The voxel's material edges that plane crosses and no sweep did.
    for (int e = 0; e < 12; ++e) {
      if ((dv.cut_edges >> e) & 1u) continue;
      const uint32_t n0 = corner_node(kVoxelEdges[e].c0), n1 = corner_node(kVoxelEdges[e].c1);
      if (!model.is_inside(n0) || !model.is_inside(n1)) continue;
      const double d0 = normal.dot(corner_position(kVoxelEdges[e].c0) - centre);
      const double d1 = normal.dot(corner_position(kVoxelEdges[e].c1) - centre);
      if ((d0 > 0.0) == (d1 > 0.0) || d0 == d1) continue;
      const EdgeHit hit{Lattice::edge(n0, kVoxelEdges[e].axis), float(std::clamp(d0 / (d0 - d1), 0.0, 1.0)),
                        normal.cast<float>()};
      divide_at(model, state, hit, stats);
      ++stats.seam_edges;
    }
  }
  close_holes(model, state, stroke, pending_before, stats);
  merge_sorted_unique(voxels, pending_before);
  stats.voxels_cut = uint32_t(voxels.size());
  stats.voxels_divided = uint32_t(state.divided.size());
}


void cut_update_surface(const VoxelModel& model, CutState& state, CutStepStats& stats, const TaskRunner& tasks) {
  state.changed_vertices.clear();
  std::vector<uint32_t>& corners = state.scratch.corners;
  std::vector<uint32_t>& quads = state.scratch.quads;
  corners.clear();
  quads.clear();
  refresh_voxels(model, state, state.pending_voxels, stats, &corners, &quads, tasks);
  if (!state.changed_vertices.empty() || !corners.empty()) {
    corners.insert(corners.end(), state.changed_vertices.begin(), state.changed_vertices.end());
    state.touched_vertices.swap(corners);
    state.touched_quads.swap(quads);
    ++state.surface_changes;
  }
  state.changed_voxels.swap(state.pending_voxels);
  state.pending_voxels.clear();
  std::sort(state.pending_reshaped.begin(), state.pending_reshaped.end());  // a voxel's entries are equal
  state.pending_reshaped.erase(std::unique(state.pending_reshaped.begin(), state.pending_reshaped.end()),
                               state.pending_reshaped.end());
  state.reshaped_voxels.swap(state.pending_reshaped);
  state.pending_reshaped.clear();
}

CutStepStats cut_step(const VoxelModel& model, CutState& state, const BladePose& from, const BladePose& to) {
  CutStepStats stats;
  cut_divide(model, state, from, to, stats);
  cut_update_surface(model, state, stats);
  return stats;
}

uint32_t vertex_quads(const CutState& state, uint32_t slot, uint32_t out[kMaxVertexQuads]) {
  const CutSurface& s = state.surface;
  if (slot >= s.vertex_patch.size() || s.vertex_patch[slot] == CutSurface::kFreeKey) return 0;
  const uint32_t voxel = uint32_t(s.vertex_patch[slot] / 16);
  int32_t vc[3];
  state.lattice.voxel_coords(voxel, vc);
  uint32_t n = 0;
  for (uint32_t bits = s.vertex_half_edges[slot]; bits; bits &= bits - 1) {
    const int h = std::countr_zero(bits);  // 2 * voxel edge + side
    const uint32_t quad = s.quad_of_half_edge.get(half_edge_key(voxel_edge_id(state.lattice, vc, h >> 1), h & 1));
    if (quad != kDeadIndex) out[n++] = quad;  // none: the two quads of a slit edge that would coincide cancel
  }
  return n;
}

SurfaceMesh compact_surface(const CutSurface& s) {
  SurfaceMesh mesh;
  std::vector<uint32_t> remap(s.positions.size(), kDeadIndex);
  for (uint32_t slot = 0; slot < s.positions.size(); ++slot) {
    if (s.vertex_piece[slot] == CutSurface::kFreeKey) continue;
    remap[slot] = uint32_t(mesh.positions.size());
    mesh.positions.push_back(s.positions[slot]);
    mesh.vertex_voxel.push_back(uint32_t(s.vertex_piece[slot] / 8));
  }
  for (const Tri& t : s.triangles) {
    if (t[0] == kDeadIndex) continue;
    mesh.triangles.push_back({remap[t[0]], remap[t[1]], remap[t[2]]});
  }
  return mesh;
}

std::vector<double> component_volumes(const SurfaceMesh& mesh) {
  const uint32_t n = uint32_t(mesh.positions.size());
  std::vector<uint32_t> parent(n);
  for (uint32_t v = 0; v < n; ++v) parent[v] = v;
  for (const Tri& t : mesh.triangles) {
    uf_unite(parent.data(), t[0], t[1]);
    uf_unite(parent.data(), t[0], t[2]);
  }
  // Components numbered by their root (the lowest vertex); the signed volume of each, by the
  // divergence theorem over its triangles.
  std::vector<uint32_t> index(n, kDeadIndex);
  std::vector<double> volume;
  for (const Tri& t : mesh.triangles) {
    const uint32_t root = uf_find(parent.data(), t[0]);
    if (index[root] == kDeadIndex) index[root] = 0;  // marked: used by a triangle
  }
  for (uint32_t v = 0; v < n; ++v) {
    if (index[v] == 0 && uf_find(parent.data(), v) == v) {
      index[v] = uint32_t(volume.size());
      volume.push_back(0.0);
    }
  }
  for (const Tri& t : mesh.triangles) {
    const Vec3d a = mesh.positions[t[0]].cast<double>(), b = mesh.positions[t[1]].cast<double>();
    const Vec3d c = mesh.positions[t[2]].cast<double>();
    volume[index[uf_find(parent.data(), t[0])]] += a.dot(b.cross(c)) / 6.0;
  }
  return volume;
}

namespace {
// check_cut_state, part 1: the edge cuts and divided voxels are indexed and agree with the material graph.
bool check_cut_index(const VoxelModel& model, const CutState& state, std::string& error) {
  [[maybe_unused]] const Lattice& l = model.lattice;
  [[maybe_unused]] const CutSurface& s = state.surface;
  const auto fail = [&](const std::string& what) {
    error = what;
    return false;
  };
  // Edge cuts: indexed, on edges with an inside end.
  if (state.edge_cut_of.size() != state.edge_cuts.size()) return fail("edge cut map and array differ in size");
  for (uint32_t i = 0; i < state.edge_cuts.size(); ++i) {
    const EdgeCut& c = state.edge_cuts[i];
    if (state.edge_cut_of.get(c.edge) != i) return fail("edge cut " + std::to_string(c.edge) + " not indexed");
    if (!(c.t_lo >= 0.0f && c.t_lo <= c.t_hi && c.t_hi <= 1.0f)) return fail("edge cut with bad parameters");
  }

  // Divided voxels: hold a cut edge; pieces are the material graph's components.
  if (state.divided_of.size() != state.divided.size()) return fail("divided voxel map and array differ in size");
  for (uint32_t i = 0; i < state.divided.size(); ++i) {
    const DividedVoxel& dv = state.divided[i];
    if (state.divided_of.get(dv.voxel) != i) return fail("divided voxel not indexed");
    int32_t vc[3];
    l.voxel_coords(dv.voxel, vc);
    uint8_t pieces[8], count = 0, partial = 0;
    uint16_t mask = 0, air = 0;
    for (int e = 0; e < 12; ++e) {
      mask |= uint16_t(find_cut(state, voxel_edge_id(l, vc, e)) ? 1u << e : 0u);
      air |= uint16_t(state.air_edges.contains(voxel_edge_id(l, vc, e)) ? 1u << e : 0u);
    }
    if (mask == 0 && air == 0) return fail("divided voxel " + std::to_string(dv.voxel) + " has no cut edge");
    if (mask != dv.cut_edges || air != dv.air_edges) {
      return fail("divided voxel " + std::to_string(dv.voxel) + " has a stale cut-edge mask");
    }
    material_components(corner_inside_bits(model, vc), mask, air, pieces, count, partial);
    if (count != dv.piece_count || partial != dv.partial_mask || !std::equal(pieces, pieces + 8, dv.corner_piece)) {
      return fail("divided voxel " + std::to_string(dv.voxel) + " pieces differ from its material graph");
    }
  }
  return true;
}

// check_cut_state, part 2: every memoised patch shape equals a fresh computation of its key.
bool check_shape_memo(const VoxelModel& model, const CutState& state, std::string& error) {
  [[maybe_unused]] const Lattice& l = model.lattice;
  [[maybe_unused]] const CutSurface& s = state.surface;
  const auto fail = [&](const std::string& what) {
    error = what;
    return false;
  };
  // The memo of shapes holds each key's shape (a pure function of its key), checked for the keys of
  // the divided voxels.
  if (state.shape_of.size() != state.shapes.size()) return fail("shape memo map and array differ in size");
  std::vector<uint8_t> shape_checked(state.shapes.size(), 0);
  for (const DividedVoxel& dv : state.divided) {
    int32_t vc[3];
    l.voxel_coords(dv.voxel, vc);
    const uint8_t in_bits = corner_inside_bits(model, vc);
    const uint32_t i = state.shape_of.get(shape_key(in_bits, dv.cut_edges, dv.air_edges));
    if (i == kDeadIndex) return fail("divided voxel " + std::to_string(dv.voxel) + " has no memoised shape");
    if (shape_checked[i]) continue;
    shape_checked[i] = 1;
    const PatchShape& m = state.shapes[i];
    PatchShape fresh;
    make_shape(in_bits, dv.cut_edges, dv.air_edges, true, fresh);
    const bool same = fresh.present == m.present && fresh.patch_count == m.patch_count && fresh.piece_count == m.piece_count &&
                      fresh.piece_partial == m.piece_partial && fresh.doubled == m.doubled &&
                      fresh.patch_partial == m.patch_partial && std::equal(m.corner_piece, m.corner_piece + 8, fresh.corner_piece) &&
                      std::equal(m.patch_of, m.patch_of + 24, fresh.patch_of) &&
                      std::equal(m.patch_half_edges, m.patch_half_edges + 12, fresh.patch_half_edges) &&
                      std::equal(m.patch_piece, m.patch_piece + 12, fresh.patch_piece);
    if (!same) return fail("memoised shape of divided voxel " + std::to_string(dv.voxel) + " differs from its key's shape");
  }
  return true;
}

// check_cut_state, part 3: every live vertex is a patch of its voxel, every patch has a vertex.
bool check_cut_vertices(const VoxelModel& model, const CutState& state, std::string& error) {
  [[maybe_unused]] const Lattice& l = model.lattice;
  [[maybe_unused]] const CutSurface& s = state.surface;
  const auto fail = [&](const std::string& what) {
    error = what;
    return false;
  };
  // Every live vertex is a patch of its voxel (piece, half-edges, position), and every patch of a
  // voxel holding a vertex has one; positions finite.
  uint32_t live_vertices = 0;
  for (uint32_t slot = 0; slot < s.positions.size(); ++slot) {
    const uint64_t key = s.vertex_patch[slot];
    if (key == CutSurface::kFreeKey) continue;
    ++live_vertices;
    if (s.vertex_of_patch.get(key) != slot) return fail("vertex slot not indexed by its patch");
    if (!s.positions[slot].allFinite()) return fail("non-finite vertex position");
    const uint32_t voxel = uint32_t(key / 16);
    const std::string where = " in voxel " + std::to_string(voxel);
    uint8_t pieces[8], count = 0, partial = 0;
    pieces_of(model, state, voxel, pieces, count, partial);
    int32_t vc[3];
    l.voxel_coords(voxel, vc);
    VoxelPatches patches;
    voxel_patches(model, state, voxel, vc, patches);
    const uint32_t p = uint32_t(key % 16);
    if (p >= patches.patch_count) return fail("vertex of a patch that does not exist" + where);
    if (key % 16 == 0) {
      for (uint32_t q = 0; q < patches.patch_count; ++q) {
        if (s.vertex_of_patch.get(patch_key(voxel, q)) == kDeadIndex) return fail("patch without a vertex" + where);
      }
    }
    if (patches.patch_piece[p] == kNoPiece || s.vertex_piece[slot] != piece_key(voxel, patches.patch_piece[p])) {
      return fail("vertex with a wrong piece" + where);
    }
    for (uint32_t bits = patches.patch_half_edges[p]; bits; bits &= bits - 1) {
      const int h = std::countr_zero(bits);
      if (patches.patch_piece[patches.patch_of[h]] != pieces[h % 2 ? kVoxelEdges[h / 2].c1 : kVoxelEdges[h / 2].c0]) {
        return fail("patch spanning two pieces" + where);
      }
    }
    if (s.vertex_half_edges[slot] != patches.patch_half_edges[p]) return fail("vertex with stale half-edges" + where);
    const Vec3f position = patch_vertex_position(model, state, voxel, vc, patches, uint8_t(p));
    if ((position - s.positions[slot]).norm() > 1e-5f * float(l.voxel_size)) return fail("stale vertex position" + where);
  }
  if (live_vertices != s.vertex_of_patch.size()) return fail("vertex map holds freed slots");
  for (uint32_t slot : s.free_vertices) {
    if (s.vertex_patch[slot] != CutSurface::kFreeKey) return fail("free list holds a live vertex");
  }
  return true;
}

// check_cut_state, part 4: every existing half-edge has its quad, and no quad outlives one.
bool check_cut_quads(const VoxelModel& model, const CutState& state, std::string& error) {
  [[maybe_unused]] const Lattice& l = model.lattice;
  [[maybe_unused]] const CutSurface& s = state.surface;
  const auto fail = [&](const std::string& what) {
    error = what;
    return false;
  };
  // Every existing half-edge has its quad joining the patches that hold it (slit quads that would
  // coincide cancel).
  uint32_t quads = 0;
  const auto check_edge = [&](uint32_t edge) -> bool {
    uint32_t around[4];
    uint8_t corners[4];
    voxels_around_edge(l, edge, around, corners);
    EdgeQuads plan;
    plan_edge_quads(model, state, edge, find_cut(state, edge), around, corners, plan);
    for (int side = 0; side < 2; ++side) {
      const std::string what = "half-edge " + std::to_string(side) + " of edge " + std::to_string(edge);
      if (plan.missing[side]) return fail(what + " has a sharing patch without a vertex");
      const uint32_t quad = s.quad_of_half_edge.get(half_edge_key(edge, side));
      if (!plan.exists[side]) {
        if (quad != kDeadIndex) return fail(what + ": a quad outlives its half-edge");
        continue;
      }
      ++quads;
      if (quad == kDeadIndex) return fail(what + " has no quad");
      if (s.quad_half_edge[quad] != half_edge_key(edge, side)) return fail("quad slot not owned by its half-edge");
      uint32_t want[4];
      std::copy(plan.v[side], plan.v[side] + 4, want);
      std::sort(want, want + 4);
      uint32_t have[6] = {s.triangles[2 * quad][0],     s.triangles[2 * quad][1],     s.triangles[2 * quad][2],
                          s.triangles[2 * quad + 1][0], s.triangles[2 * quad + 1][1], s.triangles[2 * quad + 1][2]};
      std::sort(have, have + 6);
      uint32_t* end = std::unique(have, have + 6);
      if (end - have != 4 || !std::equal(want, want + 4, have)) return fail("quad of " + what + " does not join its patches");
    }
    return true;
  };
  // Half-edges exist only on sign-change edges and cut edges.
  std::vector<uint32_t> edges;
  edges.reserve(model.crossings.size() + state.edge_cuts.size());
  for (const EdgeCrossing& c : model.crossings) edges.push_back(c.edge);
  for (const EdgeCut& c : state.edge_cuts) edges.push_back(c.edge);
  sorted_unique(edges);
  for (uint32_t edge : edges) {
    if (!check_edge(edge)) return false;
  }
  if (quads != s.quad_of_half_edge.size()) {
    return fail("quads outlive their half-edges (" + std::to_string(s.quad_of_half_edge.size()) + " quads, " +
                std::to_string(quads) + " expected)");
  }
  for (uint32_t quad : s.free_quads) {
    if (s.quad_half_edge[quad] != CutSurface::kFreeKey) return fail("free list holds a live quad");
  }
  return true;
}

}  // namespace

bool check_cut_state(const VoxelModel& model, const CutState& state, std::string& error) {
  const CutSurface& s = state.surface;
  const auto fail = [&](const std::string& what) {
    error = what;
    return false;
  };
  if (!check_cut_index(model, state, error) || !check_shape_memo(model, state, error) ||
      !check_cut_vertices(model, state, error) || !check_cut_quads(model, state, error)) {
    return false;
  }

  // The surface is a closed, consistently oriented 2-manifold.
  const SurfaceStats stats = surface_stats(compact_surface(s));
  if (stats.boundary_edges != 0 || stats.nonmanifold_edges != 0 || stats.misoriented_edges != 0) {
    return fail("surface not a closed oriented 2-manifold: " + std::to_string(stats.boundary_edges) + " boundary, " +
                std::to_string(stats.nonmanifold_edges) + " non-manifold, " + std::to_string(stats.misoriented_edges) +
                " misoriented edges");
  }
  return true;
}

double cut_dropped_length(const VoxelModel& model, const CutState& state) {
  const Lattice& l = model.lattice;
  double sum = 0.0;
  for (const EdgeCut& c : state.edge_cuts) {
    const uint32_t n0 = c.edge / 3;
    const bool in0 = model.is_inside(n0), in1 = model.is_inside(n0 + node_stride(l, int(c.edge % 3)));
    // Both ends inside: every interval has an owner (half_edge_param); one end inside: the
    // material between the outermost cut and the surface crossing holds no node.
    if (in0 != in1) {
      const EdgeCrossing* x = model.find_crossing(c.edge);
      const double ts = x != nullptr ? double(x->t) : 0.5;
      sum += in0 ? ts - double(c.t_lo) : double(c.t_hi) - ts;
    }
  }
  return sum;
}

uint64_t cut_memory_bytes(const CutState& state) {
  return state.edge_cuts.capacity() * sizeof(EdgeCut) + state.edge_cut_of.memory_bytes() +
         state.divided.capacity() * sizeof(DividedVoxel) + state.divided_of.memory_bytes() +
         state.fronts.capacity() * sizeof(VoxelFront) + state.front_of.memory_bytes() + state.air_edges.memory_bytes() +
         state.shapes.capacity() * sizeof(PatchShape) + state.shape_of.memory_bytes();
}

}  // namespace dvx
