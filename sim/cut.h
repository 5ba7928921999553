// Progressive cutting with the divide operator on a non-manifold voxel grid, and the
// dual-contoured surface kept up to date as the blade moves (paper sections 3-4, DESIGN §3).
//
// Model and state. The VoxelModel (signs + Hermite data of the uncut organ) is immutable; a
// CutState holds everything cutting adds, explicitly and only where cuts happen:
//
// - EdgeCut: a lattice edge crossed by the blade, with its lowest and highest crossing. Material
//   does not connect across a cut edge. Each inside end of an edge sees the nearest boundary along
//   the edge (mesh crossing or cut): that "half-edge" carries the Hermite data dual contouring uses.
//   Every crossing is kept as material: cuts have no thickness, so the intervals between crossings
//   of an edge are all material. On an edge with both ends inside, the lower end owns [0, t_lo] and
//   the upper end everything above t_lo (both half-edges sit at t_lo): a sliver between two
//   crossings (a V-notch's wedge, a hairpin's tongue, a blade turning back within one voxel) stays
//   material, in the upper node's piece, and the surface keeps its volume. What one vertex per patch
//   cannot show there is the second sheet on that edge: the sliver is not separated from the upper
//   piece (it holds no node, so the physics could not move it on its own either). The lowest and
//   the highest crossing are all this needs, so no list of crossings is stored. On a surface edge
//   (one end inside) the inside end sees its nearest cut; the material between the outermost cut
//   and the surface crossing holds no node and is dropped (measured: cut_dropped_length).
//
// - DividedVoxel: a voxel with at least one cut edge. Its inside corner nodes are grouped into
//   *pieces*: the connected components of the voxel's material graph (see voxel_material_joins for
//   the one rule). Each piece is one of the paper's divided voxels; a voxel completely cut has two or
//   more pieces, a partially cut voxel has a piece holding both ends of a cut edge. Sides are kept
//   per piece, not per node, so crossing cuts, helices and blades that turn back need no special
//   case. An uncut voxel is one implicit piece with all its inside corners.
//
// - Edge-sharing is derived, never stored stale: the half-edge (edge e, inside end n) is shared by
//   the piece holding n in each of the four voxels around e. An uncut material edge is shared by 4
//   pieces; a cut edge by up to 8 (4 per side) — the non-manifold connectivity of the paper.
//
// Surface (manifold dual contouring, Schaefer-Ju-Warren 2007 / Nielson 2004). One vertex per
// *patch* of a voxel, not per voxel or piece: the surface inside a voxel meets the voxel's faces
// in curves joining the half-edge points on the face's perimeter; on each face the points are
// paired by the face's own data (voxel_face_pairs), so both voxels sharing a face agree, and a
// patch is a cycle of such pairs (a loop on the voxel's boundary). A patch bounds one piece. One
// quad (two triangles) per half-edge joins the patches holding it in the four voxels around its
// edge, oriented from the inside end outward. A fully cut (or uncut) patch's vertex minimises the
// QEF of its half-edges; a partly cut patch (holding both half-edges of a cut edge: the slit's tip
// runs through the voxel) sits at the average of the cut front's face points in that voxel (paper
// Fig. 5), which keeps the singular vertices synchronised and closes the slit at the front. The
// static dual_contour is this same construction on a state without cuts. Vertex and triangle
// slots are stable (free lists), and each step reports dirty slot ranges for the renderer.
#pragma once

#include "sim/blade_sweep.h"
#include "sim/contour.h"
#include "sim/flat_map.h"
#include "sim/surface_mesh.h"
#include "sim/tasks.h"
#include "sim/voxel_model.h"

#include <cstdint>
#include <string>
#include <vector>

