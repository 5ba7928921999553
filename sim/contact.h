// Contact with static planes (a tray, a table): XPBD inequality constraints with Coulomb friction on
// plain particle arrays (positions, positions at the start of the substep, inverse masses; double[3]
// per particle). No dependence on the PBD model's layout: the model gathers contact points, these
// kernels solve them.
//
// What touches the plane. The visible surface interpolates the simulation particles (trilinear weights
// in its simulation piece), and a piece's corner particles lie up to one simulation voxel outside its
// material. Keeping the *particles* on the positive side would hold the surface up to a simulation
// voxel above the tray; so the constraint acts on *contact points of the embedded surface*: a piece's
// contact points (a fixed subset of its surface vertices, see "Contact points" below) near a plane,
// each the weighted sum of its piece's 8 particles (C = n . (sum_i w_i x_i - p) >= 0, gradient w_i n
// on particle i, generalised inverse mass W = sum_i w_i^2 / m_i). The surface then rests on the plane,
// and particles may sit below it. A piece is gathered when it may reach the plane within the step
// (2 fine voxels + twice its own motion, see "Reach"). Particles get only a frictionless backstop one
// simulation voxel below the plane, so a piece whose surface was not gathered cannot fall through.
//
// Friction (position level: Macklin et al. 2014 "Unified particle physics", 2019 "Small steps";
// Müller et al. 2020 "Detailed rigid body simulation with XPBD"). Each contact point accumulates,
// within a substep, its normal correction dn >= 0 and its friction correction f (a tangent vector).
// After the normal projection, the point's tangential motion since the start of the substep u_t is
// measured; the friction that would stop it is t = f - u_t. Static: while |t| <= mu_s dn the point
// sticks (t applied in full). Kinetic: otherwise |t| is clamped to mu_k dn (it slides, slowed). The
// accumulated form makes repeated iterations idempotent: iterating never applies friction twice.
#pragma once

#include "sim/mesh.h"

#include <algorithm>
#include <cstdint>
#include <utility>
#include <vector>

