// The cut's edges and front (sim/cut.h): the blade's crossings recorded on the lattice edges
// (record_cut: the cuts, no crumbs, the crossings in the air of ambiguous faces) and the cut front,
// the trail and blade points that place the vertices of partly cut voxels (update_front).
#include "sim/cut_internal.h"

#include <algorithm>
#include <cmath>

namespace dvx {
namespace cut_internal {
namespace {

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
// Least material (node_material, in fine voxels) of a component of more than kCrumbNodes nodes that
// is no crumb: one holding less is a flake along the surface or a lens between two cut sheets within
// a voxel of each other (docs/cutting.md "No crumbs"). Three voxels, not one: the measure is a box
// per node, and the surface that closes a lens tapers to its rim (the liver's two 5-node lenses of
// issue 29 measured 1.5 and 0.9 and enclosed 0.50 and 0.42 fine voxels).
constexpr double kCrumbVolume = 3.0;
// Most nodes the crumb test's flood fill visits: a component reaching this many is taken as large
// enough (the fill stays bounded; a film of 64 nodes under kCrumbVolume is ~0.05 voxel thick).
constexpr int kCrumbFloodNodes = 64;

// The material inside node n holds within its cell (the cube of one voxel centred on it), in fine
// voxels: per octant the box of its owned lengths along the three axes, each at most half a voxel
// (a node whose six edges run through uncut material holds one voxel). The owned length along an
// edge is what the cut leaves the node (EdgeCut: with both ends inside the lower end owns [0, t_lo],
// the upper end the rest; uncut, half each) or, on a surface edge, the way to the nearer of the
// surface crossing and the cut. `edge` counts as cut at t (the cut being decided).
double node_material(const VoxelModel& model, const CutState& state, uint32_t n, uint32_t edge, float t) {
  const Lattice& l = model.lattice;
  int32_t c[3];
  l.node_coords(n, c);
  const int32_t dims[3] = {l.nx, l.ny, l.nz};
  double volume = 1.0;  // the octants' boxes summed: the product over the axes of the two sides' lengths
  for (int a = 0; a < 3; ++a) {
    const uint32_t step = node_stride(l, a);
    double span = 0.0;
    for (int upper = 0; upper < 2; ++upper) {  // upper: n is the upper end of the edge (toward -a)
      if (upper ? c[a] == 0 : c[a] == dims[a]) continue;
      const uint32_t m = upper ? n - step : n + step;
      const uint32_t e = Lattice::edge(upper ? m : n, a);
      const EdgeCut* cut = find_cut(state, e);
      float t_lo = cut ? cut->t_lo : 0.f, t_hi = cut ? cut->t_hi : 1.f;
      if (e == edge) {
        t_lo = cut ? std::min(t_lo, t) : t;
        t_hi = cut ? std::max(t_hi, t) : t;
      }
      const bool severed = cut != nullptr || e == edge;
      double length;
      if (model.is_inside(m)) {
        length = !severed ? 0.5 : upper ? 1.0 - t_lo : t_lo;
      } else {
        const EdgeCrossing* x = model.find_crossing(e);
        const double ts = x ? x->t : 0.5;
        length = upper ? 1.0 - ts : ts;
        if (severed) length = std::min(length, upper ? 1.0 - double(t_hi) : double(t_lo));
      }
      span += std::clamp(length, 0.0, 0.5);
    }
    volume *= span;
  }
  return volume;
}

}  // namespace

// The shortcut of the crumb test, exact: true when n is an end of `edge` and the slab of 2 x 2 voxels
// beside n away from `edge` holds no cut (no voxel of it divided: divide_at divides the voxels around
// every edge record_cut cuts, at once) and all its 18 nodes are inside. Then its 33 edges are uncut
// material links other than `edge`, so the 18 nodes are in n's component, and each holds at least the
// half voxel of each of its sides in the slab (node_material: an uncut edge to an inside node gives
// 0.5 to the span on its side; the other sides give at least 0): per layer of 9 nodes the centre
// 0.5 x 1 x 1, the four edge-centres 0.5 x 0.5 x 1, the four corners 0.5 x 0.5 x 0.5, 2 voxels in all;
// 4 in the slab, and the flood's sum in any order is at least that (rounding is monotone, the bounds
// are exact): more than kCrumbNodes nodes holding at least kCrumbVolume, never a crumb. Four hash
// look-ups instead of the flood's ~40 in bulk material (a planar cut's every first cut of an edge).
bool bulk_behind(const VoxelModel& model, const CutState& state, uint32_t n, uint32_t edge) {
  const Lattice& l = model.lattice;
  const int a = int(edge % 3), b = (a + 1) % 3, d = (a + 2) % 3;
  const uint32_t lower = edge / 3, sa = node_stride(l, a), sb = node_stride(l, b), sd = node_stride(l, d);
  if (n != lower && n != lower + sa) return false;
  int32_t c[3];
  l.node_coords(n, c);
  const int32_t dims[3] = {l.nx, l.ny, l.nz};
  // The slab's voxel layer along a, and its nodes' second layer (n's is the first).
  const int32_t layer = n == lower ? c[a] - 1 : c[a];
  if (layer < 0 || layer >= dims[a] || c[b] < 1 || c[b] >= dims[b] || c[d] < 1 || c[d] >= dims[d]) return false;
  const uint32_t other = n == lower ? n - sa : n + sa;
  // Inside bits first (a read each), then the four voxels' hash look-ups.
  for (const uint32_t m : {n, other}) {
    for (int i = -1; i <= 1; ++i) {
      const uint32_t row = i < 0 ? m - sb : i > 0 ? m + sb : m;
      if (!model.is_inside(row - sd) || !model.is_inside(row) || !model.is_inside(row + sd)) return false;
    }
  }
  int32_t v[3];
  v[a] = layer;
  for (int i = -1; i <= 0; ++i) {
    for (int j = -1; j <= 0; ++j) {
      v[b] = c[b] + i;
      v[d] = c[d] + j;
      if (state.divided_of.contains(l.voxel(v[0], v[1], v[2]))) return false;
    }
  }
  return true;
}

// Whether severing `edge` (crossed at t) would leave inside node n in a crumb: a component of at
// most kCrumbNodes nodes, or of more holding less than kCrumbVolume fine voxels of material (a closed
// bit below the lattice's resolution: the organ's surface or another cut lies within a voxel or so
// of the cut on n's side). A flood fill over the material graph from n that stops as soon as it has
// found more than kCrumbNodes nodes holding kCrumbVolume, or kCrumbFloodNodes nodes. The divide does
// not make such a cut, so those nodes stay with the material across the edge (the mass is unchanged:
// nothing is dropped). A slit re-cut anywhere along it crosses only edges cut already or edges like
// this one: it sheds nothing.
bool material_flood(const VoxelModel& model, const CutState& state, uint32_t n, uint32_t edge, float t) {
  uint32_t found[kCrumbFloodNodes];
  int count = 1, next = 0, measured = 0;
  found[0] = n;
  double material = 0.0;  // of found[0, measured): measured only once the count is past kCrumbNodes
  while (next < count) {
    uint32_t links[18];
    const int k = material_links(model, state, found[next++], edge, links);
    for (int i = 0; i < k; ++i) {
      if (std::find(found, found + count, links[i]) != found + count) continue;
      if (count == kCrumbFloodNodes) return false;  // large enough
      found[count++] = links[i];
      if (count <= kCrumbNodes) continue;
      while (measured < count && material < kCrumbVolume) material += node_material(model, state, found[measured++], edge, t);
      if (material >= kCrumbVolume) return false;  // large enough
    }
  }
  return true;
}

namespace {

// The crumb test: the shortcut, else the flood.
bool last_material_link(const VoxelModel& model, const CutState& state, uint32_t n, uint32_t edge, float t) {
  return !bulk_behind(model, state, n, edge) && material_flood(model, state, n, edge, t);
}

// Whether severing `edge` (a cut of a surface edge, or a crossing in the air) would take the last link
// of an inside corner of an ambiguous face around it: the face no longer joins its diagonal.
bool isolates_diagonal(const VoxelModel& model, const CutState& state, uint32_t edge, float t) {
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
      if (last_material_link(model, state, p, edge, t) || last_material_link(model, state, q, edge, t)) return true;
    }
  }
  return false;
}

}  // namespace

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
      if (!state.edge_cut_of.contains(hit.edge) && isolates_diagonal(model, state, hit.edge, hit.t)) return EdgeChange::kNone;
      state.air_edges.set(hit.edge, 0);
      return EdgeChange::kAir;
    }
  }
  const uint32_t i = state.edge_cut_of.get(hit.edge);
  if (i == kDeadIndex) {
    // No crumbs: a first cut of a material edge that would leave one of its nodes in a crumb (a few
    // nodes, or a thin bit of little material) is not made: they stay with the other end (see
    // last_material_link).
    if (in0 && in1 && (last_material_link(model, state, n0, hit.edge, hit.t) ||
                       last_material_link(model, state, n1, hit.edge, hit.t))) {
      return EdgeChange::kNone;
    }
    if (in0 != in1 && !state.air_edges.contains(hit.edge) && on_ambiguous_face(model, hit.edge) &&
        isolates_diagonal(model, state, hit.edge, hit.t)) {
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

namespace {

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
  for (size_t i = 0; i < params.size(); ++i) {
    const double s = params[i];
    if (s <= previous) continue;  // a corner crossing several planes at once is one crossing
    const Vec3d point = scene_at(s);
    visit(voxel_at(0.5 * (previous + s)), point);
    // The voxel after the crossing: look slightly ahead (next larger parameter or the end; the
    // parameters are sorted, so a step forward past equal ones, not a binary search).
    size_t next = i + 1;
    while (next < params.size() && params[next] <= s) ++next;
    const double after = next == params.size() ? s1 : params[next];
    visit(voxel_at(0.5 * (s + after)), point);
    previous = s;
  }
  if (ends && s1 == 1.0) visit(voxel_at(1.0), scene_at(1.0));
}

}  // namespace

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
  walk_segment(l, from.a, to.a, false, state.scratch.params, add_trail);
  walk_segment(l, from.b, to.b, false, state.scratch.params, add_trail);
  // The blade edge now, walked once: its points in voxels with material (added below, once the
  // parked points are settled) and its voxels (sorted, to know where the blade is).
  std::vector<uint32_t>& blade_voxel = state.scratch.blade_voxels;
  std::vector<Vec3f>& blade_point = state.scratch.blade_points;
  blade_voxel.clear();
  blade_point.clear();
  walk_segment(l, to.a, to.b, true, state.scratch.params, [&](uint32_t voxel, const Vec3d& point) {
    if (!blade_voxel.empty() && blade_voxel.back() == voxel) {
      blade_voxel.push_back(voxel);  // same voxel as the last point: material already known
    } else if (has_material(model, voxel)) {
      blade_voxel.push_back(voxel);
    } else {
      return;
    }
    blade_point.push_back(point.cast<float>());
  });
  std::vector<uint32_t>& now = state.scratch.edges;
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
  std::vector<uint32_t>& touched = state.scratch.touched;
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

}  // namespace cut_internal
}  // namespace dvx