namespace dvx {

constexpr uint8_t kNoPiece = 0xFF;
constexpr uint32_t kDeadIndex = ~0u;  // triangle slots not in use hold {kDeadIndex x3}

// A lattice edge the blade has crossed (36 bytes: one per cut edge, kept flat).
struct EdgeCut {
  uint32_t edge;
  float t_lo, t_hi;  // lowest / highest crossing parameter along the edge (from its lower node)
  Vec3f normal_lo;   // blade normal at t_lo (unit; oriented by the reader)
  Vec3f normal_hi;   // blade normal at t_hi
};
static_assert(sizeof(EdgeCut) == 36, "EdgeCut: 4 + 2 x 4 + 2 x 12 bytes, no padding");

// A voxel with at least one cut edge, split into pieces (the paper's divided voxels).
struct DividedVoxel {
  uint32_t voxel;
  uint8_t corner_piece[8];  // piece of each corner node (corner c = dx | dy<<1 | dz<<2), kNoPiece outside
  uint8_t piece_count;
  uint8_t partial_mask;     // bit p: piece p holds both ends of a cut edge (the voxel is partly cut)
  uint16_t cut_edges;       // bit e: voxel edge e (see kVoxelEdges in sim/lattice.h) is cut
  uint16_t air_edges;       // bit e: surface edge e crossed by the blade outside the material only
};

// The pieces and surface patches of a voxel as far as they follow from its inside corners and its
// cut and air edges alone (no positions): a pure function of those 32 bits, so divided voxels share
// it through a memo (a cut meets few distinct cases) and uncut voxels read it from a 256-entry table.
struct PatchShape {
  uint32_t present;                // bit h (2 * voxel edge + side): the half-edge exists
  uint32_t patch_half_edges[12];   // bit h: patch p holds half-edge h
  uint8_t patch_of[24];            // patch of each present half-edge
  uint8_t patch_piece[12];         // piece each patch bounds
  uint8_t corner_piece[8];         // piece of each corner, kNoPiece outside
  uint8_t patch_count, piece_count;
  uint8_t piece_partial;           // bit p: piece p holds both ends of a cut edge
  bool doubled;                    // a face holds two curves of one patch (merges possible)
  uint16_t patch_partial;          // bit p: patch p holds both half-edges of a cut edge
};

// A voxel's surface vertices as refresh_voxels computes them from its patches, before it writes
// them (computed apart so a block of voxels can be computed over the workers; written in order, so
// the slots are the ones a single pass allocates).
struct VoxelVertices {
  uint32_t present;              // bit h: the half-edge exists (the voxel's half-edge mask)
  uint8_t patch_count;
  bool current;                  // (a voxel across a listed one) its vertices are already these
  uint8_t patch_piece[12];       // piece each patch bounds
  uint32_t patch_half_edges[12];  // bit h: patch p holds half-edge h
  Vec3f position[12];            // each patch's vertex
};

// The quads of one lattice edge's two half-edges, as refresh_voxels writes them and
// check_cut_state expects them.
struct EdgeQuads {
  bool exists[2] = {false, false};   // the half-edge exists and all its patches have vertices
  bool missing[2] = {false, false};  // the half-edge exists but a sharing patch has no vertex
  uint32_t v[2][4];                  // vertices, counter-clockwise seen from outside
  int diagonal[2] = {-1, -1};        // forced split (see write_quad)
  bool on_cut[2] = {false, false};
};

// Points where the cut front crosses the faces of one voxel (paper Fig. 5: the "face vertices").
// The front is the blade's current edge plus the trails its two ends leave; trail crossings are
// kept for good (they do not depend on how the motion was split into steps), crossings of the
// blade's edge are replaced when the blade moves on from them and kept while another stroke cuts
// elsewhere (see parked_voxels).
struct VoxelFront {
  uint32_t voxel;
  uint32_t trail_count;
  uint32_t blade_count;
  Vec3f trail_sum;  // sum of trail face points (scene coordinates)
  Vec3f blade_sum;  // sum of the current blade edge's face points and of its ends inside the voxel
};

// The incrementally maintained dual-contoured surface with stable slots.
struct CutSurface {
  std::vector<Vec3f> positions;        // (vertex slots)
  std::vector<uint64_t> vertex_piece;  // (vertex slots) piece key voxel*8+piece of its patch, kFreeKey when free
  std::vector<uint64_t> vertex_patch;  // (vertex slots) patch key voxel*16+patch, kFreeKey when free
  std::vector<uint32_t> vertex_half_edges;  // (vertex slots) bit 2*e+side: the patch holds that half-edge
  std::vector<Tri> triangles;          // (triangle slots) two per quad slot: 2q, 2q+1
  std::vector<uint64_t> quad_half_edge;  // (quad slots) half-edge key edge*2+side, kFreeKey when free
  std::vector<uint8_t> triangle_cut;     // (triangle slots) 1: on a cut face (its boundary is a blade crossing)
  std::vector<uint32_t> free_vertices;
  std::vector<uint32_t> free_quads;
  // patch key voxel*16+patch -> vertex slot (patches of a voxel: 0..n-1), a voxel's first four in one
  // cache line (read together: a voxel's patches, the patches around an edge)
  GroupedFlatMap<4, 2> vertex_of_patch;
  // half-edge key edge*2+side -> quad slot, an edge's two sides in one cache line (read together)
  GroupedFlatMap<1, 1> quad_of_half_edge;
  // Slots written since the last clear_dirty(): [begin, end) (empty when begin >= end).
  uint32_t dirty_vertex_begin = 0, dirty_vertex_end = 0;
  uint32_t dirty_triangle_begin = 0, dirty_triangle_end = 0;

