// The cut's surface (sim/cut.h): the surface slots (CutSurface's vertex and quad slots) and the
// vertices of pieces (each voxel's half-edges, patches and dual contouring vertices, and the quads of
// its edges), from which refresh_voxels builds and updates the dual-contoured surface.
#include "sim/cut_internal.h"
#include "sim/id_pool.h"

#include "sim/contour.h"
#include "sim/union_find.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <limits>

namespace dvx {
namespace cut_internal {
namespace {

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

// Appends the corners of quad slot `quad`'s two triangles to `corners` (when given and live).
void note_quad_corners(const CutSurface& s, uint32_t quad, std::vector<uint32_t>* corners) {
  if (corners == nullptr || s.quad_half_edge[quad] == CutSurface::kFreeKey) return;
  for (int t = 0; t < 2; ++t) corners->insert(corners->end(), s.triangles[2 * quad + t].begin(), s.triangles[2 * quad + t].end());
}

// Frees the quad of a half-edge; its corners go to `corners` and its slot to `quads` (when given).
// Returns true when it had one.
bool free_quad(CutSurface& s, uint64_t key, std::vector<uint32_t>* corners, std::vector<uint32_t>* quads) {
  const uint32_t quad = s.quad_of_half_edge.get(key);
  if (quad == kDeadIndex) return false;
  note_quad_corners(s, quad, corners);
  if (quads != nullptr) quads->push_back(quad);
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
// when a slot changed; then its old and new corners go to `corners` and the slot to `quads` (when
// given).
bool write_quad(CutSurface& s, uint64_t key, const uint32_t v[4], bool on_cut, int diagonal,
                std::vector<uint32_t>* corners, std::vector<uint32_t>* quads) {
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
  // (compared element by element: Tri's operator== is a call to memcmp)
  const auto same = [](const Tri& a, const Tri& b) { return a[0] == b[0] && a[1] == b[1] && a[2] == b[2]; };
  if (same(s.triangles[2 * quad], t0) && same(s.triangles[2 * quad + 1], t1) && s.triangle_cut[2 * quad] == flag) return false;
  note_quad_corners(s, quad, corners);  // the old ones (a new slot holds dead triangles: none)
  if (corners != nullptr) corners->insert(corners->end(), v, v + 4);
  if (quads != nullptr) quads->push_back(quad);
  s.triangles[2 * quad] = t0;
  s.triangles[2 * quad + 1] = t1;
  s.triangle_cut[2 * quad] = s.triangle_cut[2 * quad + 1] = flag;
  mark_quad_dirty(s, quad);
  return true;
}

}  // namespace

// ---- Vertices of pieces --------------------------------------------------------------------

// The half-edge at end `side` of `edge` as a parameter along the edge (see half_edge()).
// `cut` is the edge's EdgeCut (nullptr when uncut), looked up by the caller.
bool half_edge_param(const VoxelModel& model, const EdgeCut* cut, uint32_t edge, int side, double& t,
                     Vec3d& normal, bool* from_cut) {
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

namespace {

// Whether an uncut edge has the half-edge at end `side` (as half_edge_param decides it).
bool uncut_half_edge(const VoxelModel& model, uint32_t edge, int side) {
  const uint32_t n0 = edge / 3;
  const bool in0 = model.is_inside(n0), in1 = model.is_inside(n0 + node_stride(model.lattice, int(edge % 3)));
  return in0 != in1 && (side ? in1 : in0);
}

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

}  // namespace

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

namespace {

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

}  // namespace

uint64_t shape_key(uint8_t in_bits, uint16_t cut_edges, uint16_t air_edges) {
  return uint64_t(in_bits) | uint64_t(cut_edges) << 8 | uint64_t(air_edges) << 20;
}

namespace {

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

// The Hermite data of every half-edge the patches hold: the point on its edge and the outward normal.
void hermite_data(const VoxelModel& model, const CutState& state, const int32_t vc[3], const VoxelData& data,
                  VoxelPatches& out) {
  const Lattice& l = model.lattice;
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

// The patches of a voxel without their Hermite data (see voxel_patches): the face rule and the merges
// of doubled curves. Returns true when a face was changed.
bool patch_topology(const VoxelModel& model, const CutState& state, uint32_t voxel, const int32_t vc[3], VoxelData& data,
                    VoxelPatches& out) {
  voxel_data(model, state, voxel, vc, data);
  if (!rule_patches(state, data, out)) return false;
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

}  // namespace

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
  const bool merged = patch_topology(model, state, voxel, vc, data, out);
  hermite_data(model, state, vc, data, out);
  return merged;
}

namespace {

// Faces of a voxel with two or more curves: a change of this voxel can change their pairing for
// the voxel across.
uint8_t four_point_faces(uint32_t present) {
  uint8_t faces = 0;
  for (int f = 0; f < 6; ++f) faces = uint8_t(faces | (face_point_count(present, f) >= 4 ? 1u << f : 0u));
  return faces;
}

}  // namespace

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

// Two quads of a slit edge that join the same four patches are the two faces of a slit of zero
// width: they cancel. Two that share one diagonal are split along the other (a diagonal is used
// by the two triangles of each quad; shared, it would be a non-manifold edge).
void plan_edge_quads(const VoxelModel& model, const CutState& state, uint32_t edge, const EdgeCut* cut,
                     const uint32_t around[4], const uint8_t corners[4], EdgeQuads& out) {
  const CutSurface& s = state.surface;
  const int axis = int(edge % 3);
  uint32_t ring[2][4];  // vertices in the ring order about the axis
  // The vertex slots of each ring voxel's patches, looked up once for both sides (a cut edge with
  // both ends inside reads the same voxels twice; each lookup is a miss in a map of the whole surface).
  // (fetched lazily in patch order, stopping at the first absent patch: a voxel's first patch mostly holds it)
  uint32_t slots[4][kMaxPatches];
  uint8_t slot_count[4] = {0, 0, 0, 0};
  bool ended[4] = {false, false, false, false};
  const auto holding = [&](int q, int h) {
    for (int i = 0;; ++i) {
      if (i == slot_count[q]) {
        if (ended[q] || i == kMaxPatches) return kDeadIndex;
        const uint32_t slot = s.vertex_of_patch.get(patch_key(around[q], uint32_t(i)));
        if (slot == kDeadIndex) {
          ended[q] = true;
          return kDeadIndex;
        }
        slots[q][slot_count[q]++] = slot;
      }
      if ((s.vertex_half_edges[slots[q][i]] >> h) & 1u) return slots[q][i];
    }
  };
  uint32_t divided[4];
  divided_around(state, around, divided);
  for (int side = 0; side < 2; ++side) {
    double t;
    Vec3d normal;
    uint8_t pieces[4];
    // (an uncut edge: the half-edge exists at an inside end of a sign change, never on the cut)
    const bool present = cut != nullptr ? half_edge_param(model, cut, edge, side, t, normal, &out.on_cut[side])
                                        : uncut_half_edge(model, edge, side);
    if (!present || !sharing_pieces(model, state, edge, side, around, corners, divided, pieces)) continue;
    bool ok = true;
    for (int q = 0; q < 4; ++q) {
      const int h = 2 * voxel_edge_index(axis, corners[q]) + side;
      ring[side][q] = holding(q, h);
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

namespace {

static_assert(sizeof(VoxelVertices::position) / sizeof(Vec3f) == kMaxPatches, "a plan holds every patch of a voxel");

// A voxel's vertices computed from its patches (with their Hermite data): what write_voxel_vertices
// writes. Reads the cut state only (every worker of a block computes its voxels at once).
void plan_voxel_vertices(const VoxelModel& model, const CutState& state, uint32_t voxel, const int32_t vc[3],
                         const VoxelPatches& patches, VoxelVertices& out) {
  out.present = patches.present;
  out.patch_count = patches.patch_count;
  out.current = false;
  for (uint32_t p = 0; p < patches.patch_count; ++p) {
    out.position[p] = patch_vertex_position(model, state, voxel, vc, patches, uint8_t(p));
    out.patch_piece[p] = patches.patch_piece[p];
    out.patch_half_edges[p] = patches.patch_half_edges[p];
  }
}

// A voxel's planned vertices written: the changed ones marked, the patches that no longer exist
// freed. Returns its half-edge mask.
uint32_t write_voxel_vertices(CutState& state, uint32_t voxel, const VoxelVertices& plan, CutStepStats& stats) {
  CutSurface& s = state.surface;
  uint32_t p = 0;
  for (; p < plan.patch_count; ++p) {
    const uint64_t key = patch_key(voxel, p);
    const Vec3f& position = plan.position[p];
    const uint64_t piece = piece_key(voxel, plan.patch_piece[p]);
    bool created = false;
    const uint32_t slot = ensure_vertex(s, key, created);
    if (created || s.positions[slot] != position || s.vertex_piece[slot] != piece ||
        s.vertex_half_edges[slot] != plan.patch_half_edges[p]) {
      s.positions[slot] = position;
      s.vertex_piece[slot] = piece;
      s.vertex_half_edges[slot] = plan.patch_half_edges[p];
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
  return plan.present;
}

// refresh_voxels' blocks (CutScratch::voxel_plans, edge_plans: at most ~0.9 and ~0.4 MB, grown to
// the largest list met; most steps' lists are one block: one wake-up of the workers) and the least work
// a worker takes of one (a voxel's patches and vertices take a few microseconds, an edge's quads
// a fraction of one).
constexpr size_t kVoxelBlock = 4096, kEdgeBlock = 8192;
constexpr uint32_t kVoxelGrain = 32, kEdgeGrain = 128;

// Grows a block's buffer to hold `n` items (never shrinks: scratch kept between steps).
template <typename T>
void at_least(std::vector<T>& buffer, size_t n) {
  if (buffer.size() < n) buffer.resize(n);
}

// A list in blocks of `block` items: compute(k, i) for item i, slot k of its block, over the workers;
// then write(k, i) for each in list order (refresh_voxels: what it writes is what one pass writes).
template <typename Compute, typename Write>
void in_blocks(const TaskRunner& tasks, size_t size, size_t block, uint32_t grain, Compute&& compute, Write&& write) {
  for (size_t first = 0; first < size; first += block) {
    const uint32_t count = uint32_t(std::min(block, size - first));
    parallel(tasks, count, grain, [&](uint32_t k) { compute(k, first + k); });
    for (uint32_t k = 0; k < count; ++k) write(k, first + k);
  }
}

// Whether a voxel the step left alone (one across a four-point face of a listed voxel: its cuts,
// pieces and front are as they were) keeps its vertices, given its patch topology (patch_topology):
// its patches, merges included, hold the half-edges and pieces its vertices hold. A vertex's position
// follows from those and the voxel's own Hermite data and front, so it is the one
// write_voxel_vertices would compute (which then writes nothing); that skips the Hermite data and the
// vertex rule of most such voxels.
bool vertices_current(const CutState& state, uint32_t voxel, const VoxelPatches& patches) {
  const CutSurface& s = state.surface;
  for (uint32_t p = 0; p < patches.patch_count; ++p) {
    const uint32_t slot = s.vertex_of_patch.get(patch_key(voxel, p));
    if (slot == kDeadIndex || s.vertex_half_edges[slot] != patches.patch_half_edges[p] ||
        s.vertex_piece[slot] != piece_key(voxel, patches.patch_piece[p])) {
      return false;
    }
  }
  return !s.vertex_of_patch.contains(patch_key(voxel, patches.patch_count));
}

}  // namespace

// Recomputes pieces, patches, vertices and quads of the given voxels (sorted, unique) and of the
// edges they hold; adds the voxels across their four-point faces (whose pairing may toggle with
// them, see voxel_patches). Returns counts of changed slots through stats.
void refresh_voxels(const VoxelModel& model, CutState& state, std::vector<uint32_t>& voxels, CutStepStats& stats,
                    std::vector<uint32_t>* changed_corners, std::vector<uint32_t>* changed_quads, const TaskRunner& tasks) {
  const Lattice& l = model.lattice;
  CutSurface& s = state.surface;
  std::vector<uint32_t>& across = state.scratch.across;
  across.clear();
  const int32_t dims[3] = {l.nx, l.ny, l.nz};
  if (voxels.empty()) return;
  // Membership of the list (and of the voxels across its faces, added below) as bits over the window
  // of voxel ids it can span: a read instead of a binary search (about ten mispredicted branches)
  // for each voxel around each edge. The bits set here are cleared at the end.
  std::vector<uint64_t>& listed = state.scratch.listed;
  const uint32_t layer = uint32_t(l.nx) * uint32_t(l.ny);
  const uint32_t window = (voxels.front() > layer ? voxels.front() - layer : 0u) & ~63u;
  const uint64_t window_end = std::min(uint64_t(voxels.back()) + layer + 1, l.voxel_count());
  if (listed.size() < ((window_end - window) >> 6) + 1) listed.resize(((window_end - window) >> 6) + 1, 0);
  const auto list = [&](uint32_t v) { listed[(v - window) >> 6] |= uint64_t(1) << ((v - window) & 63); };
  const auto in_list = [&](uint32_t v) { return v >= window && v < window_end && ((listed[(v - window) >> 6] >> ((v - window) & 63)) & 1u); };
  for (uint32_t v : voxels) list(v);
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
  // The listed voxels' vertices, a block at a time: computed over the workers (their patches and
  // vertices read the pieces, final above, and never the surface), then written in list order, so
  // the slots are the ones one pass allocates, for any worker count.
  std::vector<VoxelVertices>& plans = state.scratch.voxel_plans;
  at_least(plans, std::min(kVoxelBlock, voxels.size()));
  const CutState& read = state;
  // (the vertex slots of the voxel two ahead are fetched while one is written: a miss each)
  constexpr size_t kAhead = 2;
  in_blocks(
      tasks, voxels.size(), kVoxelBlock, kVoxelGrain,
      [&](uint32_t k, size_t i) {
        const uint32_t voxel = voxels[i];
        int32_t vc[3];
        l.voxel_coords(voxel, vc);
        VoxelPatches patches;
        voxel_patches(model, read, voxel, vc, patches);
        plan_voxel_vertices(model, read, voxel, vc, patches, plans[k]);
      },
      [&](uint32_t k, size_t i) {
        const uint32_t voxel = voxels[i];
        if (i + kAhead < voxels.size()) s.vertex_of_patch.prefetch(patch_key(voxels[i + kAhead], 0));
        const uint8_t faces = four_point_faces(write_voxel_vertices(state, voxel, plans[k], stats));
        if (faces == 0) return;
        int32_t vc[3];
        l.voxel_coords(voxel, vc);
        for (int f = 0; f < 6; ++f) {
          int32_t nc[3] = {vc[0], vc[1], vc[2]};
          nc[f / 2] += f % 2 ? 1 : -1;
          if (!((faces >> f) & 1u) || nc[f / 2] < 0 || nc[f / 2] >= dims[f / 2]) continue;
          const uint32_t other = l.voxel(nc[0], nc[1], nc[2]);
          if (!in_list(other)) across.push_back(other);
        }
      });
  if (!across.empty()) {
    sorted_unique(across);
    at_least(plans, std::min(kVoxelBlock, across.size()));
    // Their topology first; the Hermite data and the vertices only where it changed. (Each reads its
    // own vertex slots, which the listed voxels' writes above never touch.)
    in_blocks(
        tasks, across.size(), kVoxelBlock, kVoxelGrain,
        [&](uint32_t k, size_t i) {
          const uint32_t voxel = across[i];
          int32_t vc[3];
          l.voxel_coords(voxel, vc);
          VoxelData data;
          VoxelPatches patches;
          patch_topology(model, read, voxel, vc, data, patches);
          plans[k].current = vertices_current(read, voxel, patches);
          if (plans[k].current) return;
          hermite_data(model, read, vc, data, patches);
          plan_voxel_vertices(model, read, voxel, vc, patches, plans[k]);
        },
        [&](uint32_t k, size_t i) {
          if (!plans[k].current) write_voxel_vertices(state, across[i], plans[k], stats);
        });
    const size_t n = voxels.size();
    voxels.insert(voxels.end(), across.begin(), across.end());
    std::inplace_merge(voxels.begin(), voxels.begin() + std::ptrdiff_t(n), voxels.end());
    for (uint32_t v : across) list(v);
  }

  // Edges of these voxels: one quad per existing half-edge. Each edge is handled once, by the
  // lowest voxel of the list around it; listed first, in the order they are handled.
  std::vector<CutScratch::ListedEdge>& edges = state.scratch.listed_edges;
  edges.clear();
  for (uint32_t voxel : voxels) {
    int32_t vc[3];
    l.voxel_coords(voxel, vc);
    const uint32_t d = state.divided_of.get(voxel);
    const uint16_t cut_edges = d != kDeadIndex ? state.divided[d].cut_edges : 0;
    // Only surface edges and cut edges ever hold a quad (cuts are never undone).
    for (uint32_t bits = kSignChangeEdges[corner_inside_bits(model, vc)] | cut_edges; bits; bits &= bits - 1) {
      const int e = std::countr_zero(bits);
      CutScratch::ListedEdge item;
      voxels_around_voxel_edge(l, vc, e, item.around, item.corners);
      bool owner = true;
      for (int q = 0; q < 4 && owner; ++q) {
        owner = !(item.around[q] < voxel && in_list(item.around[q]));
      }
      if (!owner) continue;
      item.edge = voxel_edge_id(l, vc, e);
      item.cut = (cut_edges >> e) & 1u;
      edges.push_back(item);
    }
  }
  // Their quads, a block at a time: planned over the workers (they read the vertices, final above),
  // then written in list order.
  std::vector<EdgeQuads>& quads = state.scratch.edge_plans;
  at_least(quads, std::min(kEdgeBlock, edges.size()));
  // (the ring's vertex slots of the edge a few ahead are fetched while one is planned, its quad
  // slots while one is written)
  constexpr size_t kEdgesAhead = 4;
  in_blocks(
      tasks, edges.size(), kEdgeBlock, kEdgeGrain,
      [&](uint32_t k, size_t i) {
        if (i + kEdgesAhead < edges.size()) {
          for (const uint32_t v : edges[i + kEdgesAhead].around) {
            if (v != kDeadIndex) s.vertex_of_patch.prefetch(patch_key(v, 0));
          }
        }
        const CutScratch::ListedEdge& item = edges[i];
        const EdgeCut* cut = item.cut ? find_cut(read, item.edge) : nullptr;
        quads[k] = EdgeQuads();
        plan_edge_quads(model, read, item.edge, cut, item.around, item.corners, quads[k]);
      },
      [&](uint32_t k, size_t i) {
        if (i + kEdgesAhead < edges.size()) s.quad_of_half_edge.prefetch(half_edge_key(edges[i + kEdgesAhead].edge, 0));
        const EdgeQuads& plan = quads[k];
        for (int side = 0; side < 2; ++side) {
          const uint64_t key = half_edge_key(edges[i].edge, side);
          if (plan.exists[side]) {
            if (write_quad(s, key, plan.v[side], plan.on_cut[side], plan.diagonal[side], changed_corners, changed_quads)) {
              stats.triangles_changed += 2;
            }
          } else if (free_quad(s, key, changed_corners, changed_quads)) {
            stats.triangles_changed += 2;
          }
        }
      });
  for (uint32_t v : voxels) listed[(v - window) >> 6] = 0;
}

}  // namespace cut_internal
}  // namespace dvx
