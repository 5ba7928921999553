#include "sim/cut.h"

#include "sim/contour.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace dvx {
namespace {

}  // namespace

// The pieces around a half-edge given the voxels around its edge (see half_edge_sharing).
bool sharing_pieces(const VoxelModel& model, const CutState& state, uint32_t edge, int side,
                    const uint32_t voxels[4], const uint8_t lower_corner[4], uint8_t pieces[4]);

namespace {

// One of the 12 edges of a voxel: its two corners and its axis.
struct VoxelEdge {
  uint8_t c0, c1, axis;
};
constexpr VoxelEdge kVoxelEdges[12] = {{0, 1, 0}, {2, 3, 0}, {4, 5, 0}, {6, 7, 0}, {0, 2, 1}, {1, 3, 1},
                                       {4, 6, 1}, {5, 7, 1}, {0, 4, 2}, {1, 5, 2}, {2, 6, 2}, {3, 7, 2}};

// Index in kVoxelEdges of the edge along `axis` starting at corner c0 (c0 has bit `axis` clear).
int voxel_edge_index(int axis, int c0) {
  for (int e = 0; e < 12; ++e) {
    if (kVoxelEdges[e].axis == axis && kVoxelEdges[e].c0 == c0) return e;
  }
  return -1;
}

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
  const int u = (axis + 1) % 3, v = (axis + 2) % 3;
  const int32_t dims[3] = {l.nx, l.ny, l.nz};
  static constexpr int kOffsets[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  for (int q = 0; q < 4; ++q) {
    int32_t c[3] = {n[0], n[1], n[2]};
    c[u] -= kOffsets[q][0];
    c[v] -= kOffsets[q][1];
    const bool inside = c[0] >= 0 && c[1] >= 0 && c[2] >= 0 && c[0] < dims[0] && c[1] < dims[1] && c[2] < dims[2];
    voxels[q] = inside ? l.voxel(c[0], c[1], c[2]) : kDeadIndex;
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

const EdgeCut* find_cut(const CutState& state, uint32_t edge) {
  const uint32_t i = state.edge_cut_of.get(edge);
  return i == kDeadIndex ? nullptr : &state.edge_cuts[i];
}

// Components of the voxel's material graph (inside corners joined by uncut edges).
void material_components(const VoxelModel& model, uint16_t cut_edges, const int32_t vc[3], uint8_t corner_piece[8],
                         uint8_t& piece_count, uint8_t& partial_mask) {
  const Lattice& l = model.lattice;
  uint8_t parent[8];
  bool inside[8];
  for (int c = 0; c < 8; ++c) {
    parent[c] = uint8_t(c);
    inside[c] = model.is_inside(corner_node(l, vc, c));
  }
  const auto find = [&](int c) {
    while (parent[c] != c) c = parent[c] = parent[parent[c]];
    return c;
  };
  bool cut[12];
  for (int e = 0; e < 12; ++e) {
    const VoxelEdge& ve = kVoxelEdges[e];
    cut[e] = (cut_edges >> e) & 1u;
    if (inside[ve.c0] && inside[ve.c1] && !cut[e]) {
      const int a = find(ve.c0), b = find(ve.c1);
      if (a != b) parent[std::max(a, b)] = uint8_t(std::min(a, b));
    }
  }
  // Number pieces in corner order.
  uint8_t id_of_root[8];
  std::fill(id_of_root, id_of_root + 8, kNoPiece);
  piece_count = 0;
  for (int c = 0; c < 8; ++c) {
    if (!inside[c]) {
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
    if (cut[e] && inside[ve.c0] && inside[ve.c1] && corner_piece[ve.c0] == corner_piece[ve.c1]) {
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

// Slot of a piece's vertex, allocated when absent.
uint32_t ensure_vertex(CutSurface& s, uint64_t key, bool& created) {
  uint32_t slot = s.vertex_of_piece.get(key);
  created = slot == kDeadIndex;
  if (!created) return slot;
  if (!s.free_vertices.empty()) {
    slot = s.free_vertices.back();
    s.free_vertices.pop_back();
  } else {
    slot = uint32_t(s.positions.size());
    s.positions.emplace_back(Vec3f::Zero());
    s.vertex_piece.push_back(CutSurface::kFreeKey);
  }
  s.vertex_piece[slot] = key;
  s.vertex_of_piece.set(key, slot);
  return slot;
}

bool free_vertex(CutSurface& s, uint64_t key) {
  const uint32_t slot = s.vertex_of_piece.get(key);
  if (slot == kDeadIndex) return false;
  s.vertex_of_piece.erase(key);
  s.vertex_piece[slot] = CutSurface::kFreeKey;
  s.positions[slot] = Vec3f::Constant(std::numeric_limits<float>::quiet_NaN());
  s.free_vertices.push_back(slot);
  mark_vertex_dirty(s, slot);
  return true;
}

bool free_quad(CutSurface& s, uint64_t key) {
  const uint32_t quad = s.quad_of_half_edge.get(key);
  if (quad == kDeadIndex) return false;
  s.quad_of_half_edge.erase(key);
  s.quad_half_edge[quad] = CutSurface::kFreeKey;
  s.triangles[2 * quad] = s.triangles[2 * quad + 1] = Tri{kDeadIndex, kDeadIndex, kDeadIndex};
  s.triangle_cut[2 * quad] = s.triangle_cut[2 * quad + 1] = 0;
  s.free_quads.push_back(quad);
  mark_quad_dirty(s, quad);
  return true;
}

// Writes the quad (v0 v1 v2 v3, counter-clockwise seen from outside) of a half-edge, split along
// the shorter diagonal. Returns true when a slot changed.
bool write_quad(CutSurface& s, uint64_t key, const uint32_t v[4], bool on_cut) {
  uint32_t quad = s.quad_of_half_edge.get(key);
  if (quad == kDeadIndex) {
    if (!s.free_quads.empty()) {
      quad = s.free_quads.back();
      s.free_quads.pop_back();
    } else {
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
  if (d02 <= d13) {
    t0 = {v[0], v[1], v[2]};
    t1 = {v[0], v[2], v[3]};
  } else {
    t0 = {v[0], v[1], v[3]};
    t1 = {v[1], v[2], v[3]};
  }
  const uint8_t flag = on_cut ? 1 : 0;
  if (s.triangles[2 * quad] == t0 && s.triangles[2 * quad + 1] == t1 && s.triangle_cut[2 * quad] == flag) return false;
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
  if (cut != nullptr) {
    if (side == 0) {
      consider(cut->t_lo, cut->normal_lo.cast<double>());
    } else {
      consider(cut->t_hi, cut->normal_hi.cast<double>());
    }
  }
  if (best < 0.0 || best > 1.0) return false;
  t = best;
  if (from_cut != nullptr) *from_cut = cut != nullptr && (side ? best == double(cut->t_hi) : best == double(cut->t_lo));
  // Outward: from the end node toward the boundary.
  if (normal[axis] * (side ? -1.0 : 1.0) < 0.0) normal = -normal;
  return true;
}

// The half-edges of a voxel's 12 edges (up to 24), each with the corner it starts from.
struct VoxelHalfEdges {
  int count = 0;
  uint8_t corner[24];
  Vec3d point[24], normal[24];
};

void voxel_half_edges(const VoxelModel& model, const CutState& state, const int32_t vc[3], uint16_t cut_edges,
                      VoxelHalfEdges& out) {
  out.count = 0;
  const Lattice& l = model.lattice;
  const Vec3d origin = l.node_position(vc[0], vc[1], vc[2]);
  for (int e = 0; e < 12; ++e) {
    const VoxelEdge& ve = kVoxelEdges[e];
    const uint32_t edge = voxel_edge_id(l, vc, e);
    const EdgeCut* cut = (cut_edges >> e) & 1u ? find_cut(state, edge) : nullptr;
    for (int side = 0; side < 2; ++side) {
      double t = 0.0;
      if (!half_edge_param(model, cut, edge, side, t, out.normal[out.count])) continue;
      // The edge starts at corner c0 of this voxel.
      Vec3d p = origin + l.voxel_size * Vec3d(ve.c0 & 1, (ve.c0 >> 1) & 1, (ve.c0 >> 2) & 1);
      p[ve.axis] += t * l.voxel_size;
      out.point[out.count] = p;
      out.corner[out.count++] = side ? ve.c1 : ve.c0;
    }
  }
}

// Position of piece p's vertex; false when the piece has no half-edge (no surface in it).
bool piece_vertex_position(const VoxelModel& model, const CutState& state, uint32_t voxel, const int32_t vc[3],
                           const VoxelHalfEdges& half_edges, const uint8_t corner_piece[8], uint8_t partial_mask,
                           uint8_t p, Vec3f& out) {
  const Lattice& l = model.lattice;
  Vec3d points[24], normals[24];
  int count = 0;
  for (int i = 0; i < half_edges.count; ++i) {
    if (corner_piece[half_edges.corner[i]] != p) continue;
    points[count] = half_edges.point[i];
    normals[count++] = half_edges.normal[i];
  }
  if (count == 0) return false;
  const Vec3d lo = l.node_position(vc[0], vc[1], vc[2]);
  const Vec3d hi = lo + Vec3d::Constant(l.voxel_size);
  // A partly cut piece sits on the cut front (the average of its face points).
  if ((partial_mask >> p) & 1u) {
    const uint32_t f = state.front_of.get(voxel);
    if (f != kDeadIndex) {
      const VoxelFront& front = state.fronts[f];
      const uint32_t n = front.trail_count + front.blade_count;
      if (n > 0) {
        const Vec3d mean = ((front.trail_sum + front.blade_sum) / float(n)).cast<double>();
        out = mean.cwiseMax(lo).cwiseMin(hi).cast<float>();
        return true;
      }
    }
  }
  // Fully cut (or uncut) piece: the dual contouring vertex rule, in the voxel's local frame.
  for (int i = 0; i < count; ++i) points[i] = (points[i] - lo) / l.voxel_size;
  const Vec3d local = place_voxel_vertex(points, normals, count);
  out = (lo + l.voxel_size * local).cast<float>();
  return true;
}

// Recomputes pieces, vertices and quads of the given voxels (sorted, unique) and of the edges
// they hold. Returns counts of changed slots through stats.
void refresh_voxels(const VoxelModel& model, CutState& state, const std::vector<uint32_t>& voxels,
                    CutStepStats& stats) {
  const Lattice& l = model.lattice;
  CutSurface& s = state.surface;

  // Pieces and vertices.
  for (uint32_t voxel : voxels) {
    int32_t vc[3];
    l.voxel_coords(voxel, vc);
    uint8_t corner_piece[8], piece_count = 0, partial_mask = 0;
    // Pieces before and after: slots of pieces that no longer exist are freed.
    uint8_t old_count = 8;
    const uint32_t d = state.divided_of.get(voxel);
    if (d != kDeadIndex) {
      DividedVoxel& dv = state.divided[d];
      old_count = dv.piece_count;
      material_components(model, dv.cut_edges, vc, dv.corner_piece, dv.piece_count, dv.partial_mask);
    }
    pieces_of(model, state, voxel, corner_piece, piece_count, partial_mask);
    VoxelHalfEdges half_edges;
    voxel_half_edges(model, state, vc, d != kDeadIndex ? state.divided[d].cut_edges : 0, half_edges);
    const uint8_t visit = std::max(old_count, piece_count);
    for (uint8_t p = 0; p < visit; ++p) {
      const uint64_t key = piece_key(voxel, p);
      Vec3f position;
      if (p < piece_count &&
          piece_vertex_position(model, state, voxel, vc, half_edges, corner_piece, partial_mask, p, position)) {
        bool created = false;
        const uint32_t slot = ensure_vertex(s, key, created);
        if (created || s.positions[slot] != position) {
          s.positions[slot] = position;
          mark_vertex_dirty(s, slot);
          state.changed_vertices.push_back(slot);
          ++stats.vertices_changed;
        }
      } else {
        const uint32_t slot = s.vertex_of_piece.get(key);
        if (free_vertex(s, key)) {
          state.changed_vertices.push_back(slot);
          ++stats.vertices_changed;
        }
      }
    }
  }

  // Edges of these voxels: one quad per existing half-edge. Each edge is handled once, by the
  // lowest voxel of the list around it (the list is sorted).
  for (uint32_t voxel : voxels) {
    int32_t vc[3];
    l.voxel_coords(voxel, vc);
    const uint32_t d = state.divided_of.get(voxel);
    const uint16_t cut_edges = d != kDeadIndex ? state.divided[d].cut_edges : 0;
    for (int e = 0; e < 12; ++e) {
      const uint32_t edge = voxel_edge_id(l, vc, e);
      uint32_t around[4];
      uint8_t corners[4];
      voxels_around_voxel_edge(l, vc, e, around, corners);
      bool owner = true;
      for (int q = 0; q < 4 && owner; ++q) {
        owner = !(around[q] < voxel && std::binary_search(voxels.begin(), voxels.end(), around[q]));
      }
      if (!owner) continue;
      const EdgeCut* cut = (cut_edges >> e) & 1u ? find_cut(state, edge) : nullptr;
      for (int side = 0; side < 2; ++side) {
        const uint64_t key = half_edge_key(edge, side);
        double t;
        Vec3d normal;
        uint8_t pieces[4];
        bool on_cut = false;
        if (half_edge_param(model, cut, edge, side, t, normal, &on_cut) &&
            sharing_pieces(model, state, edge, side, around, corners, pieces)) {
          uint32_t v[4];
          bool ok = true;
          for (int q = 0; q < 4; ++q) {
            v[q] = s.vertex_of_piece.get(piece_key(around[q], pieces[q]));
            ok = ok && v[q] != kDeadIndex;
          }
          if (!ok) continue;  // cannot happen for a consistent state; check_cut_state reports it
          if (side == 1) std::swap(v[1], v[3]);  // outward normal along -axis: reverse the winding
          if (write_quad(s, key, v, on_cut)) stats.triangles_changed += 2;
        } else if (free_quad(s, key)) {
          stats.triangles_changed += 2;
        }
      }
    }
  }
}

// ---- Cuts on edges -------------------------------------------------------------------------

// Applies one blade crossing to an edge. Returns true when the cut state of the edge changed.
bool record_cut(const VoxelModel& model, CutState& state, const EdgeHit& hit) {
  const Lattice& l = model.lattice;
  const uint32_t n0 = hit.edge / 3;
  const uint32_t n1 = n0 + node_stride(l, int(hit.edge % 3));
  const bool in0 = model.is_inside(n0), in1 = model.is_inside(n1);
  if (!in0 && !in1) return false;  // the blade is in the air
  if (in0 != in1) {
    // On a surface edge only a cut between the inside node and the surface matters.
    const EdgeCrossing* c = model.find_crossing(hit.edge);
    const float ts = c ? c->t : 0.5f;
    if (in0 ? hit.t >= ts : hit.t <= ts) return false;
  }
  const uint32_t i = state.edge_cut_of.get(hit.edge);
  if (i == kDeadIndex) {
    state.edge_cut_of.set(hit.edge, uint32_t(state.edge_cuts.size()));
    state.edge_cuts.push_back(EdgeCut{hit.edge, hit.t, hit.t, hit.normal, hit.normal});
    return true;
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
  return changed;
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
// points (replacing the previous blade's). Appends voxels whose front changed to `changed`.
void update_front(const VoxelModel& model, CutState& state, const BladePose& from, const BladePose& to,
                  std::vector<uint32_t>& changed) {
  const Lattice& l = model.lattice;
  // The previous blade edge is no longer the front.
  for (uint32_t voxel : state.blade_voxels) {
    VoxelFront& f = front_for(state, voxel);
    f.blade_count = 0;
    f.blade_sum = Vec3f::Zero();
    changed.push_back(voxel);
  }
  state.blade_voxels.clear();
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
  // The blade edge now.
  walk_segment(l, to.a, to.b, true, state.scratch_params, [&](uint32_t voxel, const Vec3d& point) {
    if (!has_material(model, voxel)) return;
    VoxelFront& f = front_for(state, voxel);
    f.blade_sum += point.cast<float>();
    ++f.blade_count;
    state.blade_voxels.push_back(voxel);
    changed.push_back(voxel);
  });
  sorted_unique(state.blade_voxels);
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

void init_cut_state(const VoxelModel& model, CutState& state) {
  state = CutState{};
  // Every voxel around a sign-change edge holds a surface vertex.
  std::vector<uint32_t> voxels;
  voxels.reserve(model.crossings.size() * 4);
  for (const EdgeCrossing& c : model.crossings) {
    uint32_t around[4];
    uint8_t corners[4];
    voxels_around_edge(model.lattice, c.edge, around, corners);
    for (uint32_t v : around) {
      if (v != kDeadIndex) voxels.push_back(v);
    }
  }
  sorted_unique(voxels);
  // Headroom for cuts, so a step rarely pays for growing a table (a p99 spike otherwise).
  const uint32_t vertices = uint32_t(voxels.size()), quads = uint32_t(model.crossings.size());
  state.surface.vertex_of_piece.reserve(vertices + vertices / 2 + 1024);
  state.surface.quad_of_half_edge.reserve(quads + quads / 2 + 1024);
  state.surface.positions.reserve(vertices + vertices / 2 + 1024);
  state.surface.vertex_piece.reserve(vertices + vertices / 2 + 1024);
  state.surface.quad_half_edge.reserve(quads + quads / 2 + 1024);
  state.surface.triangles.reserve(2 * (quads + quads / 2 + 1024));

  CutStepStats stats;
  refresh_voxels(model, state, voxels, stats);
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
  for (const EdgeHit& hit : hits) {
    if (!record_cut(model, state, hit)) continue;
    ++stats.edges_cut;
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
        state.divided.push_back(dv);
      }
      state.divided[d].cut_edges |= uint16_t(1u << voxel_edge_index(axis, corners[q]));
    }
  }
  sorted_unique(voxels);
  stats.voxels_cut = uint32_t(voxels.size());

  // The cut front moved: partly cut voxels on it get new vertex positions.
  std::vector<uint32_t>& front_changed = state.scratch_voxels;
  front_changed.clear();
  update_front(model, state, from, to, front_changed);
  for (uint32_t v : front_changed) {
    const uint32_t d = state.divided_of.get(v);
    if (d != kDeadIndex && state.divided[d].partial_mask != 0) voxels.push_back(v);
  }
  sorted_unique(voxels);
  stats.voxels_divided = uint32_t(state.divided.size());
  ++state.steps;
}

void cut_update_surface(const VoxelModel& model, CutState& state, CutStepStats& stats) {
  state.changed_vertices.clear();
  refresh_voxels(model, state, state.pending_voxels, stats);
  state.changed_voxels.swap(state.pending_voxels);
  state.pending_voxels.clear();
}

CutStepStats cut_step(const VoxelModel& model, CutState& state, const BladePose& from, const BladePose& to) {
  CutStepStats stats;
  cut_divide(model, state, from, to, stats);
  cut_update_surface(model, state, stats);
  return stats;
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

bool check_cut_state(const VoxelModel& model, const CutState& state, std::string& error) {
  const Lattice& l = model.lattice;
  const CutSurface& s = state.surface;
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
    bool has_cut = false;
    for (int e = 0; e < 12; ++e) has_cut = has_cut || find_cut(state, voxel_edge_id(l, vc, e)) != nullptr;
    if (!has_cut) return fail("divided voxel " + std::to_string(dv.voxel) + " has no cut edge");
    uint8_t pieces[8], count = 0, partial = 0;
    uint16_t mask = 0;
    for (int e = 0; e < 12; ++e) mask |= uint16_t(find_cut(state, voxel_edge_id(l, vc, e)) ? 1u << e : 0u);
    if (mask != dv.cut_edges) return fail("divided voxel " + std::to_string(dv.voxel) + " has a stale cut-edge mask");
    material_components(model, mask, vc, pieces, count, partial);
    if (count != dv.piece_count || partial != dv.partial_mask || !std::equal(pieces, pieces + 8, dv.corner_piece)) {
      return fail("divided voxel " + std::to_string(dv.voxel) + " pieces differ from its material graph");
    }
  }

  // Every live vertex belongs to a live piece that has a half-edge; positions finite.
  uint32_t live_vertices = 0;
  for (uint32_t slot = 0; slot < s.positions.size(); ++slot) {
    const uint64_t key = s.vertex_piece[slot];
    if (key == CutSurface::kFreeKey) continue;
    ++live_vertices;
    if (s.vertex_of_piece.get(key) != slot) return fail("vertex slot not indexed by its piece");
    if (!s.positions[slot].allFinite()) return fail("non-finite vertex position");
    const uint32_t voxel = uint32_t(key / 8);
    uint8_t pieces[8], count = 0, partial = 0;
    pieces_of(model, state, voxel, pieces, count, partial);
    if (key % 8 >= count) return fail("vertex of a piece that does not exist in voxel " + std::to_string(voxel));
    int32_t vc[3];
    l.voxel_coords(voxel, vc);
    Vec3f position;
    VoxelHalfEdges half_edges;
    const uint32_t d = state.divided_of.get(voxel);
    voxel_half_edges(model, state, vc, d != kDeadIndex ? state.divided[d].cut_edges : 0, half_edges);
    if (!piece_vertex_position(model, state, voxel, vc, half_edges, pieces, partial, uint8_t(key % 8), position)) {
      return fail("vertex of a piece without surface in voxel " + std::to_string(voxel));
    }
    if ((position - s.positions[slot]).norm() > 1e-5f * float(l.voxel_size)) {
      return fail("stale vertex position in voxel " + std::to_string(voxel));
    }
  }
  if (live_vertices != s.vertex_of_piece.size()) return fail("vertex map holds freed slots");
  for (uint32_t slot : s.free_vertices) {
    if (s.vertex_piece[slot] != CutSurface::kFreeKey) return fail("free list holds a live vertex");
  }

  // Every existing half-edge has its quad joining the sharing pieces' vertices.
  uint32_t half_edges = 0;
  const auto check_half_edge = [&](uint32_t edge, int side) -> bool {
    Vec3d point, normal;
    if (!half_edge(model, state, edge, side, point, normal)) return true;
    ++half_edges;
    uint32_t around[4];
    uint8_t pieces[4];
    if (!half_edge_sharing(model, state, edge, side, around, pieces)) {
      return fail("half-edge of edge " + std::to_string(edge) + " has no four sharing pieces");
    }
    const uint32_t quad = s.quad_of_half_edge.get(half_edge_key(edge, side));
    if (quad == kDeadIndex) return fail("half-edge of edge " + std::to_string(edge) + " has no quad");
    if (s.quad_half_edge[quad] != half_edge_key(edge, side)) return fail("quad slot not owned by its half-edge");
    uint32_t want[4];
    for (int q = 0; q < 4; ++q) want[q] = s.vertex_of_piece.get(piece_key(around[q], pieces[q]));
    std::sort(want, want + 4);
    uint32_t have[6] = {s.triangles[2 * quad][0],     s.triangles[2 * quad][1],     s.triangles[2 * quad][2],
                        s.triangles[2 * quad + 1][0], s.triangles[2 * quad + 1][1], s.triangles[2 * quad + 1][2]};
    std::sort(have, have + 6);
    uint32_t* end = std::unique(have, have + 6);
    if (end - have != 4 || !std::equal(want, want + 4, have)) {
      return fail("quad of edge " + std::to_string(edge) + " does not join its sharing pieces");
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
    for (int side = 0; side < 2; ++side) {
      if (!check_half_edge(edge, side)) return false;
    }
  }
  if (half_edges != s.quad_of_half_edge.size()) {
    return fail("quads outlive their half-edges (" + std::to_string(s.quad_of_half_edge.size()) + " quads, " +
                std::to_string(half_edges) + " half-edges)");
  }
  for (uint32_t quad : s.free_quads) {
    if (s.quad_half_edge[quad] != CutSurface::kFreeKey) return fail("free list holds a live quad");
  }
  return true;
}

uint64_t cut_memory_bytes(const CutState& state) {
  return state.edge_cuts.capacity() * sizeof(EdgeCut) + state.edge_cut_of.memory_bytes() +
         state.divided.capacity() * sizeof(DividedVoxel) + state.divided_of.memory_bytes() +
         state.fronts.capacity() * sizeof(VoxelFront) + state.front_of.memory_bytes();
}

}  // namespace dvx