namespace dvx {

// A static plane: material stays on the side the normal points to.
struct ContactPlane {
  Vec3d point = Vec3d::Zero();
  Vec3d normal = Vec3d(0.0, 1.0, 0.0);  // unit length
  double static_friction = 0.5;         // sticks while friction <= static_friction x normal correction
  double kinetic_friction = 0.5;        // while sliding, friction = kinetic_friction x normal correction
};

// Signed distance of a point from a plane (positive on the material side).
inline double plane_distance(const ContactPlane& plane, const Vec3d& x) { return plane.normal.dot(x - plane.point); }

// One contact: C = normal . r - target >= 0 on the *relative point* r = sum_k weights[k] x[particles[k]]
// (up to 16 particles). Against a plane, r is a surface point (its piece's 8 trilinear weights) and
// target = normal . plane.point; between two pieces, r = (point of one) - (point of the other) (the
// other's weights negated). Gradient on particle k: weights[k] normal; generalised inverse mass
// W = sum_k weights[k]^2 / m_k. Unused slots have weight 0 (and any valid index).
struct ContactPoint {
  static constexpr int kMaxParticles = 16;
  uint32_t particles[kMaxParticles] = {};
  double weights[kMaxParticles] = {};
  Vec3d normal = Vec3d(0.0, 1.0, 0.0);
  double target = 0.0;
  double static_friction = 0.0, kinetic_friction = 0.0;
  uint32_t count = kMaxParticles;        // slots in use (8 against a plane: the loops stop there)
  double normal_total = 0.0;             // normal correction applied in this substep (a length, >= 0)
  Vec3d friction_total = Vec3d::Zero();  // friction correction applied in this substep (tangent)
  // Solver data, set by the first solve (masses do not change within a step; it also drops the
  // zero weights, which change nothing) and the first solve of each substep that presses the point:
  // what moving the point by d moves particle k (scale[k] d), the share of a requested correction
  // the point moves (gain, see kMaxLever; 0: it cannot move), the point at the start of the substep.
  uint32_t solves = 0;                   // in this substep
  bool prepared = false, started = false;
  double gain = 0.0;
  double scale[kMaxParticles] = {};
  Vec3d start = Vec3d::Zero();
};

// A contact of a surface point (8 particles, trilinear weights) with a plane.
ContactPoint plane_contact(const ContactPlane& plane, const uint32_t particles[8], const double weights[8]);

// Contact points in groups, groups in batches. The points of a group are solved in order by one
// worker (the PBD model: one group per simulation piece); the groups of one batch share no particle
// and may run concurrently (one batch per piece colour), so the result does not depend on the worker
// count. Only non-empty groups are kept. Vectors keep their capacity: no allocation per step in steady
// state.
struct ContactSet {
  std::vector<ContactPoint> points;   // by batch, then group, then in the order added
  std::vector<uint32_t> group_begin;  // (groups + 1) offsets into points
  std::vector<uint32_t> batch_begin;  // (batches + 1) offsets into the groups
  // Scratch.
  std::vector<ContactPoint> staged;
  std::vector<uint64_t> staged_key;  // batch << 32 | group
  std::vector<uint32_t> order;
  std::vector<uint32_t> group_mask;  // for the gatherer (e.g. the planes a piece may reach)
};

// Gathering: clear, add points with their batch and group, then finish (sorts them, stable).
void contacts_clear(ContactSet& set);
void contacts_add(ContactSet& set, uint32_t batch, uint32_t group, const ContactPoint& point);
void contacts_finish(ContactSet& set);
inline uint32_t contact_batches(const ContactSet& set) {
  return set.batch_begin.empty() ? 0 : uint32_t(set.batch_begin.size() - 1);
}

// Zeroes the accumulated corrections (at the start of each substep, when `previous` is reset: the
// next solve takes each point's start from it).
void contacts_begin_substep(ContactSet& set);

// The lever cap. A rigid correction d of the point moves particle k by (|w_k| / m_k / W) d: up to 1/w_k
// times d. Where the point's mobility comes only from particles it barely depends on -- a vertex on
// the anchored face of its piece has weights ~1e-8 on the free corners (W ~ 1e-14) -- a 0.01 overlap
// would throw those particles 1e5 away (what blew up the 20 000-cut stress test). So no particle moves
// more than kMaxLever times the point's correction: W_eff = max(W, max_k |w_k| / m_k / kMaxLever).
// With kMaxLever = 1 no particle moves farther than the point itself: a point of a free piece with
// even weights (a particle's own point, the centre of a face) is solved exactly in one projection,
// one with uneven weights or masses a little under-relaxed (it converges over the iterations), a
// nearly anchored one is only partly corrected, as an anchored point would be. (At 2 or 4 the
// stress test's half-anchored pieces still jitter at ~60 m/s against the contacts.)
constexpr double kMaxLever = 1.0;

// One contact: normal projection (rigid, compliance 0, lever-capped), then static/kinetic friction
// against the relative motion since `previous`. Particles with inverse mass 0 do not move; W = 0 is
// skipped.
void solve_contact_point(double* x, const double* previous, const double* inv_mass, ContactPoint& point);

// The points of group `group` (an index into group_begin), in order.
void solve_contact_group(double* x, const double* previous, const double* inv_mass, ContactSet& set, uint32_t group);

// Frictionless backstop for particles [begin, end): each stays at most `depth` below every plane.
void project_particles_to_planes(double* x, const double* inv_mass, uint32_t begin, uint32_t end,
                                 const ContactPlane* planes, uint32_t plane_count, double depth);

// ---- Piece against piece ---------------------------------------------------------------------
//
// Pieces not joined by material must not pass through each other, at the scale of the surface. The
// bodies are the connected components of the particle-sharing graph (pieces sharing a particle are
// joined by material); only surface points of different bodies touch. A body does not collide with
// itself (a flap folded onto its own body is a known limit).
//
// Contact points. A piece's surface interpolates its 8 particles, so contacts at all its vertices are
// strongly redundant (at 128 / sim 16, ~17 vertex contacts per pair of simulation pieces, all on the
// same 16 particles), and their number grows with the square of the fine voxels per simulation voxel
// (every surface vertex of an exposed piece near a partner was one: at 256 the step after a sever
// cost 35 ms). So contact acts on a fixed subset of each piece's surface vertices, its *contact
// points*: its simulation voxel (rest frame) is divided into contact_cells(ratio)^3 cells
// (kContactCells = 2 per edge, fewer where a cell would be smaller than kMinContactCell = 2 fine
// voxels), and in each cell and each of six normal directions (the dominant axis of the vertex's rest
// normal and its sign, so a cut face and the old surface meeting at a rim keep a point each) the
// vertex nearest the cell's centre is a contact point (ties: the lowest slot). The choice depends on
// the rest surface only: made per piece on first need after each cut, it never flickers between
// steps. A flat face of a piece has at most 4 contact points whatever the fine resolution; the plane
// contacts and both sides of the narrow phase use only them. Between contact points the surface
// interpolates the same particles (on a flat face, exactly: it stays on the side they hold it on); a
// face curved with radius R dips up to d^2 / 8R between two points d apart. (With 4 cells per edge,
// 16 points a face, the default recording at 128 / sim 16 made ~10 contacts per pair of pieces while
// the severed head top rested on the stump, 550-680 a step, the solve alone half the step; with 2,
// 3 a pair and ~150 a step; tests/sim/test_contact.cpp checks a fresh cut and a box on a box at 8 fine
// voxels per simulation voxel, as at 4.) A contact point's deformed
// normal is its rest normal under the piece's trilinear map (the cofactor of its Jacobian there).
//
// Reach. Each piece's own: max(2 fine voxels, a contact cell) plus twice what its fastest corner moves
// in a step ((|v| + g dt) dt), capped at a simulation voxel; a pair of pieces, or of points, may touch
// within the larger of its two reaches. (With the fastest particle's speed for everyone, a piece
// falling at 3 m/s widened the reach of every piece at rest to ~6 fine voxels.)
//
// Broad phase: the bodies' bounds, grown by their pieces' largest broad growth, swept along x; the
// pieces of bodies near another body, by their deformed bounds grown by their broad growth (reach
// less half the least reach: two growths add up to at least the pair's reach), in a uniform grid; a
// piece is *exposed* when its grown bounds overlap those of a piece of another body (the pairs come from a
// cache of the pairs within reach plus a quarter simulation voxel, kept between steps while the
// pieces stay within that margin: PairCache). Narrow phase: the
// contact points of exposed pieces (near a partner's bounds) in a grid of cell = the largest reach
// (dense over the cells they span when those are few, as in a contact zone; else hashed), each pair
// of points met once (a cell against itself and the 13 cells after it); each point
// v pairs with its nearest point q of another body within the pair's reach whose normal faces it
// (n_v . n_q < -0.9: more than ~155 degrees apart, so the rims where a cut face meets the old surface
// do not pair). The contact keeps v on the outer side of q's tangent plane: C = n_q . (x_v - x_q) >=
// -allowance, x_v and x_q the trilinear points of their pieces (16 particles, q's weights negated).
//
// Fresh cuts. The two faces of a fresh cut coincide (their vertices sit on the blade's plane to within
// the contouring's precision), so some start a hair inside the other side. Pushing them out would be a
// separating impulse; letting each step's overlap become the next step's limit would let them sink.
// So each vertex carries an *allowance*: a vertex created or moved by a cut is fresh, and at its
// first contact its allowance is its overlap then (0 where it starts with a gap: a gap may close,
// it is never held open); from then on the allowance only shrinks (to the overlap of each later step,
// to 0 when it is out of contact). Vertices that were never fresh have none: they never enter another
// body. The cut faces start in contact at zero depth and resist any deeper interpenetration. Surfaces
// farther apart than the reach (a few fine voxels) are untouched.
//
// Push-out speed. An overlap deeper than the allowance (a vertex that slipped in between the other
// body's vertices, a change of partner) is pushed out by at most max_push per step (kMaxPush fine
// voxels): a rigid correction of the whole overlap in one step would turn it into a separating speed
// of overlap / dt (what, with the gaps that fresh pairs once held open, pumped energy into the pieces
// of the 20 000-cut stress test). The allowance itself does not grow: the rest is pushed out in the
// following steps.
//
// Contacts. A pair of points that are each other's nearest make one contact (the same constraint,
// the normals within 25 degrees of opposite): the two faces of a fresh cut pair up so.
//
// Resting offset. The contacts of one face pair are redundant: several per pair of simulation pieces
// (~17 vertex pairs before the contact points, when this was measured), all on the same 16
// particles, each projected fully in turn (projected Gauss-Seidel). A projection lifts its neighbours
// too (they share its particles), and a neighbour lifted past its target cannot pull back unless it
// pushed itself, so one sweep over-separates the faces by a fraction of what it corrected. In each iteration the stretch and shape constraints
// close the faces again (the load they pass between the sides), and each sweep over-separates them
// again: the faces rest that far apart (measured on a block cut through horizontally on a tray,
// tests/sim/test_contact.cpp: the mean gap of the cut faces settles at 0.055 g dt^2 with 5 substeps
// x 2 iterations, 0.25 with 1 x 10, 0.004 with 8 x 10). A fresh cut starts at zero gap and reaches
// that offset in its first step: a separating speed of offset / dt (5.8 % of g dt at 5 x 2, 22 % at
// 1 x 10). So each substep ends with kFinalContactSweeps sweeps of the piece contacts alone (no
// stretch or shape in between to close the faces again): the accumulated clamping pulls back what
// the iterations over-pushed and the offset falls by an order of magnitude or more per sweep (with
// two: |offset| <= 0.001 g dt^2 at 5 x 2 and 1 x 10). Then the planes once more, so a substep still
// ends with the surface above them. (Not the released strain of an unconverged solve, as once
// guessed: in the first substep after the cut at 5 x 2 the stretch and shape corrections close the
// faces, -0.24 g dt^2 on their mean gap, and the contacts open them by more, +0.28; measured per
// batch kind, the contacts alone part them.) With the contact points (4 per face pair of a piece in
// that test) the sweeps are still needed: without them the faces part at 0.047 g dt at 5 x 2, 0.18 at
// 1 x 10.
//
// Colouring: the contacts between two pieces form one group (they share those pieces' 16
// particles), solved in order by one worker; groups are coloured greedily over their particles (63
// colours, a 64-bit mask per particle); a group that finds every colour taken goes to the overflow
// batch (kContactOverflow), which the caller solves serially.

constexpr uint32_t kContactOverflow = 63;
constexpr double kMaxPush = 0.2;  // fine voxels per step (see "Push-out speed")
constexpr int kFinalContactSweeps = 2;  // piece-contact sweeps closing each substep (see "Resting offset")

// A surface vertex offered to the narrow phase.
struct SurfacePoint {
  Vec3d position;  // deformed
  Vec3d normal;    // deformed, unit, outward
  uint32_t body;   // connected component of its piece (a small number: the PBD model numbers them 0..)
  uint32_t particles[8];
  double weights[8];
  float allowance;  // in: overlap it may keep (infinity: fresh); out: the updated allowance
  uint32_t slot;    // the caller's id (the PBD model: its surface vertex slot)
  uint32_t piece = 0;  // the caller's piece: contacts between two pieces form one group
  float reach = 0.0f;  // its piece's contact reach: a pair within the larger of its points' reaches may touch
};

// The broad phase's pair cache (a Verlet list): per piece slot, bounds grown by its reach plus a
// margin and its body when cached (`member`: cached), and every pair of members of different bodies
// whose cached bounds overlap. While a candidate is a member with the same body and its bounds grown
// by its reach now lie inside its cached ones, every pair whose grown bounds overlap now is among the
// cached pairs, so testing only those finds the same pairs as the grid (find_exposed_pieces). The
// entries are geometric, per piece slot: a cut that adds pieces or reuses a slot only makes the
// entries it invalidates stale. Stale candidates (new, moved out, body changed) are refreshed in
// place, paired through a grid of the members' cached bounds; more than three quarters of the
// members stale, the cache is rebuilt over the candidates (it then also drops the entries of pieces
// that are no longer candidates). On the sliced bunny at 256 (`divvox bench contact`, 168 steps)
// the cache was rebuilt twice and refreshed 120 times (at a quarter: 15 rebuilds, ~0.6 ms each
// against ~0.3 for a refresh; a sever costs either ~2 ms).
struct PairCache {
  bool valid = false;
  uint32_t pieces = 0;
  std::vector<uint8_t> member;  // (pieces) cached
  std::vector<uint32_t> body;   // (pieces) its body when cached
  std::vector<Vec3d> lo, hi;    // (pieces) grown bounds when cached
  std::vector<uint64_t> pairs;  // i << 32 | j, i < j, ascending
  uint64_t builds = 0, updates = 0;  // diagnostics: rebuilds, refreshes of stale entries
};

// Below this many stale entries the pair cache refreshes them whatever the members' count.
constexpr size_t kPairCachePartialMin = 64;

// Scratch of the piece-piece phases (kept between steps: no allocation in steady state).
struct PieceContactScratch {
  std::vector<uint32_t> parent;                   // (particles) union-find
  std::vector<uint64_t> keys;                     // cell << 32 | item
  std::vector<uint32_t> cell_begin, cell_items;   // items grouped by cell
  std::vector<uint64_t> cells;                    // distinct cell keys, in order of first appearance
  std::vector<uint32_t> cell_of, cursor;          // (keys) cell index; counts and fill cursors
  std::vector<uint32_t> table;                    // open addressing: cell index + 1 (0: empty)
  uint32_t table_bits = 1;
  std::vector<uint64_t> by_body;                  // (points) body << 32 | point, sorted (narrow phase)
  std::vector<int64_t> point_cell;                // (points x 3) cell coordinates, by rank in body order
  std::vector<uint32_t> item_body, run_end;       // (cell_items) body; end of its body's run in the cell
  std::vector<uint32_t> item_rank;                // (cell_items) rank in body order
  // Broad-phase result: the pieces of other bodies whose grown bounds overlap piece i's are
  // partners[partner_begin[i] .. partner_begin[i + 1]) (ascending).
  std::vector<uint64_t> pairs;                    // i << 32 | j, i < j (box_pairs)
  std::vector<uint64_t> sort_buffer;              // the pairs' radix sort and merge
  std::vector<Vec3d> box_lo, box_hi;              // (pieces) bounds grown by their reach (find_exposed_pieces)
  std::vector<Vec3d> cell_lo, cell_hi;            // (cell_items) a box_pairs item's bounds, by cell
  std::vector<uint64_t> both;                     // the exposed pairs (i < j)
  PairCache pair_cache;
  std::vector<uint32_t> stale;                    // pair cache entries to refresh
  std::vector<uint8_t> is_stale;                  // (pieces) the same, as flags
  std::vector<uint32_t> partner_begin, partners;
  std::vector<uint64_t> busy;                     // (particles) colour bits taken
  std::vector<uint32_t> touched;                  // particles whose busy bits are set
  std::vector<float> allowance;                   // (points) updated allowances
  // Narrow phase: the points' positions and normals in cell order (a query scans them in sequence),
  // each point's nearest facing partner, the item ranges of the cells after the query's cell.
  std::vector<Vec3d> item_position, item_normal;  // (cell_items)
  std::vector<double> item_reach;                 // (cell_items) squared reach
  std::vector<uint32_t> best;                     // (points) partner point, ~0u: none
  std::vector<double> best_d;                     // (items) squared distance to it
  std::vector<double> allowed;                    // (points) overlap its contact allows this step
  std::vector<std::pair<uint64_t, uint32_t>> pending;  // (piece pair, point) of the contacts to make
  std::vector<uint32_t> ranges;                   // begin, end pairs
  // Body broad phase: bounds of the bodies, the pairs of bodies whose grown bounds overlap, and each
  // body's overlapping bodies.
  std::vector<Vec3d> body_lo, body_hi;            // (bodies)
  std::vector<double> body_reach;                 // (bodies) the largest reach of its pieces
  std::vector<uint32_t> body_order;               // bodies by lower x bound
  std::vector<uint64_t> body_pairs;               // b << 32 | c, both directions
  std::vector<uint32_t> body_partner_begin, body_partners;
  std::vector<uint8_t> candidate;                 // (pieces) may touch another body
};

// What the contact gathers know of the PBD model's surface between its edits: the piece of each
// surface vertex slot, the slots and triangles of each piece, the bodies. A vertex slot changes piece
// only when a cut edits the model (PbdModel::revision) or the surface (CutState::steps), so the index
// is rebuilt only then and the gathers visit only the pieces near something, not every slot.
struct ContactIndex {
  uint64_t revision = ~uint64_t(0), cut_steps = ~uint64_t(0);  // what it was built from
  uint32_t slots = 0, triangle_count = 0, pieces = 0;
  // Updated incrementally after a cut (the caller's record of what it changed): `edits` records
  // seen; `updates` counts the updates, `revisited` lists the slots the last one looked up again
  // (all slots when `rebuilt`), so another cache of the slots' pieces can follow it.
  uint64_t edits = ~uint64_t(0), updates = 0;
  bool rebuilt = true;
  std::vector<uint32_t> revisited;
  uint64_t revisited_since = ~uint64_t(0);  // cut steps the last update started from
  uint64_t bodies_updates = ~uint64_t(0);  // `updates` when mobile, bodies and the corners were built
  std::vector<uint32_t> slot_piece;   // (slots) piece slot, ~0u: not embedded
  std::vector<uint32_t> piece_begin;  // (pieces + 1) offsets into piece_slots
  std::vector<uint32_t> piece_slots;  // the slots of each piece, ascending
  std::vector<uint8_t> mobile;        // (pieces) some corner particle is free (inverse mass > 0)
  std::vector<uint32_t> body_index;   // (pieces) bodies numbered 0.. (~0u: dead slot)
  uint32_t bodies = 0;
  std::vector<uint32_t> scratch;         // fill cursors; body numbers by root particle
  std::vector<uint32_t> next_begin, next_slots;  // the incremental update's new piece_begin, piece_slots
  std::vector<uint64_t> arrivals;        // (piece << 32 | slot) of the slots that changed piece
  std::vector<uint32_t> changed;         // pieces whose slots changed
  std::vector<uint32_t> flipped;         // slots that became embedded or stopped being so
};

// A contact point of a piece: a representative surface vertex slot (see "Contact points") and its
// unit outward normal at rest (the deformed normal is its image under the piece's deformation).
struct ContactRep {
  uint32_t slot;
  float normal[3];
};

// Contact cells per simulation voxel edge (see "Contact points"): kContactCells, fewer where a cell
// would be smaller than kMinContactCell fine voxels.
constexpr int kContactCells = 2;
constexpr int kMinContactCell = 2;
inline int contact_cells(int ratio) { return std::max(1, std::min(kContactCells, ratio / kMinContactCell)); }

// The simulation voxels a block of quad slots touches (see PieceContacts::quad_blocks): up to
// kQuadBlockVoxels listed, `all` once more were.
constexpr uint32_t kQuadBlock = 16;
constexpr uint32_t kQuadBlockVoxels = 6;
struct QuadBlock {
  uint32_t voxels[kQuadBlockVoxels];
  uint8_t count = 0;
  bool all = false;
};

// Everything a PBD model keeps for piece-piece contact between steps (contacts and scratch).
struct PieceContacts {
  ContactSet set;               // batch = colour (kContactOverflow: serial)
  PieceContactScratch scratch;
  std::vector<uint32_t> corners, body;  // (pieces x 8), (pieces)
  std::vector<uint8_t> live, exposed;   // (pieces)
  std::vector<Vec3d> lo, hi;            // (pieces) deformed bounds
  std::vector<double> motion, reach;    // (pieces) how far it may move this step; its contact reach
  std::vector<double> broad_reach;      // (pieces) the broad phase's growth (see "Broad phase")
  ContactIndex index;                   // also read by the plane gather
  std::vector<SurfacePoint> points;
  // Contact points (see "Contact points"): each piece's representative surface vertices, built on a
  // piece's first need after a cut changed it; the index's update and the surface update they
  // follow (a cut marks stale only the pieces it touched).
  uint64_t rep_updates = ~uint64_t(0), rep_surface_changes = 0;
  std::vector<uint32_t> rep_begin;      // (pieces) offset into reps, ~0u: to be built
  std::vector<uint16_t> rep_count;      // (pieces)
  std::vector<ContactRep> reps;         // by piece (in order of building), a piece's by slot
  std::vector<ContactRep> rep_kept;     // compaction scratch
  std::vector<uint32_t> rep_voxels;     // simulation voxels whose pieces a cut made stale, scratch
  std::vector<Vec3d> rep_normal;        // rest normals of the slots of the pieces built at once, scratch
  std::vector<uint32_t> rep_offset;     // (pieces built at once + 1) offsets of their slots, scratch
  std::vector<uint32_t> rep_scratch;    // (surface vertex slots) entry of rep_normal while built, else ~0u
  std::vector<uint64_t> rep_wanted;     // (parts x surface vertex slots, bits) the slots of a scan, scratch
  std::vector<uint64_t> rep_sim_voxels; // (parts x simulation voxels, bits) those of their pieces, scratch
  std::vector<uint32_t> rep_part;       // (pieces built at once) the part of the scan of each, scratch
  std::vector<uint64_t> rep_rank;       // their coordinate << 32 | index, scratch
  // Where the surface's quads lie, by blocks of kQuadBlock consecutive quad slots: the simulation
  // voxels of the fine voxels around each live quad's lattice edge (its corners' vertices lie in
  // those fine voxels, and their pieces in those simulation voxels). Added to as the cuts write
  // quads (CutState::touched_quads), never taken from (a freed quad leaves its voxels listed: a scan
  // then reads its block for nothing), so a scan of rest normals reads only the blocks of the
  // pieces it builds. (A box per block does not do: the surface's first quads come in lattice
  // order, and consecutive ones jump across the object from one row to the next.)
  std::vector<QuadBlock> quad_blocks;
  uint64_t quad_blocks_changes = ~uint64_t(0);  // the CutState::surface_changes they follow (~0: none yet)
  // A batch of pieces to build whose slots exceed the surface's triangles / rep_slots_per_scan is
  // built by scan_rest_normals, a smaller one through the quads around each slot (both give the
  // same bits; why 4096: build_stale_reps in sim/contact_points.cpp).
  uint32_t rep_slots_per_scan = 4096;
  uint32_t rep_slots_per_part = 16384;  // a scanned batch of at least this many slots: two parts at once
  std::vector<uint32_t> slot_marks;     // (vertex slots) stamps, scratch
  uint32_t slot_stamp = 0;
  // Pieces a cut made stale, built ahead of need once no cut has touched them for a gather
  // (build_settled_reps): a stroke's pieces are built over its steps as the blade leaves them,
  // not all in the step that severs (the points do not depend on when they are built).
  std::vector<uint32_t> rep_pending;
  std::vector<uint64_t> rep_stale_at;   // (pieces) the gather (rep_clock) that made each stale
  uint64_t rep_clock = 0;               // gathers run
  uint32_t rep_ahead_slots = 16384;     // the most slots built ahead in one gather
  std::vector<uint32_t> rep_need;       // pieces a gather needs the points of, scratch
  std::vector<uint32_t> rep_build;      // of those, the pieces to build (built at once), scratch
  std::vector<ContactRep> rep_staged;   // their points as built, a fixed stride a piece, scratch
  std::vector<uint16_t> rep_staged_count;
  // gather_surface_points' pieces in chunks over the workers: each chunk's points, the slots it
  // gathered and a piece's partner regions (partner_regions), joined in chunk order (scratch).
  struct PointChunk {
    std::vector<SurfacePoint> points;
    std::vector<uint32_t> gathered;
    std::vector<Vec3d> region_lo, region_hi;
  };
  std::vector<PointChunk> point_chunks;
  // Pieces per chunk: up to 48 contact points each, ~1 µs of work a piece (a sever at 256 exposes
  // 500-1 300 pieces; twelve bodies at rest ~1 700). The same arrays for any value.
  uint32_t point_pieces_per_chunk = 64;
  std::vector<uint32_t> gathered;       // slots of the last gather's points (before the normals)
  std::vector<float> allowance;         // (surface vertex slots) overlap it may keep (see above)
  std::vector<Vec3f> seen;              // (surface vertex slots) rest position when last seen
  uint64_t seen_steps = 0;              // CutState::steps when last seen
  uint32_t exposed_pieces = 0;          // of the last gather (diagnostics)
  // Cumulative counters (diagnostics, never part of the state hash): what the phases touched.
  struct Counters {
    uint64_t gathers = 0;       // steps that ran the narrow phase
    uint64_t piece_pairs = 0;   // piece pairs whose grown bounds were compared (broad phase)
    uint64_t points = 0;        // surface points offered to the narrow phase
    uint64_t point_pairs = 0;   // point pairs whose distance was compared (narrow phase)
    uint64_t contacts = 0;      // contacts made
    uint64_t contact_pairs = 0; // pairs of pieces with contacts (their groups)
    uint64_t reps_built = 0;    // pieces whose contact points were (re)built
    uint64_t reps_scanned = 0;  // of those, built in a batch that found its triangles in one pass over the surface
    uint64_t scans_split = 0;   // batches scanned in two parts at once
    uint64_t reps_ahead = 0;    // pieces built ahead of need (build_settled_reps)
  } counters;
};

// Bodies: the connected components of the pieces under particle sharing. `corners` holds 8 particles
// per piece (live[piece] == 0: dead slot); body[piece] = the smallest particle of its component.
void find_bodies(const uint32_t* corners, const uint8_t* live, uint32_t piece_count, uint32_t particle_count,
                 std::vector<uint32_t>& body, PieceContactScratch& scratch);

// Body broad phase: marks (candidate[piece] = 1) the live pieces whose bounds grown by their reach
// (reach[piece]) overlap the bounds of another body grown by its largest reach (body_index: bodies
// numbered 0 .. bodies - 1); only they can be exposed. Returns how many.
uint32_t find_candidate_pieces(const Vec3d* lo, const Vec3d* hi, const double* reach, const uint8_t* live,
                               const uint32_t* body_index, uint32_t bodies, uint32_t piece_count, PieceContactScratch& scratch);

// Marks the pieces whose bounds (lo, hi per piece; live as above), grown by their reach, overlap a
// piece of another body grown by its own, and lists each one's partners (scratch.partners). Returns
// how many.
uint32_t find_exposed_pieces(const Vec3d* lo, const Vec3d* hi, const double* reach, const uint8_t* live,
                             const uint32_t* body, uint32_t piece_count, std::vector<uint8_t>& exposed,
                             PieceContactScratch& scratch, uint64_t* pairs_tested = nullptr);

// find_exposed_pieces over the pieces marked in `candidate`, through the pair cache (PairCache:
// entries grown by reach + margin): the same result.
uint32_t find_exposed_pieces_cached(const Vec3d* lo, const Vec3d* hi, const double* reach, const uint8_t* candidate, const uint32_t* body, uint32_t piece_count, double margin,
                                    std::vector<uint8_t>& exposed, PieceContactScratch& scratch,
                                    uint64_t* pairs_tested = nullptr);

// Whether x lies within the pair's reach (the larger of the two pieces') of the bounds of a partner
// of `piece` (the last find_exposed_pieces): only such a surface point can be within reach of a point
// of another body (every embedded point lies in its piece's bounds), so the others need not enter
// the narrow phase.
bool near_partner(const PieceContactScratch& scratch, const Vec3d* lo, const Vec3d* hi, const double* reach,
                  uint32_t piece, const Vec3d& x);

// near_partner for many points of one piece: its partners' bounds grown by the pair's reach (once per
// piece), then whether x lies in one of them (the same answer as near_partner).
void partner_regions(const PieceContactScratch& scratch, const Vec3d* lo, const Vec3d* hi, const double* reach,
                     uint32_t piece, std::vector<Vec3d>& region_lo, std::vector<Vec3d>& region_hi);
bool in_regions(const std::vector<Vec3d>& region_lo, const std::vector<Vec3d>& region_hi, const Vec3d& x);

// Adds the contacts of `points` (see above; each pair within the larger of its points' reaches) to
// `set` (batch = colour, group = pair of pieces), coloured over `particle_count` particles, and
// updates the points' allowances; an overlap beyond the allowance is pushed out by at most
// `max_push` this step. `x` are the current particle positions (double[3]). Returns how many it added.
uint32_t gather_piece_contacts(SurfacePoint* points, uint32_t count, const double* x, uint32_t particle_count,
                               double max_push, double friction, ContactSet& set, PieceContactScratch& scratch,
                               uint64_t* pairs_tested = nullptr);

}  // namespace dvx