  static constexpr uint64_t kFreeKey = ~uint64_t(0);
  uint32_t live_vertices() const { return uint32_t(positions.size() - free_vertices.size()); }
  uint32_t live_triangles() const { return uint32_t(triangles.size() - 2 * free_quads.size()); }
  void clear_dirty() { dirty_vertex_begin = dirty_vertex_end = dirty_triangle_begin = dirty_triangle_end = 0; }
};

// Scratch of a cut step, reused from step to step so a cut allocates nothing in steady state. Not
// state: no hash reads it, and a copy of a CutState (undo keeps copies) copies none of it.
struct CutScratch {
  std::vector<EdgeHit> hits;
  std::vector<uint32_t> voxels, edges, touched, across;
  std::vector<double> params;
  std::vector<uint32_t> blade_voxels;  // the blade edge's points' voxels and points (update_front)
  std::vector<Vec3f> blade_points;
  std::vector<uint32_t> corners;       // the next touched_vertices, as cut_update_surface fills it
  std::vector<uint32_t> quads;         // the next touched_quads
  std::vector<uint64_t> listed;        // refresh_voxels' list as bits from a window's start: all zero
                                       // between calls (it clears the bits it set), grown, never shrunk
  // The edges refresh_voxels handles, in order: listed before their quads are written, so the hash
  // slots of the ones a few ahead are fetched while one is worked on.
  struct ListedEdge {
    uint32_t edge;
    uint32_t around[4];   // the voxels around it (voxels_around_edge)
    uint8_t corners[4];   // the edge's lower node's corner in each
    bool cut;             // the edge is cut
  };
  std::vector<ListedEdge> listed_edges;
  // refresh_voxels' blocks: the vertices of a block of voxels and the quads of a block of edges,
  // computed over the workers, then written in list order (VoxelVertices, EdgeQuads).
  std::vector<VoxelVertices> voxel_plans;
  std::vector<EdgeQuads> edge_plans;
  CutScratch() = default;
  CutScratch(const CutScratch&) {}
  CutScratch& operator=(const CutScratch&) { return *this; }
  CutScratch(CutScratch&&) = default;
  CutScratch& operator=(CutScratch&&) = default;
};

struct CutState {
  std::vector<EdgeCut> edge_cuts;        // (cut edges)
  FlatMap edge_cut_of;                   // lattice edge -> index in edge_cuts
  FlatMap air_edges;                     // surface edges crossed outside the material only (value 0):
                                         // they cut no material but the faces they bound
  std::vector<DividedVoxel> divided;     // (divided voxels)
  FlatMap divided_of;                    // lattice voxel -> index in divided
  std::vector<VoxelFront> fronts;        // (voxels the cut front has passed)
  FlatMap front_of;                      // lattice voxel -> index in fronts
  std::vector<uint32_t> blade_voxels;    // voxels holding points of the current blade edge
  std::vector<uint32_t> parked_voxels;   // voxels holding an earlier stroke's last blade edge (a slit tip
                                         // holds still until the blade comes back to its voxel)
  std::vector<uint32_t> pending_voxels;  // voxels cut_divide changed, for cut_update_surface (sorted)
  std::vector<uint32_t> changed_voxels;  // voxels the last step refreshed (sorted), for the PBD model
  // The last step's voxels whose cut or air edges changed, as voxel << 32 | their pieces before the
  // step (4 bits per corner c at bit 4c, 0xF outside), sorted: only their pieces can differ (the
  // others' vertices moved: a widened crossing, the front), so the PBD model looks only at these.
  std::vector<uint64_t> reshaped_voxels;
  std::vector<uint64_t> pending_reshaped;  // the same, as cut_divide finds them (unsorted, repeats)
  std::vector<uint32_t> changed_vertices;  // vertex slots the last step wrote or freed (unsorted)
  // Of the last surface update that changed the surface (surface_changes counts them): the vertex
  // slots it wrote or freed and the corners, old and new, of the triangles it wrote or freed
  // (repeats): every vertex whose position or triangles changed, so the PBD model's contact points
  // (sim/contact.h) are rebuilt only for the pieces the cut touched. An update that changes nothing
  // (a blade moving through air) leaves them alone. touched_quads: the quad slots it wrote or freed
  // (where the contact points look for their triangles, sim/contact_points.cpp).
  std::vector<uint32_t> touched_vertices;
  std::vector<uint32_t> touched_quads;
  uint64_t surface_changes = 0;
  Lattice lattice;                       // the fine lattice (vertex_quads without the model)
  std::vector<PatchShape> shapes;        // memo of divided voxels' shapes (see PatchShape)
  FlatMap shape_of;                      // inside corners | cut edges << 8 | air edges << 20 -> index in shapes
  CutSurface surface;
  ContourParams contour;                 // vertex placement rule (as dual_contour)
  BladePose last_blade;                  // where the last step left the blade (valid when steps > 0)
  uint64_t steps = 0;                    // cut steps applied
  CutScratch scratch;                    // never copied (see CutScratch)
};

// What one cut step did.
struct CutStepStats {
  uint32_t edges_hit = 0;           // lattice edges crossed by the swept quad (with repeats)
  uint32_t edges_cut = 0;           // material or surface edges whose cut state changed
  uint32_t voxels_cut = 0;          // voxels whose pieces were recomputed (newly or further divided)
  uint32_t voxels_divided = 0;      // divided voxels in total after the step
  uint32_t vertices_changed = 0;    // vertex slots written or freed
  uint32_t triangles_changed = 0;   // triangle slots written or freed
  uint32_t seam_edges = 0;          // edges cut_close_seams cut closing partly cut voxels
  uint32_t hole_edges = 0;          // edges cut_close_seams cut closing holes in the stroke's cut
};

// Builds the initial state: no cuts, the closed dual-contoured surface of the uncut model (the
// same surface dual_contour returns: it is built by this function).
void init_cut_state(const VoxelModel& model, CutState& state, const ContourParams& params = {}, const TaskRunner& tasks = {});

// Cuts with the quad swept by the blade from `from` to `to` and updates pieces and surface:
// cut_divide then cut_update_surface (split so callers can time the two phases).
CutStepStats cut_step(const VoxelModel& model, CutState& state, const BladePose& from, const BladePose& to);

// Phase 1: finds the crossed edges, records the cuts, divides the voxels around them and moves the
// cut front. Leaves the voxels whose pieces or vertices must be refreshed in state.pending_voxels.
void cut_divide(const VoxelModel& model, CutState& state, const BladePose& from, const BladePose& to,
                CutStepStats& stats);
// At the end of a stroke through moving tissue: closes its seams. Where the tissue moved and deformed
// between steps, a strip's start and the last one's end can disagree by up to a fine voxel, leaving
// holes in the cut surface that keep the sides joined. Each voxel the stroke left partly cut
// (`stroke_voxels`, any order and repeats; partial_mask) has the material edges cut that the plane of
// its cuts (through their crossings, normal to their mean normal) crosses: a hole a voxel wide closes;
// a real edge of the cut (a blade tip inside the tissue) moves by at most a voxel. Then the holes up
// to ~3.6 voxels wide that closing leaves inside the cut (where its crossings surround them), and the
// edges between nodes on either side of it along its normal's axis (strips that pass a plane of
// nodes on either side, or overlap across it), are cut through (CutStepStats::hole_edges). Leaves
// its voxels in state.pending_voxels (then cut_update_surface); sorts `stroke_voxels` and drops its
// repeats.
void cut_close_seams(const VoxelModel& model, CutState& state, std::vector<uint32_t>& stroke_voxels,
                     CutStepStats& stats);
// Phase 2: refreshes pieces, vertices and quads of state.pending_voxels (moves them to changed_voxels).
void cut_update_surface(const VoxelModel& model, CutState& state, CutStepStats& stats, const TaskRunner& tasks = {});

// The live quads around vertex slot `slot`: those on the half-edges its patch holds (a quad joins the
// patches holding its half-edge), in the order of its half-edges; each names the slot in one or both
// of its triangles, and every live triangle naming the slot is in one of them. None for a free slot.
// At most one per half-edge of a voxel.
constexpr int kMaxVertexQuads = 24;
uint32_t vertex_quads(const CutState& state, uint32_t slot, uint32_t out[kMaxVertexQuads]);

// The surface as a compact mesh (live slots only; vertex_voxel filled).
SurfaceMesh compact_surface(const CutSurface& surface);

// The enclosed volume of each connected component (triangles sharing a vertex) of a surface, in the
// order of each component's lowest vertex: the pieces a cut made and how small the smallest is (the
// crumb rule, docs/cutting.md; summary.json "strokes").
std::vector<double> component_volumes(const SurfaceMesh& mesh);

// Faces of a voxel: the 4 corners of face f (x=0, x=1, y=0, y=1, z=0, z=1) in cyclic order.
extern const uint8_t kVoxelFaceCorners[6][4];

// The one rule for which inside corners of a voxel are joined (its material graph), shared by the
// surface (patches) and the PBD model (through voxel_pieces). Two inside corners are joined
//  - along a voxel edge the blade has not cut (cut_edges bit e, edges as in kVoxelEdges of sim/lattice.h:
//    x edges 0-3, y edges 4-7, z edges 8-11), and
//  - across an *ambiguous* face (its two inside corners diagonal, the other two outside) when the
//    blade has cut none of that face's edges: a thin ridge crossing the face diagonally is one
//    material, and this choice reproduces the input's topology on the shared meshes at 128 where
//    keeping them apart gives handles (the armadillo: Euler characteristic 0). A face the blade
//    cuts always separates its two sides.
//  - never across the voxel's body diagonal.
// Returns the bit mask of faces f whose diagonal joins (bit f set), for corner_inside (bit c: corner
// c inside).
uint8_t voxel_material_joins(uint8_t corner_inside, uint16_t cut_edges);

// Pieces of a voxel: for uncut voxels the single implicit piece (0) of all inside corners; for
// divided voxels the components of the material graph (voxel_material_joins).
void voxel_pieces(const VoxelModel& model, const CutState& state, uint32_t voxel, uint8_t corner_piece[8],
                  uint8_t& piece_count);

// The half-edge at end `side` (0: lower node, 1: upper node) of lattice edge `edge`: false when that
// end is outside or the material runs through the whole edge; otherwise the boundary point and the
// outward normal (pointing from the end node toward the boundary).
bool half_edge(const VoxelModel& model, const CutState& state, uint32_t edge, int side, Vec3d& point,
               Vec3d& normal);

// The pieces sharing a half-edge: the voxel and piece in each of the 4 voxels around the edge, in
// counter-clockwise order about the edge axis. Returns false at the lattice border.
bool half_edge_sharing(const VoxelModel& model, const CutState& state, uint32_t edge, int side,
                       uint32_t voxels[4], uint8_t pieces[4]);

// Full consistency check of the state (tests call it after every step): divided voxels hold a cut
// edge and their pieces equal the material graph's components; vertex slots map one-to-one to the
// voxels' patches (piece, half-edges, position); every half-edge has its live quad joining the
// patches that hold it (except the two quads of a slit edge that would coincide, which cancel), and
// no quad outlives its half-edge; free lists hold only free slots; all positions are finite; and the
// surface is a closed, consistently oriented 2-manifold (no boundary, non-manifold or misoriented
// edge). Returns false with the first problem in `error`.
bool check_cut_state(const VoxelModel& model, const CutState& state, std::string& error);

// Material the surface cannot represent (measured, never silent). Material is held by lattice nodes:
// on an edge with both ends inside every interval has an owner (see EdgeCut), and on a surface
// edge the material between the inside end's nearest cut and the surface crossing holds no node
// and is dropped (at the rim where a cut meets the organ's surface, a sliver thinner than a voxel
// along that edge). Returns the summed length of those intervals in voxels; the volume dropped is
// about this times voxel_size^3.
double cut_dropped_length(const VoxelModel& model, const CutState& state);

// Bytes held by the explicit cut elements (edge cuts, divided voxels, fronts, shapes, their maps).
uint64_t cut_memory_bytes(const CutState& state);

}  // namespace dvx
