// Internals of the cut shared by its files (cut.cpp: the public API and its checks; cut_surface.cpp:
// the surface slots and the vertices of pieces, which build and update the dual-contoured surface;
// cut_edges.cpp: the cuts on edges and the cut front). Not for engine/, bench/ or ui/
// (tests/layers_test.sh): they use sim/cut.h and sim/world.h.
#pragma once

#include "sim/cut.h"
#include "sim/union_find.h"

#include <algorithm>
#include <array>
#include <cstdint>
#include <vector>

namespace dvx {

// The indices in CutState::divided of the voxels around an edge (kDeadIndex: uncut, or no voxel).
inline void divided_around(const CutState& state, const uint32_t voxels[4], uint32_t divided[4]) {
  for (int q = 0; q < 4; ++q) divided[q] = voxels[q] == kDeadIndex ? kDeadIndex : state.divided_of.get(voxels[q]);
}

// The pieces around a half-edge given the voxels around its edge (see half_edge_sharing) and their
// indices in CutState::divided (divided_around), looked up once for both sides of the edge.
bool sharing_pieces(const VoxelModel& model, const CutState& state, uint32_t edge, int side,
                    const uint32_t voxels[4], const uint8_t lower_corner[4], const uint32_t divided[4],
                    uint8_t pieces[4]);

namespace cut_internal {

// Index in kVoxelEdges of the edge along `axis` starting at corner c0 (c0 has bit `axis` clear).
constexpr std::array<std::array<int8_t, 8>, 3> make_edge_index() {
  std::array<std::array<int8_t, 8>, 3> t{};
  for (auto& row : t) row.fill(-1);
  for (int e = 0; e < 12; ++e) t[kVoxelEdges[e].axis][kVoxelEdges[e].c0] = int8_t(e);
  return t;
}
inline constexpr std::array<std::array<int8_t, 8>, 3> kEdgeIndex = make_edge_index();
inline int voxel_edge_index(int axis, int c0) { return kEdgeIndex[size_t(axis)][size_t(c0)]; }

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
inline constexpr FaceEdges kFaceEdges = make_face_edges();

// Patches of a voxel are numbered 0..n-1; a voxel holds at most 12 (24 half-edges, two per loop).
inline constexpr int kMaxPatches = 12;
inline uint64_t patch_key(uint32_t voxel, uint32_t patch) { return uint64_t(voxel) * 16 + patch; }

inline uint64_t piece_key(uint32_t voxel, uint32_t piece) { return uint64_t(voxel) * 8 + piece; }
inline uint64_t half_edge_key(uint32_t edge, int side) { return uint64_t(edge) * 2 + uint64_t(side); }

// Node of corner c of the voxel at lattice coordinates vc.
inline uint32_t corner_node(const Lattice& l, const int32_t vc[3], int c) {
  return l.node(vc[0] + (c & 1), vc[1] + ((c >> 1) & 1), vc[2] + ((c >> 2) & 1));
}

// Lattice edge id of voxel edge e.
inline uint32_t voxel_edge_id(const Lattice& l, const int32_t vc[3], int e) {
  return Lattice::edge(corner_node(l, vc, kVoxelEdges[e].c0), kVoxelEdges[e].axis);
}

// Node index step along an axis.
inline uint32_t node_stride(const Lattice& l, int axis) {
  return axis == 0 ? 1u : axis == 1 ? uint32_t(l.nx + 1) : uint32_t(l.nx + 1) * uint32_t(l.ny + 1);
}

// The voxels around a lattice edge (up to 4, in counter-clockwise order about the axis); the
// corner of the edge's lower node in each. Entries outside the lattice get voxel = kDeadIndex.
// The voxels around the lattice edge from node n along `axis` (see voxels_around_edge).
inline void voxels_around_node_edge(const Lattice& l, const int32_t n[3], int axis, uint32_t voxels[4],
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

inline void voxels_around_edge(const Lattice& l, uint32_t edge, uint32_t voxels[4], uint8_t lower_corner[4]) {
  int32_t n[3];
  l.node_coords(edge / 3, n);
  voxels_around_node_edge(l, n, int(edge % 3), voxels, lower_corner);
}

// The same for edge e of the voxel at vc, without divisions (the hot path of the surface update).
inline void voxels_around_voxel_edge(const Lattice& l, const int32_t vc[3], int e, uint32_t voxels[4],
                                     uint8_t lower_corner[4]) {
  const VoxelEdge& ve = kVoxelEdges[e];
  const int32_t n[3] = {vc[0] + (ve.c0 & 1), vc[1] + ((ve.c0 >> 1) & 1), vc[2] + ((ve.c0 >> 2) & 1)};
  voxels_around_node_edge(l, n, ve.axis, voxels, lower_corner);
}

// Inserts into a sorted vector if absent.
inline void sorted_unique(std::vector<uint32_t>& v) {
  std::sort(v.begin(), v.end());
  v.erase(std::unique(v.begin(), v.end()), v.end());
}

inline const EdgeCut* find_cut(const CutState& state, uint32_t edge) {
  const uint32_t i = state.edge_cut_of.get(edge);
  return i == kDeadIndex ? nullptr : &state.edge_cuts[i];
}

// Inside bits of a voxel's corners (bit c: corner c inside).
inline uint8_t corner_inside_bits(const VoxelModel& model, const int32_t vc[3]) {
  uint8_t bits = 0;
  for (int c = 0; c < 8; ++c) bits = uint8_t(bits | (model.is_inside(corner_node(model.lattice, vc, c)) ? 1u << c : 0u));
  return bits;
}

// Components of the voxel's material graph (voxel_material_joins: uncut edges, uncut ambiguous faces).
// `air_edges`: surface edges the blade crossed outside the material (they cut the faces they bound).
inline void material_components(uint8_t in_bits, uint16_t cut_edges, uint16_t air_edges, uint8_t corner_piece[8],
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

// ---- Shared by the sections ----------------------------------------------------------------

// Vertices of pieces (cut_surface.cpp).

// The half-edge at end `side` of `edge` as a parameter along the edge (see half_edge()).
bool half_edge_param(const VoxelModel& model, const EdgeCut* cut, uint32_t edge, int side, double& t,
                     Vec3d& normal, bool* from_cut = nullptr);

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

// The shape of a voxel by the face rule (PatchShape), and its key in the memo (CutState::shape_of).
void make_shape(uint8_t in_bits, uint16_t cut_edges, uint16_t air_edges, bool divided, PatchShape& out);
uint64_t shape_key(uint8_t in_bits, uint16_t cut_edges, uint16_t air_edges);

// Half-edges, pieces and patches of a voxel (with the merges of doubled curves).
bool voxel_patches(const VoxelModel& model, const CutState& state, uint32_t voxel, const int32_t vc[3],
                   VoxelPatches& out);

// Position of patch p's vertex.
Vec3f patch_vertex_position(const VoxelModel& model, const CutState& state, uint32_t voxel, const int32_t vc[3],
                            const VoxelPatches& patches, uint8_t p);

// The quads of a lattice edge's two half-edges (slit quads that coincide cancel).
void plan_edge_quads(const VoxelModel& model, const CutState& state, uint32_t edge, const EdgeCut* cut,
                     const uint32_t around[4], const uint8_t corners[4], EdgeQuads& out);

// Recomputes pieces, patches, vertices and quads of the given voxels and of the edges they hold;
// the corners (old and new) and the slots of the quads it changed go to changed_corners and
// changed_quads when given.
// What it computes (patches, vertices, quads) runs over `tasks`; what it writes, in list order.
void refresh_voxels(const VoxelModel& model, CutState& state, std::vector<uint32_t>& voxels, CutStepStats& stats,
                    std::vector<uint32_t>* changed_corners, std::vector<uint32_t>* changed_quads,
                    const TaskRunner& tasks = {});

// Cuts on edges and the cut front (cut_edges.cpp).

// What one blade crossing did to its edge.
enum class EdgeChange { kNone, kCut, kAir };

// Applies one blade crossing to an edge.
EdgeChange record_cut(const VoxelModel& model, CutState& state, const EdgeHit& hit);

// The crumb test's two halves (record_cut; tests/sim/test_cut.cpp compares them): whether severing
// `edge` at t would leave inside node n in a crumb, by the bounded flood fill; and its exact shortcut,
// true only where the flood would say no (n an end of `edge` with uncut bulk material behind it).
bool material_flood(const VoxelModel& model, const CutState& state, uint32_t n, uint32_t edge, float t);
bool bulk_behind(const VoxelModel& model, const CutState& state, uint32_t n, uint32_t edge);

// Records the front of a sweep from `from` to `to`; appends voxels whose front changed to `changed`.
void update_front(const VoxelModel& model, CutState& state, const BladePose& from, const BladePose& to,
                  std::vector<uint32_t>& changed);

}  // namespace cut_internal
}  // namespace dvx
