#include "sim/cut.h"
#include "sim/id_pool.h"

#include "sim/contour.h"
#include "sim/surface_metrics.h"
#include "sim/union_find.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <limits>

namespace dvx {
namespace {

}  // namespace

// The pieces around a half-edge given the voxels around its edge (see half_edge_sharing).
bool sharing_pieces(const VoxelModel& model, const CutState& state, uint32_t edge, int side,
                    const uint32_t voxels[4], const uint8_t lower_corner[4], uint8_t pieces[4]);

namespace {

// Index in kVoxelEdges of the edge along `axis` starting at corner c0 (c0 has bit `axis` clear).
constexpr std::array<std::array<int8_t, 8>, 3> make_edge_index() {
  std::array<std::array<int8_t, 8>, 3> t{};
  for (auto& row : t) row.fill(-1);
  for (int e = 0; e < 12; ++e) t[kVoxelEdges[e].axis][kVoxelEdges[e].c0] = int8_t(e);
  return t;
}
constexpr std::array<std::array<int8_t, 8>, 3> kEdgeIndex = make_edge_index();
int voxel_edge_index(int axis, int c0) { return kEdgeIndex[size_t(axis)][size_t(c0)]; }

// Index in kVoxelEdges of the edge joining corners a and b (-1 when they share no edge).
constexpr int edge_between(int a, int b) {
  for (int e = 0; e < 12; ++e) {
    if ((kVoxelEdges[e].c0 == a && kVoxelEdges[e].c1 == b) || (kVoxelEdges[e].c0 == b && kVoxelEdges[e].c1 == a)) {
      return e;
    }
  }
  return -1;
}

// The edge from corner i to corner i+1 (cyclic) of each face, and the face's edge mask.
struct FaceEdges {
  uint8_t edge[6][4];
  uint16_t mask[6];
};
constexpr FaceEdges make_face_edges() {
  FaceEdges f{};
  constexpr uint8_t corners[6][4] = {{0, 2, 6, 4}, {1, 3, 7, 5}, {0, 4, 5, 1}, {2, 6, 7, 3}, {0, 1, 3, 2}, {4, 5, 7, 6}};
  for (int face = 0; face < 6; ++face) {
    for (int i = 0; i < 4; ++i) {
      f.edge[face][i] = uint8_t(edge_between(corners[face][i], corners[face][(i + 1) % 4]));
      f.mask[face] = uint16_t(f.mask[face] | (1u << f.edge[face][i]));
    }
  }
  return f;
}
constexpr FaceEdges kFaceEdges = make_face_edges();

// Patches of a voxel are numbered 0..n-1; a voxel holds at most 12 (24 half-edges, two per loop).
constexpr int kMaxPatches = 12;
uint64_t patch_key(uint32_t voxel, uint32_t patch) { return uint64_t(voxel) * 16 + patch; }

uint64_t piece_key(uint32_t voxel, uint32_t piece) { return uint64_t(voxel) * 8 + piece; }
uint64_t half_edge_key(uint32_t edge, int side) { return uint64_t(edge) * 2 + uint64_t(side); }

// Node of corner c of the voxel at lattice coordinates vc.
uint32_t corner_node(const Lattice& l, const int32_t vc[3], int c) {
  return l.node(vc[0] + (c & 1), vc[1] + ((c >> 1) & 1), vc[2] + ((c >> 2) & 1));
}

// Lattice edge id of voxel edge e.
uint32_t voxel_edge_id(const Lattice& l, const int32_t vc[3], int e) {
  return Lattice::edge(corner_node(l, vc, kVoxelEdges[e].c0), kVoxelEdges[e].axis);
}

// Node index step along an axis.
uint32_t node_stride(const Lattice& l, int axis) {
  return axis == 0 ? 1u : axis == 1 ? uint32_t(l.nx + 1) : uint32_t(l.nx + 1) * uint32_t(l.ny + 1);
}

// The voxels around a lattice edge (up to 4, in counter-clockwise order about the axis); the
// corner of the edge's lower node in each. Entries outside the lattice get voxel = kDeadIndex.
// The voxels around the lattice edge from node n along `axis` (see voxels_around_edge).
void voxels_around_node_edge(const Lattice& l, const int32_t n[3], int axis, uint32_t voxels[4],
                             uint8_t lower_corner[4]) {
  static constexpr int kNext[3][2] = {{1, 2}, {2, 0}, {0, 1}};
  const int u = kNext[axis][0], v = kNext[axis][1];
  const int32_t dims[3] = {l.nx, l.ny, l.nz};
  const int64_t stride[3] = {1, int64_t(l.nx), int64_t(l.nx) * int64_t(l.ny)};
  // The voxel at the edge's node (it may lie past the border along u or v), then its neighbours.
  const int64_t base = int64_t(n[0]) + stride[1] * n[1] + stride[2] * n[2];
  const bool u_hi = n[u] < dims[u], u_lo = n[u] > 0, v_hi = n[v] < dims[v], v_lo = n[v] > 0;
  const bool in_axis = n[axis] >= 0 && n[axis] < dims[axis];
  static constexpr int kOffsets[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  const bool ok[4] = {u_hi && v_hi, u_lo && v_hi, u_lo && v_lo, u_hi && v_lo};
  for (int q = 0; q < 4; ++q) {
    voxels[q] = in_axis && ok[q] ? uint32_t(base - kOffsets[q][0] * stride[u] - kOffsets[q][1] * stride[v]) : kDeadIndex;
    lower_corner[q] = uint8_t((kOffsets[q][0] << u) | (kOffsets[q][1] << v));
  }
}

void voxels_around_edge(const Lattice& l, uint32_t edge, uint32_t voxels[4], uint8_t lower_corner[4]) {
  int32_t n[3];
  l.node_coords(edge / 3, n);
  voxels_around_node_edge(l, n, int(edge % 3), voxels, lower_corner);
}

// The same for edge e of the voxel at vc, without divisions (the hot path of the surface update).
void voxels_around_voxel_edge(const Lattice& l, const int32_t vc[3], int e, uint32_t voxels[4],
                              uint8_t lower_corner[4]) {
  const VoxelEdge& ve = kVoxelEdges[e];
  const int32_t n[3] = {vc[0] + (ve.c0 & 1), vc[1] + ((ve.c0 >> 1) & 1), vc[2] + ((ve.c0 >> 2) & 1)};
  voxels_around_node_edge(l, n, ve.axis, voxels, lower_corner);
}

// Inserts into a sorted vector if absent.
void sorted_unique(std::vector<uint32_t>& v) {
  std::sort(v.begin(), v.end());
  v.erase(std::unique(v.begin(), v.end()), v.end());
}

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

const EdgeCut* find_cut(const CutState& state, uint32_t edge) {
  const uint32_t i = state.edge_cut_of.get(edge);
  return i == kDeadIndex ? nullptr : &state.edge_cuts[i];
}

// Inside bits of a voxel's corners (bit c: corner c inside).
uint8_t corner_inside_bits(const VoxelModel& model, const int32_t vc[3]) {
  uint8_t bits = 0;
  for (int c = 0; c < 8; ++c) bits = uint8_t(bits | (model.is_inside(corner_node(model.lattice, vc, c)) ? 1u << c : 0u));
  return bits;
}

// Components of the voxel's material graph (voxel_material_joins: uncut edges, uncut ambiguous faces).
// `air_edges`: surface edges the blade crossed outside the material (they cut the faces they bound).
void material_components(uint8_t in_bits, uint16_t cut_edges, uint16_t air_edges, uint8_t corner_piece[8],
                         uint8_t& piece_count, uint8_t& partial_mask) {
  uint8_t parent[8];
  for (int c = 0; c < 8; ++c) parent[c] = uint8_t(c);
  const auto find = [&](int c) { return int(uf_find(parent, uint8_t(c))); };
  const auto join = [&](int c0, int c1) { uf_unite(parent, uint8_t(c0), uint8_t(c1)); };
  for (int e = 0; e < 12; ++e) {
    const VoxelEdge& ve = kVoxelEdges[e];
    if ((in_bits >> ve.c0 & 1u) && (in_bits >> ve.c1 & 1u) && !((cut_edges >> e) & 1u)) join(ve.c0, ve.c1);
  }
  const uint8_t faces = voxel_material_joins(in_bits, uint16_t(cut_edges | air_edges));
  for (int f = 0; f < 6; ++f) {
    if (!(faces >> f & 1u)) continue;
    const uint8_t* k = kVoxelFaceCorners[f];
    if (in_bits >> k[0] & 1u) {
      join(k[0], k[2]);
    } else {
      join(k[1], k[3]);
    }
  }
  // Number pieces in corner order.
  uint8_t id_of_root[8];
  std::fill(id_of_root, id_of_root + 8, kNoPiece);
  piece_count = 0;
  for (int c = 0; c < 8; ++c) {
    if (!(in_bits >> c & 1u)) {
      corner_piece[c] = kNoPiece;
      continue;
    }
    const int r = find(c);
    if (id_of_root[r] == kNoPiece) id_of_root[r] = piece_count++;
    corner_piece[c] = id_of_root[r];
  }
  // A piece holding both ends of a cut edge is partly cut.
  partial_mask = 0;
  for (int e = 0; e < 12; ++e) {
    const VoxelEdge& ve = kVoxelEdges[e];
    if (((cut_edges >> e) & 1u) && (in_bits >> ve.c0 & 1u) && (in_bits >> ve.c1 & 1u) &&
        corner_piece[ve.c0] == corner_piece[ve.c1]) {
      partial_mask |= uint8_t(1u << corner_piece[ve.c0]);
    }
  }
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

// ---- Surface slots -------------------------------------------------------------------------

// Grows the dirty range [begin, end) to cover [lo, hi).
void grow_range(uint32_t& begin, uint32_t& end, uint32_t lo, uint32_t hi) {
  if (begin >= end) {
    begin = lo;
    end = hi;
  } else {
    begin = std::min(begin, lo);
    end = std::max(end, hi);
  }
}

void mark_vertex_dirty(CutSurface& s, uint32_t slot) {
  grow_range(s.dirty_vertex_begin, s.dirty_vertex_end, slot, slot + 1);
}

void mark_quad_dirty(CutSurface& s, uint32_t quad) {
  grow_range(s.dirty_triangle_begin, s.dirty_triangle_end, 2 * quad, 2 * quad + 2);
}

// Slot of a patch's vertex, allocated when absent.
uint32_t ensure_vertex(CutSurface& s, uint64_t key, bool& created) {
  uint32_t slot = s.vertex_of_patch.get(key);
  created = slot == kDeadIndex;
  if (!created) return slot;
  if (!take_free_slot(s.free_vertices, slot)) {
    slot = uint32_t(s.positions.size());
    s.positions.emplace_back(Vec3f::Zero());
    s.vertex_piece.push_back(CutSurface::kFreeKey);
    s.vertex_patch.push_back(CutSurface::kFreeKey);
    s.vertex_half_edges.push_back(0);
  }
  s.vertex_patch[slot] = key;
  s.vertex_of_patch.set(key, slot);
  return slot;
}

bool free_vertex(CutSurface& s, uint64_t key) {
  const uint32_t slot = s.vertex_of_patch.get(key);
  if (slot == kDeadIndex) return false;
  s.vertex_of_patch.erase(key);
  s.vertex_piece[slot] = s.vertex_patch[slot] = CutSurface::kFreeKey;
  s.vertex_half_edges[slot] = 0;
  s.positions[slot] = Vec3f::Constant(std::numeric_limits<float>::quiet_NaN());
  s.free_vertices.push_back(slot);
  mark_vertex_dirty(s, slot);
  return true;
}

// The vertex of the patch of `voxel` that holds half-edge h (2 * voxel edge + side), or kDeadIndex.
uint32_t vertex_holding(const CutSurface& s, uint32_t voxel, int h) {
  for (uint32_t p = 0; p < uint32_t(kMaxPatches); ++p) {
    const uint32_t slot = s.vertex_of_patch.get(patch_key(voxel, p));
    if (slot == kDeadIndex) return kDeadIndex;
    if ((s.vertex_half_edges[slot] >> h) & 1u) return slot;
  }
  return kDeadIndex;
}

// Appends the corners of quad slot `quad`'s two triangles to `corners` (when given and live).
void note_quad_corners(const CutSurface& s, uint32_t quad, std::vector<uint32_t>* corners) {
  if (corners == nullptr || s.quad_half_edge[quad] == CutSurface::kFreeKey) return;
  for (int t = 0; t < 2; ++t) corners->insert(corners->end(), s.triangles[2 * quad + t].begin(), s.triangles[2 * quad + t].end());
}

// Frees the quad of a half-edge; its corners go to `corners` (when given). Returns true when it had one.
bool free_quad(CutSurface& s, uint64_t key, std::vector<uint32_t>* corners) {
  const uint32_t quad = s.quad_of_half_edge.get(key);
  if (quad == kDeadIndex) return false;
  note_quad_corners(s, quad, corners);
  s.quad_of_half_edge.erase(key);
  s.quad_half_edge[quad] = CutSurface::kFreeKey;
  s.triangles[2 * quad] = s.triangles[2 * quad + 1] = Tri{kDeadIndex, kDeadIndex, kDeadIndex};
  s.triangle_cut[2 * quad] = s.triangle_cut[2 * quad + 1] = 0;
  s.free_quads.push_back(quad);
  mark_quad_dirty(s, quad);
  return true;
}

// Writes the quad (v0 v1 v2 v3, counter-clockwise seen from outside) of a half-edge, split along
// the shorter diagonal unless `diagonal` forces one (0: v0-v2, 1: v1-v3; -1: free). Returns true
// when a slot changed; then its old and new corners go to `corners` (when given).
bool write_quad(CutSurface& s, uint64_t key, const uint32_t v[4], bool on_cut, int diagonal,
                std::vector<uint32_t>* corners) {
  uint32_t quad = s.quad_of_half_edge.get(key);
  if (quad == kDeadIndex) {
    if (!take_free_slot(s.free_quads, quad)) {
      quad = uint32_t(s.quad_half_edge.size());
      s.quad_half_edge.push_back(CutSurface::kFreeKey);
      s.triangles.resize(s.triangles.size() + 2);
      s.triangle_cut.resize(s.triangles.size(), 0);
    }
    s.quad_half_edge[quad] = key;
    s.quad_of_half_edge.set(key, quad);
  }
  const float d02 = (s.positions[v[0]] - s.positions[v[2]]).squaredNorm();
  const float d13 = (s.positions[v[1]] - s.positions[v[3]]).squaredNorm();
  Tri t0, t1;
  if (diagonal == 0 || (diagonal < 0 && d02 <= d13)) {
    t0 = {v[0], v[1], v[2]};
    t1 = {v[0], v[2], v[3]};
  } else {
    t0 = {v[0], v[1], v[3]};
    t1 = {v[1], v[2], v[3]};
  }
  const uint8_t flag = on_cut ? 1 : 0;
  if (s.triangles[2 * quad] == t0 && s.triangles[2 * quad + 1] == t1 && s.triangle_cut[2 * quad] == flag) return false;
  note_quad_corners(s, quad, corners);  // the old ones (a new slot holds dead triangles: none)
  if (corners != nullptr) corners->insert(corners->end(), v, v + 4);
  s.triangles[2 * quad] = t0;
  s.triangles[2 * quad + 1] = t1;
  s.triangle_cut[2 * quad] = s.triangle_cut[2 * quad + 1] = flag;
  mark_quad_dirty(s, quad);
  return true;
}

// ---- Vertices of pieces --------------------------------------------------------------------

// The half-edge at end `side` of `edge` as a parameter along the edge (see half_edge()).
// `cut` is the edge's EdgeCut (nullptr when uncut), looked up by the caller.
bool half_edge_param(const VoxelModel& model, const EdgeCut* cut, uint32_t edge, int side, double& t,
                     Vec3d& normal, bool* from_cut = nullptr) {
  const int axis = int(edge % 3);
  const uint32_t n0 = edge / 3;
  const uint32_t n1 = n0 + node_stride(model.lattice, axis);
  const bool in0 = model.is_inside(n0), in1 = model.is_inside(n1);
  if (!(side ? in1 : in0)) return false;
  if (in0 == in1 && cut == nullptr) return false;  // material runs through the whole edge
  // Nearest boundary from the end node: the mesh crossing and the cuts.
  double best = side ? -1.0 : 2.0;
  const auto consider = [&](double candidate, const Vec3d& n) {
    if (side ? candidate > best : candidate < best) {
      best = candidate;
      normal = n;
    }
  };
  if (in0 != in1) {
    const EdgeCrossing* c = model.find_crossing(edge);
    if (c != nullptr) {
      consider(c->t, decode_normal(c->normal));
    } else {
      Vec3d n = Vec3d::Zero();
      n[axis] = in0 ? 1.0 : -1.0;
      consider(0.5, n);
    }
  }
  // The cut: each inside end sees its nearest crossing, except on an edge with both ends inside,
  // where the upper end owns everything above the lowest crossing (every interval between two
  // crossings stays material: a sliver between them belongs to the upper node's piece).
  double t_cut = -1.0;
  if (cut != nullptr) {
    const bool lower = side == 0 || in0;
    t_cut = lower ? cut->t_lo : cut->t_hi;
    consider(t_cut, (lower ? cut->normal_lo : cut->normal_hi).cast<double>());
  }
  if (best < 0.0 || best > 1.0) return false;
  t = best;
  if (from_cut != nullptr) *from_cut = cut != nullptr && best == t_cut;
  // Outward: from the end node toward the boundary.
  if (normal[axis] * (side ? -1.0 : 1.0) < 0.0) normal = -normal;
  return true;
}

// Whether an uncut edge has the half-edge at end `side` (as half_edge_param decides it).
bool uncut_half_edge(const VoxelModel& model, uint32_t edge, int side) {
  const uint32_t n0 = edge / 3;
  const bool in0 = model.is_inside(n0), in1 = model.is_inside(n0 + node_stride(model.lattice, int(edge % 3)));
  return in0 != in1 && (side ? in1 : in0);
}

// The surface of one voxel: its half-edges (slot h = 2 * voxel edge + side) and their patches.
struct VoxelPatches {
  uint32_t present = 0;  // bit h: the half-edge exists
  Vec3d point[24], normal[24];  // scene coordinates; outward normal
  uint8_t patch_of[24];  // patch of each present half-edge
  uint8_t patch_count = 0;
  uint32_t patch_half_edges[kMaxPatches];  // bit h: the patch holds half-edge h
  uint8_t patch_piece[kMaxPatches];
  uint16_t partial = 0;  // bit p: patch p holds both half-edges of a cut edge (the slit's tip is here)
};

// Voxel edges whose two corners differ in sign, by the voxel's inside corners.
constexpr std::array<uint16_t, 256> make_sign_change_edges() {
  std::array<uint16_t, 256> t{};
  for (int bits = 0; bits < 256; ++bits) {
    for (int e = 0; e < 12; ++e) {
      if (((bits >> kVoxelEdges[e].c0) & 1) != ((bits >> kVoxelEdges[e].c1) & 1)) t[size_t(bits)] |= uint16_t(1u << e);
    }
  }
  return t;
}
constexpr std::array<uint16_t, 256> kSignChangeEdges = make_sign_change_edges();

// Half-edge slots (bits 2e, 2e+1) of the four edges of each face.
constexpr std::array<uint32_t, 6> make_face_slots() {
  std::array<uint32_t, 6> slots{};
  for (int f = 0; f < 6; ++f) {
    for (int i = 0; i < 4; ++i) slots[size_t(f)] |= 3u << (2 * kFaceEdges.edge[f][i]);
  }
  return slots;
}
constexpr std::array<uint32_t, 6> kFaceSlots = make_face_slots();

// Number of half-edge points on face f's perimeter.
int face_point_count(uint32_t present, int f) {
  // (a bit count written out: std::popcount is a library call without a popcount instruction)
  uint32_t x = present & kFaceSlots[size_t(f)];
  x = x - ((x >> 1) & 0x55555555u);
  x = (x & 0x33333333u) + ((x >> 2) & 0x33333333u);
  x = (x + (x >> 4)) & 0x0F0F0F0Fu;
  return int((x * 0x01010101u) >> 24);
}

// Voxel edges holding a half-edge (bit e: slot 2e or 2e+1 present).
uint32_t present_edges(uint32_t present) {
  uint32_t edges = 0;
  for (uint32_t bits = (present | (present >> 1)) & 0x555555u; bits; bits &= bits - 1) {
    edges |= 1u << (std::countr_zero(bits) / 2);
  }
  return edges;
}

// The half-edge points of face f's perimeter in cyclic order (corner k0 -> k1 -> k2 -> k3): slots h.
// Returns their count (even: each point is a switch between inside and outside).
int face_perimeter(uint32_t present, int f, int pts[8]) {
  int k = 0;
  for (int i = 0; i < 4; ++i) {
    const int e = kFaceEdges.edge[f][i];
    const bool forward = kVoxelEdges[e].c0 == kVoxelFaceCorners[f][i];
    const int first = forward ? 2 * e : 2 * e + 1, second = forward ? 2 * e + 1 : 2 * e;
    if ((present >> first) & 1u) pts[k++] = first;
    if ((present >> second) & 1u) pts[k++] = second;
  }
  return k;
}

// Curve merges of the faces of a voxel: partner[f][m] is the curve that curve m of face f is merged
// with (kNoPartner: none).
struct FaceMerges {
  static constexpr int8_t kNoPartner = -1;
  int8_t partner[6][4];
  FaceMerges() {
    for (auto& face : partner) std::fill(face, face + 4, kNoPartner);
  }
};

// Pairs the half-edge points of each face (the curves the surface draws on it; the rule depends only
// on the face's own data, so both voxels sharing it agree): the arcs of the perimeter alternate
// between inside and outside; an ambiguous face whose diagonal joins (voxel_material_joins) pairs the
// ends of each outside arc (the inside corners meet across it), every other face the ends of each
// inside arc. Curves m and j merged (see voxel_patches) pair the end of arc m with the start of arc
// j and the end of arc j with the start of arc m instead: the two arcs meet across the face, the
// arcs between them keep their curves (nested, never crossing). The cycles of pairs are the patches.
void pair_faces(uint8_t in_bits, uint16_t cut_edges, uint32_t present, const FaceMerges& merges, uint8_t parent[24]) {
  const auto unite = [&](int x, int y) { uf_unite(parent, uint8_t(x), uint8_t(y)); };
  const uint8_t joins = voxel_material_joins(in_bits, cut_edges);
  for (int f = 0; f < 6; ++f) {
    if (face_point_count(present, f) < 2) continue;
    int pts[8];
    const int k = face_perimeter(present, f, pts);
    const bool start_inside = (in_bits >> kVoxelFaceCorners[f][0]) & 1u;
    const bool joined = (joins >> f) & 1u;
    // The arc from point j to point j+1 is inside when start_inside != (j even); it is paired
    // when that differs from `joined`: the first paired arc starts at j0.
    const int j0 = ((!start_inside) != joined) ? 0 : 1;
    const auto start = [&](int m) { return pts[(j0 + 2 * m) % k]; };
    const auto end = [&](int m) { return pts[(j0 + 2 * m + 1) % k]; };
    for (int m = 0; m < k / 2; ++m) {
      const int j = merges.partner[f][m];
      if (j == FaceMerges::kNoPartner) {
        unite(start(m), end(m));
      } else if (m < j) {
        unite(end(m), start(j));
        unite(end(j), start(m));
      }
    }
  }
}

// Numbers the patches (cycles of face pairs) in order of their lowest half-edge.
void number_patches(uint8_t in_bits, uint16_t face_cut_edges, uint16_t cut_edges, const FaceMerges& merges,
                    const uint8_t corner_piece[8], VoxelPatches& out) {
  out.partial = 0;
  out.patch_count = 0;
  if (out.present == 0) return;
  uint8_t parent[24];
  for (int h = 0; h < 24; ++h) parent[h] = uint8_t(h);
  pair_faces(in_bits, face_cut_edges, out.present, merges, parent);
  uint8_t id_of_root[24];
  std::fill(id_of_root, id_of_root + 24, uint8_t(0xFF));
  for (int h = 0; h < 24; ++h) {
    if (!((out.present >> h) & 1u)) continue;
    const int r = uf_find(parent, uint8_t(h));
    if (id_of_root[r] == 0xFF) {
      const uint8_t p = out.patch_count < kMaxPatches ? out.patch_count++ : uint8_t(kMaxPatches - 1);
      id_of_root[r] = p;
      out.patch_half_edges[p] = 0;
      const VoxelEdge& ve = kVoxelEdges[h / 2];
      out.patch_piece[p] = corner_piece[h % 2 ? ve.c1 : ve.c0];
    }
    out.patch_of[h] = id_of_root[r];
    out.patch_half_edges[id_of_root[r]] |= 1u << h;
  }
  for (int e = 0; e < 12; ++e) {
    if (((cut_edges >> e) & 1u) && ((out.present >> (2 * e)) & 3u) == 3u && out.patch_of[2 * e] == out.patch_of[2 * e + 1]) {
      out.partial = uint16_t(out.partial | (1u << out.patch_of[2 * e]));
    }
  }
}

// The voxel's own data for its patches: inside corners, pieces, cut and air edges.
struct VoxelData {
  uint8_t in_bits = 0;
  uint8_t corner_piece[8];
  uint16_t cut_edges = 0, air_edges = 0;
  bool divided = false;
};

void voxel_data(const VoxelModel& model, const CutState& state, uint32_t voxel, const int32_t vc[3], VoxelData& out) {
  const uint32_t d = state.divided_of.get(voxel);
  out.divided = d != kDeadIndex;
  if (out.divided) {
    const DividedVoxel& dv = state.divided[d];
    std::copy(dv.corner_piece, dv.corner_piece + 8, out.corner_piece);
    out.in_bits = 0;
    for (int c = 0; c < 8; ++c) out.in_bits = uint8_t(out.in_bits | (dv.corner_piece[c] != kNoPiece ? 1u << c : 0u));
    out.cut_edges = dv.cut_edges;
    out.air_edges = dv.air_edges;
    return;
  }
  // Uncut: one implicit piece of all inside corners.
  out.in_bits = corner_inside_bits(model, vc);
  for (int c = 0; c < 8; ++c) out.corner_piece[c] = (out.in_bits >> c) & 1u ? 0 : kNoPiece;
  out.cut_edges = out.air_edges = 0;
}

// The half-edges a voxel has, from its signs and cut edges alone (as half_edge_param decides them):
// an inside end of an edge that has a boundary (a sign change or a cut).
uint32_t half_edge_presence(uint8_t in_bits, uint16_t cut_edges) {
  uint32_t present = 0;
  for (int e = 0; e < 12; ++e) {
    const bool in0 = (in_bits >> kVoxelEdges[e].c0) & 1u, in1 = (in_bits >> kVoxelEdges[e].c1) & 1u;
    if (in0 == in1 && !((cut_edges >> e) & 1u)) continue;
    present |= (in0 ? 1u : 0u) << (2 * e);
    present |= (in1 ? 1u : 0u) << (2 * e + 1);
  }
  return present;
}

// A pair of curves of one face that belong to one patch: a candidate for a merge.
struct CurvePair {
  uint8_t face, m, j;  // curves m < j
  uint8_t point_m, point_j;  // a half-edge slot on each
};

// The candidate pairs of the voxel's faces (at most 6 per face: four curves).
int doubled_curves(const VoxelData& data, const VoxelPatches& patches, CurvePair out[36]) {
  int count = 0;
  const uint8_t joins = voxel_material_joins(data.in_bits, uint16_t(data.cut_edges | data.air_edges));
  for (int f = 0; f < 6; ++f) {
    if (face_point_count(patches.present, f) < 4) continue;
    int pts[8];
    const int k = face_perimeter(patches.present, f, pts);
    const bool start_inside = (data.in_bits >> kVoxelFaceCorners[f][0]) & 1u;
    const int j0 = ((!start_inside) != bool((joins >> f) & 1u)) ? 0 : 1;
    for (int m = 0; m < k / 2; ++m) {
      for (int j = m + 1; j < k / 2; ++j) {
        const int a = pts[(j0 + 2 * m) % k], b = pts[(j0 + 2 * j) % k];
        if (patches.patch_of[a] == patches.patch_of[b]) {
          out[count++] = CurvePair{uint8_t(f), uint8_t(m), uint8_t(j), uint8_t(a), uint8_t(b)};
        }
      }
    }
  }
  return count;
}

// The shape of a voxel (PatchShape): pieces, half-edges and patches by the face rule (before merges).
// `divided`: pieces are the material graph's components; otherwise one implicit piece.
void make_shape(uint8_t in_bits, uint16_t cut_edges, uint16_t air_edges, bool divided, PatchShape& out) {
  VoxelData data;
  data.in_bits = in_bits;
  data.cut_edges = cut_edges;
  data.air_edges = air_edges;
  data.divided = divided;
  out.piece_partial = 0;
  if (divided) {
    material_components(in_bits, cut_edges, air_edges, data.corner_piece, out.piece_count, out.piece_partial);
  } else {
    for (int c = 0; c < 8; ++c) data.corner_piece[c] = (in_bits >> c) & 1u ? 0 : kNoPiece;
    out.piece_count = in_bits != 0 ? 1 : 0;
  }
  VoxelPatches patches;
  std::fill(patches.patch_of, patches.patch_of + 24, uint8_t(0xFF));  // absent half-edges: no patch
  patches.present = half_edge_presence(in_bits, cut_edges);
  number_patches(in_bits, uint16_t(cut_edges | air_edges), cut_edges, FaceMerges{}, data.corner_piece, patches);
  CurvePair pairs[36];
  out.present = patches.present;
  out.patch_count = patches.patch_count;
  out.patch_partial = patches.partial;
  out.doubled = doubled_curves(data, patches, pairs) > 0;
  std::copy(data.corner_piece, data.corner_piece + 8, out.corner_piece);
  std::copy(patches.patch_of, patches.patch_of + 24, out.patch_of);
  std::fill(out.patch_half_edges, out.patch_half_edges + kMaxPatches, 0u);
  std::fill(out.patch_piece, out.patch_piece + kMaxPatches, kNoPiece);
  std::copy(patches.patch_half_edges, patches.patch_half_edges + patches.patch_count, out.patch_half_edges);
  std::copy(patches.patch_piece, patches.patch_piece + patches.patch_count, out.patch_piece);
}

// Uncut voxels' shapes depend on their inside corners alone: one table of the 256 cases, so building
// the surface and refreshing the voxels around a cut never pair faces for an uncut voxel, and one
// whose faces hold no doubled curve skips the merge search.
const PatchShape& uncut_shape(uint8_t in_bits) {
  static const std::vector<PatchShape> table = [] {
    std::vector<PatchShape> t(256);
    for (int bits = 0; bits < 256; ++bits) make_shape(uint8_t(bits), 0, 0, false, t[size_t(bits)]);
    return t;
  }();
  return table[in_bits];
}

uint64_t shape_key(uint8_t in_bits, uint16_t cut_edges, uint16_t air_edges) {
  return uint64_t(in_bits) | uint64_t(cut_edges) << 8 | uint64_t(air_edges) << 20;
}

// A divided voxel's shape from the memo, computed and kept when new (refresh_voxels: every divided
// voxel passes here before its patches are read).
const PatchShape& divided_shape(CutState& state, uint8_t in_bits, uint16_t cut_edges, uint16_t air_edges) {
  const uint64_t key = shape_key(in_bits, cut_edges, air_edges);
  uint32_t i = state.shape_of.get(key);
  if (i == kDeadIndex) {
    i = uint32_t(state.shapes.size());
    state.shapes.emplace_back();
    make_shape(in_bits, cut_edges, air_edges, true, state.shapes.back());
    state.shape_of.set(key, i);
  }
  return state.shapes[i];
}

// Patches by the face rule alone (no merges) from the voxel's data: the table for uncut voxels, the
// memo for divided ones (computed here when absent). Returns whether merges are possible.
bool rule_patches(const CutState& state, const VoxelData& data, VoxelPatches& out) {
  PatchShape local;
  const PatchShape* shape = &local;
  if (!data.divided) {
    shape = &uncut_shape(data.in_bits);
  } else {
    const uint32_t i = state.shape_of.get(shape_key(data.in_bits, data.cut_edges, data.air_edges));
    if (i != kDeadIndex) {
      shape = &state.shapes[i];
    } else {
      make_shape(data.in_bits, data.cut_edges, data.air_edges, true, local);
    }
  }
  out.present = shape->present;
  out.patch_count = shape->patch_count;
  out.partial = shape->patch_partial;
  std::copy(shape->patch_of, shape->patch_of + 24, out.patch_of);
  std::copy(shape->patch_half_edges, shape->patch_half_edges + shape->patch_count, out.patch_half_edges);
  std::copy(shape->patch_piece, shape->patch_piece + shape->patch_count, out.patch_piece);
  return shape->doubled;
}

// Patches by the face rule alone (no merges), with the Hermite data of every half-edge.
bool base_patches(const VoxelModel& model, const CutState& state, uint32_t voxel, const int32_t vc[3], VoxelData& data,
                  VoxelPatches& out) {
  const Lattice& l = model.lattice;
  voxel_data(model, state, voxel, vc, data);
  const bool doubled = rule_patches(state, data, out);
  const Vec3d origin = l.node_position(vc[0], vc[1], vc[2]);
  for (uint32_t edges = present_edges(out.present); edges; edges &= edges - 1) {
    const int e = std::countr_zero(edges);
    const VoxelEdge& ve = kVoxelEdges[e];
    const uint32_t edge = voxel_edge_id(l, vc, e);
    const EdgeCut* cut = (data.cut_edges >> e) & 1u ? find_cut(state, edge) : nullptr;
    for (int side = 0; side < 2; ++side) {
      double t = 0.0;
      const int h = 2 * e + side;
      if (!((out.present >> h) & 1u)) continue;
      // half_edge_presence and half_edge_param agree: every present half-edge has its point.
      half_edge_param(model, cut, edge, side, t, out.normal[h]);
      Vec3d p = origin + l.voxel_size * Vec3d(ve.c0 & 1, (ve.c0 >> 1) & 1, (ve.c0 >> 2) & 1);
      p[ve.axis] += t * l.voxel_size;
      out.point[h] = p;
    }
  }
  return doubled;
}

// Base patches without the Hermite data (no crossing lookups): enough to compare patch membership.
void topology_patches(const VoxelModel& model, const CutState& state, uint32_t voxel, const int32_t vc[3],
                      VoxelData& data, VoxelPatches& out) {
  voxel_data(model, state, voxel, vc, data);
  rule_patches(state, data, out);
}

// The same half-edge slot seen from the voxel across face f (2 * axis + s).
int slot_across(int h, int f) {
  const int flip = 1 << (f / 2);
  const VoxelEdge& ve = kVoxelEdges[h / 2];
  return 2 * edge_between(ve.c0 ^ flip, ve.c1 ^ flip) + h % 2;
}

// Half-edges, pieces and patches of a voxel. Where two consecutive curves on a face belong to one
// patch on both sides of it, the dual edge between the two patches would be used by four quads
// (not a manifold: a tunnel through the face, or a slit whose two sides meet again in both voxels);
// those two curves are merged (their arcs meet across the face: for a face of four points, its
// other pairing), which cannot double on either side (the arcs inside and outside cannot both be
// connected through a voxel). Both voxels decide from the same base patches, so they agree.
// Returns true when a face was changed.
bool voxel_patches(const VoxelModel& model, const CutState& state, uint32_t voxel, const int32_t vc[3],
                   VoxelPatches& out) {
  VoxelData data;
  if (!base_patches(model, state, voxel, vc, data, out)) return false;
  CurvePair pairs[36];
  const int count = doubled_curves(data, out, pairs);
  if (count == 0) return false;
  FaceMerges merges;
  bool any = false;
  const int32_t dims[3] = {model.lattice.nx, model.lattice.ny, model.lattice.nz};
  int other_face = -1;  // the face whose neighbour `other` holds
  VoxelData other_data;
  VoxelPatches other;
  for (int i = 0; i < count; ++i) {
    const CurvePair& c = pairs[i];
    int32_t nc[3] = {vc[0], vc[1], vc[2]};
    nc[c.face / 2] += c.face % 2 ? 1 : -1;
    if (nc[c.face / 2] < 0 || nc[c.face / 2] >= dims[c.face / 2]) continue;
    if (other_face != c.face) {
      topology_patches(model, state, model.lattice.voxel(nc[0], nc[1], nc[2]), nc, other_data, other);
      other_face = c.face;
    }
    const int a = slot_across(c.point_m, c.face), b = slot_across(c.point_j, c.face);
    if (!((other.present >> a) & 1u) || !((other.present >> b) & 1u) || other.patch_of[a] != other.patch_of[b]) continue;
    // Doubled on both sides: merge, unless it overlaps or crosses a merge already made.
    int8_t* partner = merges.partner[c.face];
    bool free = partner[c.m] == FaceMerges::kNoPartner && partner[c.j] == FaceMerges::kNoPartner;
    for (int m = 0; m < 4 && free; ++m) {
      const int j = partner[m];
      if (j > m) free = !((m < c.m && c.m < j && j < c.j) || (c.m < m && m < c.j && c.j < j));
    }
    if (!free) continue;
    partner[c.m] = int8_t(c.j);
    partner[c.j] = int8_t(c.m);
    any = true;
  }
  if (any) number_patches(data.in_bits, uint16_t(data.cut_edges | data.air_edges), data.cut_edges, merges, data.corner_piece, out);
  return any;
}

// Faces of a voxel with two or more curves: a change of this voxel can change their pairing for
// the voxel across.
uint8_t four_point_faces(uint32_t present) {
  uint8_t faces = 0;
  for (int f = 0; f < 6; ++f) faces = uint8_t(faces | (face_point_count(present, f) >= 4 ? 1u << f : 0u));
  return faces;
}

// Position of patch p's vertex.
Vec3f patch_vertex_position(const VoxelModel& model, const CutState& state, uint32_t voxel, const int32_t vc[3],
                            const VoxelPatches& patches, uint8_t p) {
  const Lattice& l = model.lattice;
  const Vec3d lo = l.node_position(vc[0], vc[1], vc[2]);
  const Vec3d hi = lo + Vec3d::Constant(l.voxel_size);
  // A partly cut patch sits on the cut front (the average of its face points).
  if ((patches.partial >> p) & 1u) {
    const uint32_t f = state.front_of.get(voxel);
    if (f != kDeadIndex) {
      const VoxelFront& front = state.fronts[f];
      const uint32_t n = front.trail_count + front.blade_count;
      if (n > 0) {
        const Vec3d mean = ((front.trail_sum + front.blade_sum) / float(n)).cast<double>();
        return mean.cwiseMax(lo).cwiseMin(hi).cast<float>();
      }
    }
  }
  // Fully cut (or uncut) patch: the dual contouring vertex rule, in the voxel's local frame.
  Vec3d points[24], normals[24];
  int count = 0;
  for (uint32_t bits = patches.patch_half_edges[p]; bits; bits &= bits - 1) {
    const int h = std::countr_zero(bits);
    points[count] = (patches.point[h] - lo) / l.voxel_size;
    normals[count++] = patches.normal[h];
  }
  const Vec3d local = place_voxel_vertex(points, normals, count, state.contour);
  return (lo + l.voxel_size * local).cast<float>();
}

// The quads of one lattice edge's two half-edges, as refresh_voxels writes them and
// check_cut_state expects them.
struct EdgeQuads {
  bool exists[2] = {false, false};  // the half-edge exists and all its patches have vertices
  bool missing[2] = {false, false};  // the half-edge exists but a sharing patch has no vertex
  uint32_t v[2][4];                 // vertices, counter-clockwise seen from outside
  int diagonal[2] = {-1, -1};       // forced split (see write_quad)
  bool on_cut[2] = {false, false};
};

// Two quads of a slit edge that join the same four patches are the two faces of a slit of zero
// width: they cancel. Two that share one diagonal are split along the other (a diagonal is used
// by the two triangles of each quad; shared, it would be a non-manifold edge).
void plan_edge_quads(const VoxelModel& model, const CutState& state, uint32_t edge, const EdgeCut* cut,
                     const uint32_t around[4], const uint8_t corners[4], EdgeQuads& out) {
  const CutSurface& s = state.surface;
  const int axis = int(edge % 3);
  uint32_t ring[2][4];  // vertices in the ring order about the axis
  for (int side = 0; side < 2; ++side) {
    double t;
    Vec3d normal;
    uint8_t pieces[4];
    // (an uncut edge: the half-edge exists at an inside end of a sign change, never on the cut)
    const bool present = cut != nullptr ? half_edge_param(model, cut, edge, side, t, normal, &out.on_cut[side])
                                        : uncut_half_edge(model, edge, side);
    if (!present || !sharing_pieces(model, state, edge, side, around, corners, pieces)) continue;
    bool ok = true;
    for (int q = 0; q < 4; ++q) {
      const int h = 2 * voxel_edge_index(axis, corners[q]) + side;
      ring[side][q] = vertex_holding(s, around[q], h);
      ok = ok && ring[side][q] != kDeadIndex;
    }
    out.exists[side] = ok;
    out.missing[side] = !ok;
  }
  if (out.exists[0] && out.exists[1]) {
    const bool d02 = ring[0][0] == ring[1][0] && ring[0][2] == ring[1][2];
    const bool d13 = ring[0][1] == ring[1][1] && ring[0][3] == ring[1][3];
    if (d02 && d13) {
      out.exists[0] = out.exists[1] = false;
    } else if (d02) {
      out.diagonal[0] = out.diagonal[1] = 1;
    } else if (d13) {
      out.diagonal[0] = out.diagonal[1] = 0;
    }
  }
  for (int side = 0; side < 2; ++side) {
    if (!out.exists[side]) continue;
    std::copy(ring[side], ring[side] + 4, out.v[side]);
    if (side == 1) std::swap(out.v[1][1], out.v[1][3]);  // outward normal along -axis: reverse the winding
  }
}

// Patches and vertices of one voxel (its pieces already up to date). Returns its half-edge mask.
uint32_t refresh_voxel_vertices(const VoxelModel& model, CutState& state, uint32_t voxel, CutStepStats& stats) {
  CutSurface& s = state.surface;
  int32_t vc[3];
  model.lattice.voxel_coords(voxel, vc);
  VoxelPatches patches;
  voxel_patches(model, state, voxel, vc, patches);
  uint32_t p = 0;
  for (; p < patches.patch_count; ++p) {
    const uint64_t key = patch_key(voxel, p);
    const Vec3f position = patch_vertex_position(model, state, voxel, vc, patches, uint8_t(p));
    const uint64_t piece = piece_key(voxel, patches.patch_piece[p]);
    bool created = false;
    const uint32_t slot = ensure_vertex(s, key, created);
    if (created || s.positions[slot] != position || s.vertex_piece[slot] != piece ||
        s.vertex_half_edges[slot] != patches.patch_half_edges[p]) {
      s.positions[slot] = position;
      s.vertex_piece[slot] = piece;
      s.vertex_half_edges[slot] = patches.patch_half_edges[p];
      mark_vertex_dirty(s, slot);
      state.changed_vertices.push_back(slot);
      ++stats.vertices_changed;
    }
  }
  // Patches that no longer exist.
  for (; p < uint32_t(kMaxPatches); ++p) {
    const uint64_t key = patch_key(voxel, p);
    const uint32_t slot = s.vertex_of_patch.get(key);
    if (slot == kDeadIndex) break;
    free_vertex(s, key);
    state.changed_vertices.push_back(slot);
    ++stats.vertices_changed;
  }
  return patches.present;
}

// Recomputes pieces, patches, vertices and quads of the given voxels (sorted, unique) and of the
// edges they hold; adds the voxels across their four-point faces (whose pairing may toggle with
// them, see voxel_patches). Returns counts of changed slots through stats.
void refresh_voxels(const VoxelModel& model, CutState& state, std::vector<uint32_t>& voxels, CutStepStats& stats,
                    std::vector<uint32_t>* changed_corners) {
  const Lattice& l = model.lattice;
  CutSurface& s = state.surface;
  std::vector<uint32_t>& across = state.scratch_across;
  across.clear();
  const int32_t dims[3] = {l.nx, l.ny, l.nz};
  // Pieces first: a voxel's patches look at the pieces of the voxels across its faces.
  for (uint32_t voxel : voxels) {
    const uint32_t d = state.divided_of.get(voxel);
    if (d == kDeadIndex) continue;
    int32_t vc[3];
    l.voxel_coords(voxel, vc);
    DividedVoxel& dv = state.divided[d];
    const PatchShape& shape = divided_shape(state, corner_inside_bits(model, vc), dv.cut_edges, dv.air_edges);
    std::copy(shape.corner_piece, shape.corner_piece + 8, dv.corner_piece);
    dv.piece_count = shape.piece_count;
    dv.partial_mask = shape.piece_partial;
  }
  for (uint32_t voxel : voxels) {
    const uint8_t faces = four_point_faces(refresh_voxel_vertices(model, state, voxel, stats));
    if (faces == 0) continue;
    int32_t vc[3];
    l.voxel_coords(voxel, vc);
    for (int f = 0; f < 6; ++f) {
      int32_t nc[3] = {vc[0], vc[1], vc[2]};
      nc[f / 2] += f % 2 ? 1 : -1;
      if (!((faces >> f) & 1u) || nc[f / 2] < 0 || nc[f / 2] >= dims[f / 2]) continue;
      const uint32_t other = l.voxel(nc[0], nc[1], nc[2]);
      if (!std::binary_search(voxels.begin(), voxels.end(), other)) across.push_back(other);
    }
  }
  if (!across.empty()) {
    sorted_unique(across);
    for (uint32_t voxel : across) refresh_voxel_vertices(model, state, voxel, stats);
    const size_t n = voxels.size();
    voxels.insert(voxels.end(), across.begin(), across.end());
    std::inplace_merge(voxels.begin(), voxels.begin() + std::ptrdiff_t(n), voxels.end());
  }

  // Edges of these voxels: one quad per existing half-edge. Each edge is handled once, by the
  // lowest voxel of the list around it (the list is sorted; a long one, as when the surface is
  // built, is looked up in a bitset).
  std::vector<uint64_t> listed;
  if (voxels.size() > 4096) {
    listed.assign((l.voxel_count() + 63) / 64, 0);
    for (uint32_t v : voxels) listed[v >> 6] |= uint64_t(1) << (v & 63);
  }
  const auto in_list = [&](uint32_t v) {
    return listed.empty() ? std::binary_search(voxels.begin(), voxels.end(), v) : bool((listed[v >> 6] >> (v & 63)) & 1u);
  };
  for (uint32_t voxel : voxels) {
    int32_t vc[3];
    l.voxel_coords(voxel, vc);
    const uint32_t d = state.divided_of.get(voxel);
    const uint16_t cut_edges = d != kDeadIndex ? state.divided[d].cut_edges : 0;
    // Only surface edges and cut edges ever hold a quad (cuts are never undone).
    for (uint32_t edges = kSignChangeEdges[corner_inside_bits(model, vc)] | cut_edges; edges; edges &= edges - 1) {
      const int e = std::countr_zero(edges);
      const bool cut_edge = (cut_edges >> e) & 1u;
      uint32_t around[4];
      uint8_t corners[4];
      voxels_around_voxel_edge(l, vc, e, around, corners);
      bool owner = true;
      for (int q = 0; q < 4 && owner; ++q) {
        owner = !(around[q] < voxel && in_list(around[q]));
      }
      if (!owner) continue;
      const uint32_t edge = voxel_edge_id(l, vc, e);
      const EdgeCut* cut = cut_edge ? find_cut(state, edge) : nullptr;
      EdgeQuads quads;
      plan_edge_quads(model, state, edge, cut, around, corners, quads);
      for (int side = 0; side < 2; ++side) {
        const uint64_t key = half_edge_key(edge, side);
        if (quads.exists[side]) {
          if (write_quad(s, key, quads.v[side], quads.on_cut[side], quads.diagonal[side], changed_corners)) {
            stats.triangles_changed += 2;
          }
        } else if (free_quad(s, key, changed_corners)) {
          stats.triangles_changed += 2;
        }
      }
    }
  }
}

// ---- Cuts on edges -------------------------------------------------------------------------

// True when a surface edge bounds an ambiguous face (two diagonal inside corners): only there does a
// blade crossing outside the material change what is joined (voxel_material_joins).
bool on_ambiguous_face(const VoxelModel& model, uint32_t edge) {
  const Lattice& l = model.lattice;
  const int axis = int(edge % 3);
  const uint32_t n0 = edge / 3, n1 = n0 + node_stride(l, axis);
  const bool in0 = model.is_inside(n0);
  int32_t c[3];
  l.node_coords(n0, c);
  const int32_t dims[3] = {l.nx, l.ny, l.nz};
  for (int k = 1; k <= 2; ++k) {
    const int b = (axis + k) % 3;
    for (int s = -1; s <= 1; s += 2) {
      if (c[b] + s < 0 || c[b] + s > dims[b]) continue;
      const uint32_t step = node_stride(l, b);
      const uint32_t m0 = s > 0 ? n0 + step : n0 - step, m1 = s > 0 ? n1 + step : n1 - step;
      if (model.is_inside(m0) != in0 && model.is_inside(m1) == in0) return true;
    }
  }
  return false;
}

// The nodes inside node n is linked to in the material graph with `edge` severed: the uncut lattice
// edges to inside neighbours, and the ambiguous faces that join n to their diagonal corner
// (voxel_material_joins: a face none of whose edges is cut or crossed in the air). Returns the count
// (at most 6 + 12).
int material_links(const VoxelModel& model, const CutState& state, uint32_t n, uint32_t edge, uint32_t out[18]) {
  const Lattice& l = model.lattice;
  int32_t c[3];
  l.node_coords(n, c);
  const int32_t dims[3] = {l.nx, l.ny, l.nz};
  const auto severed = [&](uint32_t e) { return e == edge || state.edge_cut_of.contains(e) || state.air_edges.contains(e); };
  int count = 0;
  for (int a = 0; a < 3; ++a) {
    const uint32_t step = node_stride(l, a);
    if (c[a] < dims[a]) {
      const uint32_t e = Lattice::edge(n, a);
      if (e != edge && model.is_inside(n + step) && !state.edge_cut_of.contains(e)) out[count++] = n + step;
    }
    if (c[a] > 0) {
      const uint32_t e = Lattice::edge(n - step, a);
      if (e != edge && model.is_inside(n - step) && !state.edge_cut_of.contains(e)) out[count++] = n - step;
    }
  }
  for (int a = 0; a < 3; ++a) {
    for (int b = a + 1; b < 3; ++b) {
      for (int sa = -1; sa <= 1; sa += 2) {
        for (int sb = -1; sb <= 1; sb += 2) {
          if (c[a] + sa < 0 || c[a] + sa > dims[a] || c[b] + sb < 0 || c[b] + sb > dims[b]) continue;
          const uint32_t na = sa > 0 ? n + node_stride(l, a) : n - node_stride(l, a);
          const uint32_t nb = sb > 0 ? n + node_stride(l, b) : n - node_stride(l, b);
          const uint32_t nd = sb > 0 ? na + node_stride(l, b) : na - node_stride(l, b);
          if (!model.is_inside(nd) || model.is_inside(na) || model.is_inside(nb)) continue;
          // The face's edges, each from its lower node.
          const uint32_t e0 = Lattice::edge(sa > 0 ? n : na, a), e1 = Lattice::edge(sb > 0 ? n : nb, b);
          const uint32_t e2 = Lattice::edge(sb > 0 ? na : nd, b), e3 = Lattice::edge(sa > 0 ? nb : nd, a);
          if (!severed(e0) && !severed(e1) && !severed(e2) && !severed(e3)) out[count++] = nd;
        }
      }
    }
  }
  return count;
}

// Most nodes of a crumb: a cut leaving a component of this many nodes or fewer makes a crumb.
constexpr int kCrumbNodes = 4;

// Whether severing `edge` would leave inside node n in a component of at most kCrumbNodes nodes
// (a closed bit below the lattice's resolution: the organ's surface lies within a voxel or two of the
// cut on n's side). A flood fill over the material graph from n that stops as soon as it finds a
// node past kCrumbNodes. The divide does not make such a cut, so those nodes stay with the material across
// the edge (the mass is unchanged: nothing is dropped). A slit re-cut anywhere along it crosses only
// edges cut already or edges like this one: it sheds nothing.
bool last_material_link(const VoxelModel& model, const CutState& state, uint32_t n, uint32_t edge) {
  uint32_t found[kCrumbNodes];
  int count = 1, next = 0;
  found[0] = n;
  while (next < count) {
    uint32_t links[18];
    const int k = material_links(model, state, found[next++], edge, links);
    for (int i = 0; i < k; ++i) {
      if (std::find(found, found + count, links[i]) != found + count) continue;
      if (count == kCrumbNodes) return false;  // large enough
      found[count++] = links[i];
    }
  }
  return true;
}

// Whether severing `edge` (a cut of a surface edge, or a crossing in the air) would take the last link
// of an inside corner of an ambiguous face around it: the face no longer joins its diagonal.
bool isolates_diagonal(const VoxelModel& model, const CutState& state, uint32_t edge) {
  const Lattice& l = model.lattice;
  const int a = int(edge % 3);
  const uint32_t n0 = edge / 3, n1 = n0 + node_stride(l, a);
  int32_t c[3];
  l.node_coords(n0, c);
  const int32_t dims[3] = {l.nx, l.ny, l.nz};
  for (int k = 1; k <= 2; ++k) {
    const int b = (a + k) % 3;
    for (int sb = -1; sb <= 1; sb += 2) {
      if (c[b] + sb < 0 || c[b] + sb > dims[b]) continue;
      const uint32_t m0 = sb > 0 ? n0 + node_stride(l, b) : n0 - node_stride(l, b);
      const uint32_t m1 = sb > 0 ? n1 + node_stride(l, b) : n1 - node_stride(l, b);
      const bool i0 = model.is_inside(n0), i1 = model.is_inside(n1), j0 = model.is_inside(m0), j1 = model.is_inside(m1);
      if (!(i0 == j1 && i1 == j0 && i0 != i1)) continue;  // not ambiguous
      const uint32_t p = i0 ? n0 : n1, q = i0 ? m1 : m0;   // the face's inside corners
      if (last_material_link(model, state, p, edge) || last_material_link(model, state, q, edge)) return true;
    }
  }
  return false;
}

// What one blade crossing did to its edge.
enum class EdgeChange { kNone, kCut, kAir };

// Applies one blade crossing to an edge: kCut when the cut state of the edge changed, kAir when a
// surface edge is crossed for the first time outside the material (no material is cut, but the
// face is: it no longer joins its ambiguous diagonal, voxel_material_joins).
EdgeChange record_cut(const VoxelModel& model, CutState& state, const EdgeHit& hit) {
  const Lattice& l = model.lattice;
  const uint32_t n0 = hit.edge / 3;
  const uint32_t n1 = n0 + node_stride(l, int(hit.edge % 3));
  const bool in0 = model.is_inside(n0), in1 = model.is_inside(n1);
  if (!in0 && !in1) return EdgeChange::kNone;  // the blade is in the air
  if (in0 != in1) {
    // On a surface edge only a cut between the inside node and the surface matters.
    const EdgeCrossing* c = model.find_crossing(hit.edge);
    const float ts = c ? c->t : 0.5f;
    if (in0 ? hit.t >= ts : hit.t <= ts) {
      if (!on_ambiguous_face(model, hit.edge) || state.air_edges.contains(hit.edge)) return EdgeChange::kNone;
      if (!state.edge_cut_of.contains(hit.edge) && isolates_diagonal(model, state, hit.edge)) return EdgeChange::kNone;
      state.air_edges.set(hit.edge, 0);
      return EdgeChange::kAir;
    }
  }
  const uint32_t i = state.edge_cut_of.get(hit.edge);
  if (i == kDeadIndex) {
    // No crumbs: a first cut of a material edge that would leave one of its nodes joined to no other
    // node is not made (the node stays with the other end: see last_material_link).
    if (in0 && in1 && (last_material_link(model, state, n0, hit.edge) || last_material_link(model, state, n1, hit.edge))) {
      return EdgeChange::kNone;
    }
    if (in0 != in1 && !state.air_edges.contains(hit.edge) && on_ambiguous_face(model, hit.edge) &&
        isolates_diagonal(model, state, hit.edge)) {
      return EdgeChange::kNone;
    }
    state.edge_cut_of.set(hit.edge, uint32_t(state.edge_cuts.size()));
    state.edge_cuts.push_back(EdgeCut{hit.edge, hit.t, hit.t, hit.normal, hit.normal});
    return EdgeChange::kCut;
  }
  EdgeCut& cut = state.edge_cuts[i];
  bool changed = false;
  if (hit.t < cut.t_lo) {
    cut.t_lo = hit.t;
    cut.normal_lo = hit.normal;
    changed = true;
  }
  if (hit.t > cut.t_hi) {
    cut.t_hi = hit.t;
    cut.normal_hi = hit.normal;
    changed = true;
  }
  return changed ? EdgeChange::kCut : EdgeChange::kNone;
}

// ---- The cut front --------------------------------------------------------------------------

// True when any corner of the voxel is inside (fronts are kept only where there is material).
bool has_material(const VoxelModel& model, uint32_t voxel) {
  int32_t vc[3];
  model.lattice.voxel_coords(voxel, vc);
  for (int c = 0; c < 8; ++c) {
    if (model.is_inside(corner_node(model.lattice, vc, c))) return true;
  }
  return false;
}

VoxelFront& front_for(CutState& state, uint32_t voxel) {
  uint32_t f = state.front_of.get(voxel);
  if (f == kDeadIndex) {
    f = uint32_t(state.fronts.size());
    state.front_of.set(voxel, f);
    state.fronts.push_back(VoxelFront{voxel, 0, 0, Vec3f::Zero(), Vec3f::Zero()});
  }
  return state.fronts[f];
}

// Walks segment p->q (scene coordinates) through the lattice and calls visit(voxel, point) for each
// face crossing (for both voxels sharing the face) and, when `ends` is set, for p and q in their voxels.
template <typename Visit>
void walk_segment(const Lattice& l, const Vec3d& p_scene, const Vec3d& q_scene, bool ends,
                  std::vector<double>& params, Visit&& visit) {
  const Vec3d p = (p_scene - l.origin) / l.voxel_size;
  const Vec3d q = (q_scene - l.origin) / l.voxel_size;
  const Vec3d d = q - p;
  const double dims[3] = {double(l.nx), double(l.ny), double(l.nz)};
  // Clip to the lattice box.
  double s0 = 0.0, s1 = 1.0;
  for (int a = 0; a < 3; ++a) {
    if (std::abs(d[a]) < 1e-300) {
      if (p[a] < 0.0 || p[a] > dims[a]) return;
      continue;
    }
    double e0 = (0.0 - p[a]) / d[a], e1 = (dims[a] - p[a]) / d[a];
    if (e0 > e1) std::swap(e0, e1);
    s0 = std::max(s0, e0);
    s1 = std::min(s1, e1);
  }
  if (!(s0 <= s1)) return;
  const auto voxel_at = [&](double s) {
    int32_t c[3];
    const int32_t n[3] = {l.nx, l.ny, l.nz};
    for (int a = 0; a < 3; ++a) c[a] = std::clamp(int32_t(std::floor(p[a] + s * d[a])), 0, n[a] - 1);
    return l.voxel(c[0], c[1], c[2]);
  };
  const auto scene_at = [&](double s) { return l.origin + l.voxel_size * (p + s * d); };
  // Parameters of the lattice planes crossed.
  params.clear();
  for (int a = 0; a < 3; ++a) {
    if (std::abs(d[a]) < 1e-300) continue;
    const double x0 = p[a] + s0 * d[a], x1 = p[a] + s1 * d[a];
    const double lo = std::min(x0, x1), hi = std::max(x0, x1);
    for (double plane = std::floor(lo) + 1.0; plane < hi; plane += 1.0) {
      params.push_back((plane - p[a]) / d[a]);
    }
  }
  std::sort(params.begin(), params.end());
  if (ends && s0 == 0.0) visit(voxel_at(0.0), scene_at(0.0));
  double previous = s0;
  for (double s : params) {
    if (s <= previous) continue;  // a corner crossing several planes at once is one crossing
    const Vec3d point = scene_at(s);
    visit(voxel_at(0.5 * (previous + s)), point);
    // The voxel after the crossing: look slightly ahead (next parameter or the end).
    const auto next = std::upper_bound(params.begin(), params.end(), s);
    const double after = next == params.end() ? s1 : *next;
    visit(voxel_at(0.5 * (s + after)), point);
    previous = s;
  }
  if (ends && s1 == 1.0) visit(voxel_at(1.0), scene_at(1.0));
}

// Records the front of a sweep from `from` to `to`: trail face points (kept) and the blade edge's
// points. The previous blade edge's points stay (a slit tip holds still) until the blade comes back
// to their voxel: every voxel when this sweep continues from where the last one ended, otherwise
// the voxels this sweep cuts or its front passes. Appends voxels whose front changed to `changed`.
void update_front(const VoxelModel& model, CutState& state, const BladePose& from, const BladePose& to,
                  std::vector<uint32_t>& changed) {
  const Lattice& l = model.lattice;
  const size_t first_new = changed.size();
  // Trails of the blade's ends.
  const auto add_trail = [&](uint32_t voxel, const Vec3d& point) {
    if (!has_material(model, voxel)) return;
    VoxelFront& f = front_for(state, voxel);
    f.trail_sum += point.cast<float>();
    ++f.trail_count;
    changed.push_back(voxel);
  };
  walk_segment(l, from.a, to.a, false, state.scratch_params, add_trail);
  walk_segment(l, from.b, to.b, false, state.scratch_params, add_trail);
  // The blade edge now, walked once: its points in voxels with material (added below, once the
  // parked points are settled) and its voxels (sorted, to know where the blade is).
  std::vector<uint32_t>& blade_voxel = state.scratch_blade_voxels;
  std::vector<Vec3f>& blade_point = state.scratch_blade_points;
  blade_voxel.clear();
  blade_point.clear();
  walk_segment(l, to.a, to.b, true, state.scratch_params, [&](uint32_t voxel, const Vec3d& point) {
    if (!blade_voxel.empty() && blade_voxel.back() == voxel) {
      blade_voxel.push_back(voxel);  // same voxel as the last point: material already known
    } else if (has_material(model, voxel)) {
      blade_voxel.push_back(voxel);
    } else {
      return;
    }
    blade_point.push_back(point.cast<float>());
  });
  std::vector<uint32_t>& now = state.scratch_edges;
  now.assign(blade_voxel.begin(), blade_voxel.end());
  sorted_unique(now);
  // The previous blade edge's points: replaced when this sweep continues from it; otherwise they
  // are parked (a slit tip) until the blade comes back to their voxel.
  const auto clear_blade = [&](uint32_t voxel) {
    VoxelFront& f = front_for(state, voxel);
    f.blade_count = 0;
    f.blade_sum = Vec3f::Zero();
    changed.push_back(voxel);
  };
  const bool continues = state.steps > 0 && state.last_blade.a == from.a && state.last_blade.b == from.b;
  for (uint32_t voxel : state.blade_voxels) {
    if (continues) {
      clear_blade(voxel);
    } else {
      state.parked_voxels.push_back(voxel);
    }
  }
  state.blade_voxels.clear();
  sorted_unique(state.parked_voxels);
  std::vector<uint32_t>& touched = state.scratch_touched;
  touched.assign(changed.begin() + std::ptrdiff_t(first_new), changed.end());
  sorted_unique(touched);
  size_t kept = 0;
  for (uint32_t voxel : state.parked_voxels) {
    if (std::binary_search(now.begin(), now.end(), voxel) || std::binary_search(touched.begin(), touched.end(), voxel) ||
        std::binary_search(state.pending_voxels.begin(), state.pending_voxels.end(), voxel)) {
      clear_blade(voxel);
    } else {
      state.parked_voxels[kept++] = voxel;
    }
  }
  state.parked_voxels.resize(kept);
  for (size_t i = 0; i < blade_voxel.size(); ++i) {
    VoxelFront& f = front_for(state, blade_voxel[i]);
    f.blade_sum += blade_point[i];
    ++f.blade_count;
    state.blade_voxels.push_back(blade_voxel[i]);
    changed.push_back(blade_voxel[i]);
  }
  sorted_unique(state.blade_voxels);
  state.last_blade = to;
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
  return sharing_pieces(model, state, edge, side, voxels, lower_corner, pieces);
}

bool sharing_pieces(const VoxelModel& model, const CutState& state, uint32_t edge, int side,
                    const uint32_t voxels[4], const uint8_t lower_corner[4], uint8_t pieces[4]) {
  const int axis = int(edge % 3);
  const uint32_t node = side ? edge / 3 + node_stride(model.lattice, axis) : edge / 3;
  const bool node_inside = model.is_inside(node);
  for (int q = 0; q < 4; ++q) {
    if (voxels[q] == kDeadIndex) return false;
    // Uncut voxels are one piece of all their inside corners; divided ones say which piece.
    const uint32_t d = state.divided_of.get(voxels[q]);
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

void init_cut_state(const VoxelModel& model, CutState& state, const ContourParams& params) {
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
  // Headroom for cuts, so a step rarely pays for growing a table (a p99 spike otherwise).
  const uint32_t vertices = uint32_t(voxels.size()), quads = uint32_t(model.crossings.size());
  state.surface.vertex_of_patch.reserve(vertices + vertices / 2 + 1024);
  state.surface.quad_of_half_edge.reserve(quads + quads / 2 + 1024);
  state.surface.positions.reserve(vertices + vertices / 2 + 1024);
  state.surface.vertex_piece.reserve(vertices + vertices / 2 + 1024);
  state.surface.vertex_patch.reserve(vertices + vertices / 2 + 1024);
  state.surface.vertex_half_edges.reserve(vertices + vertices / 2 + 1024);
  state.surface.quad_half_edge.reserve(quads + quads / 2 + 1024);
  state.surface.triangles.reserve(2 * (quads + quads / 2 + 1024));
  // The cut's maps and the arrays they index start at about two cross-sections of the model (1/16
  // of its surface vertices): a rehash or a reallocation inside a cut step copies the whole map or
  // array into fresh pages (a p99 spike: at 512 the edge cuts' array doubling at 65 536 cost 8 ms in
  // the bunny, 579 page faults, and the liver's cut, larger than 1/32 of its vertices, rehashed
  // its maps and doubled its arrays in four steps of 10-26 ms).
  const uint32_t cut_expected = vertices / 16 + 1024;
  state.edge_cut_of.reserve(cut_expected);
  state.divided_of.reserve(cut_expected);
  state.front_of.reserve(cut_expected);
  state.edge_cuts.reserve(state.edge_cut_of.capacity());
  state.divided.reserve(state.divided_of.capacity());
  state.fronts.reserve(state.front_of.capacity());

  CutStepStats stats;
  refresh_voxels(model, state, voxels, stats, nullptr);  // the whole surface is new: no list of changes
  state.surface.clear_dirty();
}

void cut_divide(const VoxelModel& model, CutState& state, const BladePose& from, const BladePose& to,
                CutStepStats& stats) {
  const Lattice& l = model.lattice;

  // Edges the swept quad crosses.
  std::vector<EdgeHit>& hits = state.scratch_hits;
  hits.clear();
  sweep_edge_hits(l, from, to, hits);
  stats.edges_hit = uint32_t(hits.size());

  // Divide: record the cuts; the voxels around each changed edge are (re)divided.
  std::vector<uint32_t>& voxels = state.pending_voxels;
  const size_t pending_before = voxels.size();  // sorted and unique (several calls per step with physics)
  for (const EdgeHit& hit : hits) {
    const EdgeChange change = record_cut(model, state, hit);
    if (change == EdgeChange::kNone) continue;
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
  merge_sorted_unique(voxels, pending_before);
  stats.voxels_cut = uint32_t(voxels.size());

  // The cut front moved: partly cut voxels on it get new vertex positions.
  std::vector<uint32_t>& front_changed = state.scratch_voxels;
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

void cut_update_surface(const VoxelModel& model, CutState& state, CutStepStats& stats) {
  state.changed_vertices.clear();
  std::vector<uint32_t>& corners = state.scratch_corners;
  corners.clear();
  refresh_voxels(model, state, state.pending_voxels, stats, &corners);
  if (!state.changed_vertices.empty() || !corners.empty()) {
    corners.insert(corners.end(), state.changed_vertices.begin(), state.changed_vertices.end());
    state.touched_vertices.swap(corners);
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
