// Deformation: position-based dynamics on coarse simulation voxels, kept in correspondence with the
// cut surface through every cut without remapping (paper section 5, DESIGN §3 "Deformation").
//
// Simulation voxels. The fine lattice is grouped into blocks of ratio^3 fine voxels (ratio = 2^l =
// resolution / sim_resolution). A block with material is a simulation voxel. Its *sim pieces* are
// the connected components of the fine material inside the block, from the start (not only after
// a cut): fine nodes are joined when a fine voxel of the block puts them in one of its pieces
// (cut.h's voxel_pieces, so the fine level's joining rule is the only one). A block whose material
// is one component needs no labels; a block with several keeps one label per fine node. Each sim
// piece is a shape-matching cluster with a particle at each of its 8 corners and stretching
// constraints along its 12 edges.
//
// Particles. Pieces meeting at a coarse corner share its particle only when material joins them
// there: the pieces of the (up to) 8 simulation voxels around the corner are united whenever a fine
// node on their common boundary belongs to both; each resulting group has one particle. So disjoint
// shells, thin gaps and ears are never welded, a severed piece is free, a cut duplicates the corner
// particles it separates (the paper's divide at the coarse level), and a partially cut simulation
// voxel keeps shared particles up to its front. Masses are exact: a piece holds its volume as an
// integer count of eighths of a fine voxel and gives that count to each of its 8 particles; a
// particle's mass is density x count x h^3 / 64, so the total is conserved through cuts exactly.
//
// Incremental updates. A cut step relabels only the simulation voxels holding changed fine voxels;
// their pieces and those of their 26 neighbours are detached (constraint references, masses, colour
// slots) and re-attached after the corners are re-assigned. Piece, particle and constraint slots are
// stable, with free lists; constraints sit in colour groups and leave them by swap-with-last. Colours
// are greedy over a 63-bit per-particle mask; a constraint that finds every colour taken goes to the
// overflow group, solved serially after the others (no silent cap, no race).
//
// Embedding. A surface vertex belongs to a fine piece, which lies in exactly one sim piece; it keeps
// its sim voxel and one fine node of its fine piece (the node's label names the sim piece, so a
// relabelled voxel needs no re-embedding) and its rest position. Its deformed position is the
// trilinear interpolation of that piece's 8 particles. Interior fine nodes are never materialised.
//
// Model and data. PbdModel is the topology (pieces, labels, constraints, colours, embedding); PbdData
// the dynamic state (positions, velocities, lambdas, rotations' warm starts, grab, deformed surface)
// and the caches the solver derives from the model. They are two objects passed apart, as MuJoCo's
// mj_step(const mjModel*, mjData*): cuts edit the model (and resize the data with it) between steps;
// a step reads the model (const) and writes the data; read-only queries take only what they read.
//
// Threads. Each step is one TaskRunner job (run_batches: per substep predict, per iteration the colour
// groups of each constraint type and the contact batches, velocities fused with the next substep's
// predict; a barrier between batches) that the caller's runner executes (sim/ owns no threads); constraints of one colour share no particle, so
// results are bit-identical for any number of workers.
#pragma once

#include "sim/colouring.h"
#include "sim/contact.h"
#include "sim/cut.h"
#include "sim/flat_map.h"
#include "sim/pbd_elastic.h"
#include "sim/pbd_kernels.h"
#include "sim/step_timings.h"
#include "sim/voxel_model.h"

#include <Eigen/Geometry>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace dvx {

// The elastic model of the pieces. kPaper: the paper's stretch + shape matching (solver knobs: it
// stiffens with every iteration); kNeoHookean: a material (E, nu) whose stiffness does not depend
// on the solver's budget (issue 30; the energy is corotated elasticity: sim/pbd_elastic.h says why).
enum class ElasticModel : uint8_t { kPaper, kNeoHookean };

struct PbdParams {
  int resolution = 128;              // fine voxels along the longest axis (the scene's resolution)
  int sim_resolution = 16;           // simulation voxels along the longest axis of the object
  ElasticModel elastic = ElasticModel::kPaper;
  double youngs_modulus = 5000.0;    // Pa (kNeoHookean)
  double poisson_ratio = 0.45;       // (kNeoHookean)
  double stiffness_damping = 0.0;    // s: Rayleigh stiffness-proportional damping of the strains (kNeoHookean;
                                     // a rigid motion is not slowed: `damping` below is kPaper's only)
  double density = 1000.0;           // kg/m^3 (lengths in metres: scene units x metres_per_unit)
  double stretch_compliance = 1e-6;  // XPBD compliance of the edge constraints (inverse stiffness)
  double shape_stiffness = 1.0;      // shape-matching stiffness in [0, 1]
  double dt = 1.0 / 60.0;
  int substeps = 1;
  int iterations = 10;
  Vec3d gravity = Vec3d(0.0, -9.81, 0.0);
  double damping = 0.01;             // fraction of velocity removed per time step dt ((1-d)^(1/substeps) per
                                     // substep); kPaper only (it slows rigid motion; kNeoHookean damps strains)
  std::vector<Aabb> fixed;           // particles whose rest position lies in a box are anchored
  std::vector<ContactPlane> planes;  // static contact planes (sim/contact.h)
  bool piece_contact = true;         // pieces of different bodies do not interpenetrate (sim/contact.h)
  bool global_step = false;          // kNeoHookean: a global linear solve each substep before the iterations
                                     // (sim/pbd_global.h: stiff materials at any budget)
  double piece_friction = 0.5;       // Coulomb coefficient between pieces
};

// A shape-matching cluster: one piece of one simulation voxel. Slot kDeadIndex sim_voxel: free.
struct SimPiece {
  uint32_t sim_voxel;
  uint8_t piece;           // label inside its simulation voxel
  uint8_t colour;          // shape-matching colour group
  uint32_t colour_slot;    // index in its colour group
  uint32_t particles[8];   // corner particles (corner c = dx | dy<<1 | dz<<2)
  uint64_t eighths;        // material volume in eighths of a fine voxel (exact)
  uint32_t octants[8];     // the same per octant of the block (octant c at corner c): the material
                           // model's quadrature weights (Gauss point c lies in octant c)
};

// A simulation voxel whose material has several components: labels of its fine nodes and the piece
// slot of each label.
struct SimDivided {
  uint32_t sim_voxel;
  uint32_t first_label;  // offset into PbdModel::labels ((ratio+1)^3 labels), kNoPiece for outside nodes
  uint32_t first_slot;   // offset into PbdModel::label_slots (256 piece slots)
  uint8_t piece_count;
};

// A stretching constraint along a simulation-voxel edge, shared by every piece using both particles.
struct StretchConstraint {
  uint32_t a, b;
  double rest;
  uint32_t handle;  // index in PbdModel::stretch_handles
};

// Where a stretching constraint sits, and how many piece edges use it.
struct StretchHandle {
  uint8_t colour;
  uint32_t index;  // in stretch_groups[colour]
  uint32_t refs;   // kDeadIndex: free handle
};

// Where a surface vertex sits: its simulation voxel and one fine node (block index) of its fine piece.
struct VertexEmbedding {
  uint32_t sim_voxel;  // kDeadIndex: not embedded (free slot)
  uint32_t node;       // block index of a node of the vertex's fine piece
  Vec3f local;         // rest position in the sim voxel's frame ([0,1]^3 inside it)
};

// Label pairs that touch across a face between two simulation voxels, per face (scratch of a cut step).
struct FaceCache {
  FlatMap offset;               // face (lower sim voxel * 3 + axis) -> offset in data
  std::vector<uint16_t> data;   // count, then pairs (lower label << 8 | upper label)
  void clear() {
    offset.clear();
    data.clear();
  }
};

// Scratch of the local relabelling (sim/pbd_labels.cpp relabel_local).
struct LocalSearch {
  std::vector<uint32_t> owner;    // (block nodes) search group of a visited node, kDeadIndex otherwise
  std::vector<uint32_t> queue, visited, parent, pending;
  std::vector<uint8_t> dropped, new_label;
  int32_t active[256] = {};       // per label: groups still running
};

// Scratch of the span relabelling (sim/pbd_internal.h relabel_spans): a block's fine nodes as runs
// along x ("spans", one 64-bit mask per node row), united across rows where material joins them.
struct SpanScratch {
  std::vector<uint64_t> record;     // the cut record (sim/pbd_labels.cpp record_rows) of a block without one
  std::vector<uint32_t> row_begin;  // (node rows + 1) first span of each row
  std::vector<uint64_t> mask;       // (spans) nodes of the span
  std::vector<uint32_t> parent;     // (spans) union-find
  std::vector<uint8_t> label;       // (spans) label of a root
  std::vector<uint64_t> weight;     // (ratio + 2) prefix sums of the eighths per node along x
};

// Scratch of the model's updates after a cut, reused from step to step so a cut step allocates
// nothing in steady state. Not state: copying a PbdModel (undo keeps copies of the world's state)
// copies none of it, and no hash reads it.
struct PbdScratch {
  std::vector<uint32_t> parent, parent2, sim, near, old_slots, relabelled;
  std::vector<uint8_t> labels, mark, octant_counts;
  std::vector<uint64_t> corners;
  FaceCache face_cache;
  LocalSearch search;
  SpanScratch spans;
  std::vector<uint64_t> changed, corner_ids;
  PbdScratch() = default;
  PbdScratch(const PbdScratch&) {}
  PbdScratch& operator=(const PbdScratch&) { return *this; }
  PbdScratch(PbdScratch&&) = default;
  PbdScratch& operator=(PbdScratch&&) = default;
};

// What one pbd_apply_cut did (counters for the benchmarks).
struct PbdCutStats {
  uint32_t sim_voxels = 0;       // simulation voxels relabelled
  uint32_t components_changed = 0;  // of those, whose material components changed (the others keep
                                    // their pieces: no particle or constraint is touched)
  uint32_t local_relabels = 0;   // of those, relabelled by the local search
  uint32_t span_relabels = 0;    // by spans (the whole block, O(ratio^2) rows)
  uint32_t kept_by_search = 0;   // shown unchanged by a search next to their cut (keeps_components)
  uint32_t block_relabels = 0;   // by the node-by-node labelling (ratio > 32)
  uint64_t nodes_searched = 0;   // fine nodes the local searches visited
  uint64_t spans = 0;            // spans the span relabels built
  uint32_t pieces_touched = 0;   // piece slots detached and re-attached
  uint32_t corners = 0;          // coarse corners re-assigned
};

// What the cut steps since init changed, for the caches derived from the model (the embedding rows,
// the contact index, the solver's blocks): pbd_apply_cut appends one record each, so a cache brings
// itself up to date by revisiting only what the cuts touched. A cache remembers how many records it
// has seen; records every cache has seen are dropped, and so are all of them when they grow past a
// bound (a cache that is not read every step, like the embedding of a headless replay): a cache
// that fell behind the records kept rebuilds from scratch, as does one whose model or surface
// changed otherwise (its revision or cut steps do not match the record it saw last).
struct PbdEdits {
  struct Record {
    uint64_t revision, cut_steps;                   // PbdModel::revision and CutState::steps after it
    uint32_t slots_end, voxels_end, particles_end;  // ends of its entries in the lists below
  };
  uint64_t first = 0;                      // records dropped; the first kept is number first + 1
  uint64_t base_revision = 0, base_cut_steps = 0;  // state after record `first` (or init)
  std::vector<Record> records;
  std::vector<uint32_t> slots;      // vertex slots re-embedded (CutState::changed_vertices)
  std::vector<uint32_t> voxels;     // simulation voxels relabelled (their label slots changed)
  std::vector<uint32_t> particles;  // particles whose pieces, rest position or mass changed
  uint64_t count() const { return first + records.size(); }
};

// The topology: what cuts edit (pbd_apply_cut, between steps). A step takes it const: whatever the
// solver writes, scratch and caches included, lives in PbdData.
struct PbdModel {
  // Simulation grid.
  int32_t ratio = 1;                 // fine voxels per simulation voxel side
  int32_t sx = 0, sy = 0, sz = 0;    // simulation voxels per axis
  double sim_size = 1.0;             // simulation voxel edge length
  double fine_size = 1.0;            // fine voxel edge length
  Vec3d origin = Vec3d::Zero();      // = fine lattice origin

  // Pieces: stable slots (free list). Per simulation voxel: its single piece, or its labels.
  std::vector<SimPiece> pieces;
  std::vector<uint32_t> free_pieces;
  std::vector<uint32_t> voxel_piece;     // (sim voxels) the piece slot of an undivided voxel, else kDeadIndex
  std::vector<uint32_t> voxel_divided;   // (sim voxels) index in divided, kDeadIndex: one component or none
  std::vector<uint8_t> pieces_in_voxel;  // (sim voxels) piece count
  std::vector<SimDivided> divided;
  std::vector<uint8_t> labels;           // labels of divided simulation voxels
  std::vector<uint32_t> label_slots;     // (divided x 256) piece slot per label

  // Particles' static part (SoA; a free particle has refs 0 and sits in free_particles).
  std::vector<Vec3d> rest;
  std::vector<uint64_t> mass_eighths;  // sum of the eighths of the pieces using it
  std::vector<double> mass, inv_mass;
  std::vector<uint32_t> refs;          // piece corners using it
  std::vector<uint8_t> anchored;
  std::vector<uint32_t> free_particles;

  // Constraints in colour groups; the per-particle masks of colours taken.
  std::vector<StretchConstraint> stretch_groups[kColourGroups];
  std::vector<StretchHandle> stretch_handles;
  std::vector<uint32_t> free_stretch_handles;
  FlatMap stretch_of;                            // particle pair a*2^32+b (a<b) -> handle
  std::vector<uint32_t> piece_groups[kColourGroups];  // piece slots by shape-matching colour
  std::vector<uint64_t> stretch_busy, shape_busy;     // (particles) colour bits taken

  // Surface embedding (per vertex slot of the cut surface).
  std::vector<VertexEmbedding> embedding;

  PbdParams params;

  // Scratch reused between cut steps (no allocation in steady state); never copied (PbdScratch).
  PbdScratch scratch;
  // Cuts per simulation voxel (ratio <= 32): its divided fine voxels (one 64-bit mask per (y, z)
  // voxel row) and its cut lattice edges (one mask per node row and axis), so a relabel finds the
  // block's cuts without looking up each fine voxel; with the block's inside nodes and corner
  // patterns per row (they never change), so it reads no node of the model either.
  FlatMap cut_rows_of;              // sim voxel -> offset into cut_rows (3 ratio^2 + 4 (ratio+1)^2 rows)
  std::vector<uint64_t> cut_rows;

  // Bumped by every edit of the model (init_pbd, pbd_apply_cut): the solver updates its constraint
  // blocks (PbdCache::shape_blocks) only when it changed.
  uint64_t revision = 0;
  PbdEdits edits;
};

// One batch of a solver step (pbd_step runs them through TaskRunner::run_batches): what it solves.
struct StepBatch {
  enum Kind : uint8_t { kPredict, kGlobal, kStretch, kShape, kElastic, kGrab, kPieceContact, kPlaneContact, kVelocity, kHalves };
  // kHalves' index: what each half does (SolverHalf), in this order.
  enum HalfWork : uint32_t { kHalfVelocity = 1, kHalfPredict = 2, kHalfSolve = 4 };
  uint8_t kind;
  uint32_t index;  // colour group, or contact batch; kVelocity: 1 when the next substep's predict follows in the pass; kHalves: HalfWork bits
};

// One of the solver's two halves (PbdCache::halves): a set of bodies (pieces joined through shared
// particles) with its particles and its part of every colour's constraints, in the colour's order.
// A body's constraints move only its own particles, so one thread solves a half through all its
// colours with no barrier between them while another solves the other half: the same operations on
// every particle, in the same order, as colour by colour over both.
// Its constraints name its own numbering of its particles and pieces (particles, pieces): a half
// solves on its own copy of their positions and rotations (x, previous, rotation), gathered before
// and scattered after each of its batches, so the two threads never write to one cache line while
// they solve (after a few cuts the bodies' particles interleave; sharing the lines where they meet
// cost what the split gained).
struct SolverHalf {
  std::vector<uint32_t> runs;  // its particles as ranges [runs[2i], runs[2i + 1]), ascending
  std::vector<uint32_t> particles, pieces;  // the particle and piece slot of each of its own numbers
  std::vector<double> x, previous;          // (its particles x 3) positions, and previous ones (material)
  std::vector<Eigen::Quaterniond> rotation;  // (its pieces)
  std::vector<StretchRow> stretch_rows[kColourGroups];
  std::vector<double> stretch_lambda[kColourGroups];  // parallel to stretch_rows, reset every substep
  std::vector<ShapeBlock> shape_blocks[kColourGroups];
  std::vector<ElasticRow> elastic_rows[kColourGroups];
  std::vector<double> elastic_lambda[kColourGroups];  // kElasticConstraints per row, reset every substep
  uint64_t work = 0;                                  // instructions an iteration, estimated (pbd.cpp costs)
};

// Work of the smallest chunk a step's batch is split into across workers, in instructions (the
// grains in pbd.cpp follow from it): a batch with less than two such chunks runs on one thread.
constexpr uint32_t kDefaultChunkWork = 40000;

struct GlobalStepCache;  // sim/pbd_global.cpp

// What the solver derives from the model and rebuilds from it (Jolt's SoftBodyUpdateContext, Box2D's
// arena): never hashed, and never copied — a copy of the state (undo keeps copies) starts with an
// empty cache and rebuilds it at its next step, to the same bits (tests/sim/test_pbd_incremental.cpp
// checks an updated cache against a rebuilt one).
struct PbdCache {
  // Rebuilt when the model changes (blocks_revision != PbdModel::revision; masses and rest positions
  // change only with it): the shape-matching clusters of each colour in blocks (their rest frames),
  // the stretch constraints with their masses; each step, each piece's corners in float for the
  // embedding. Updated from PbdModel::edits (the pieces using a changed particle leave their block,
  // by moving the colour's last lane into their place, and join at the end: within a colour other
  // than the overflow clusters share no particle and each lane is solved alone, so their order does
  // not change the bits; the overflow colour is rebuilt in its group's order).
  uint64_t blocks_revision = ~uint64_t(0), blocks_edits = ~uint64_t(0);
  std::vector<ShapeBlock> shape_blocks[kColourGroups];
  std::vector<uint32_t> shape_lane;    // (piece slots) colour << 26 | block << 3 | lane, ~0u: in no block
  std::vector<uint8_t> blocks_mark;    // (particles) scratch: changed by the recorded cuts
  std::vector<uint32_t> blocks_dirty;  // scratch: pieces whose clusters join again
  std::vector<StretchRow> stretch_rows[kColourGroups];  // parallel to stretch_groups
  // kNeoHookean: the hexahedra of each colour group (parallel to piece_groups, rebuilt with the blocks)
  // and their multipliers (kElasticConstraints per row, reset every substep).
  std::vector<ElasticRow> elastic_rows[kColourGroups];
  std::vector<double> elastic_lambda[kColourGroups];
  // The global step's unknowns, matrices and factorisation (sim/pbd_global.h; PbdParams::global_step).
  std::shared_ptr<GlobalStepCache> global;
  std::vector<float> piece_corners;  // (piece slots x 8 corners x 4: x, y, z, 0)
  // The embedded surface vertices as pbd_embed reads them: slot, piece slot and local position, in
  // no particular order (each row writes its own slot), so a step without a cut looks up no labels.
  // Kept in step with the contact index's slot pieces (ContactIndex::updates): after its update
  // only the slots it revisited are, else rebuilt. Unembedded slots are written (their rest
  // position) when they are revisited or rebuilt.
  std::vector<EmbedRow> embed_rows;
  std::vector<uint32_t> embed_row_of;  // (surface vertex slots) index in embed_rows, ~0u: none
  uint64_t embed_revision = ~uint64_t(0), embed_updates = ~uint64_t(0);
  // The solver's two halves, rebuilt with the blocks (pbd.cpp refresh_halves): in use (halves_on)
  // when the pieces form two or more bodies whose work splits with at least kMinHalfShare in the
  // smaller half, and the material has no global step. Then a step's iterations solve the halves
  // side by side, one barrier before the contacts, instead of one batch per colour (which, below a
  // chunk's work, runs on one thread: the sliced bunny at sim 16 solved its 6 bodies on one core).
  SolverHalf halves[2];
  bool halves_on = false;
  std::vector<uint32_t> body_root;  // scratch (particles): union-find of the bodies
  std::vector<uint64_t> body_work;  // scratch (particles): the work of the body each roots, then its half
  std::vector<uint32_t> half_number;  // scratch (particles, then piece slots): number within its half
  // The grab's multipliers (held particles x 3), reset every substep.
  std::vector<double> grab_lambda;
  // The batches of one step (parallel arrays), rebuilt every step: constraints change between steps.
  std::vector<StepBatch> step_batches;
  std::vector<TaskBatch> task_batches;

  PbdCache() = default;
  PbdCache(const PbdCache&) {}
  PbdCache& operator=(const PbdCache& other) {
    if (this != &other) *this = PbdCache();
    return *this;
  }
  PbdCache(PbdCache&&) = default;
  PbdCache& operator=(PbdCache&&) = default;
};

// The dynamic state: what a step writes. Its per-particle, per-piece and per-constraint arrays are
// parallel to the model's slots, so a cut that adds slots resizes them with it.
struct PbdData {
  std::vector<Vec3d> position, velocity, previous;  // (particle slots)
  std::vector<double> stretch_lambda[kColourGroups];  // parallel to stretch_groups
  std::vector<Eigen::Quaterniond> rotation;           // (piece slots) warm start of the rotation extraction
  // (piece slots x 9) the incompatible modes' amplitudes of the material's hexahedra (pbd_elastic.h):
  // written by the global step, held by the iterations; zero without it.
  std::vector<double> enhancement;
  // Grab tool (see "Grab" at grab_begin): the held particles and, parallel to them, their offsets
  // from the target, the compliances (m/N) and force limits (N) of their attachments. Empty: no grab.
  std::vector<uint32_t> grab_particles;
  std::vector<Vec3d> grab_offsets;
  std::vector<double> grab_compliance, grab_limit;
  Vec3d grab_target = Vec3d::Zero();
  bool grab_region = false;      // a region grab (else the single-particle grab of older recordings)
  uint32_t grab_anchored = 0;    // candidates of the region left out because they are anchored
  Vec3d grab_force = Vec3d::Zero();  // N: sum of the multipliers / h^2 of the last step's last substep
  std::vector<Vec3f> deformed;  // (surface vertex slots)
  // Contact points of this step against params.planes (grouped by piece, batched by its colour) and
  // between pieces of different bodies (sim/contact.h).
  ContactSet contacts;
  PieceContacts piece_contacts;
  uint64_t steps = 0;
  // Work per chunk of a shared batch (kDefaultChunkWork). A solver setting, not physics: the results
  // are the same bits for any value. Tests lower it so that small scenes split every batch.
  uint32_t chunk_work = kDefaultChunkWork;
  // Whether the solver may split its bodies into two halves (PbdCache::halves). A solver setting,
  // not physics: the same bits either way. Tests turn it off to compare. Turned on, it takes effect
  // when the blocks are next rebuilt (a cut, or a copy of the state); off, at once.
  bool body_halves = true;
  PbdCache cache;  // derived from the model; a copy starts empty (see PbdCache)
};

// Model and data side by side (what the world holds, sim/world.h; undo copies it whole). Not one
// object to the functions: each takes the part it reads or writes, so a step cannot edit the model.
struct PbdState {
  PbdModel model;
  PbdData data;
};

// Builds simulation voxels, particles, constraints and the embedding of the current surface.
// Returns false with a reason when sim_resolution does not divide the lattice into 2^l blocks.
bool init_pbd(const VoxelModel& model, const CutState& cut, const PbdParams& params, PbdModel& pbd, PbdData& data,
              std::string& error);

// Updates the PBD model after a cut step (uses cut.changed_voxels / changed_vertices): relabels the
// simulation voxels holding changed fine voxels, duplicates corner particles where material separated,
// updates constraints and masses of the pieces around them, re-embeds the changed vertices. Returns
// the number of simulation voxels relabelled.
uint32_t pbd_apply_cut(const VoxelModel& model, const CutState& cut, PbdModel& pbd, PbdData& data,
                       PbdCutStats* stats = nullptr);

// One time step (substeps x iterations), then (with `embed`) the deformed surface positions. A
// caller that reads PbdData::deformed only now and then (a headless replay: the state hash and
// contact read the particles, not the surface; the window, which embeds for the snapshots the
// renderer takes) passes false and calls pbd_embed before it reads; the embedding's rows are kept
// up to date either way.
// With a clock, `contact_ms` gets the time gathering the contacts took (StepTimings::contact_ms).
void pbd_step(const CutState& cut, const PbdModel& pbd, PbdData& data, const TaskRunner& tasks = {}, bool embed = true,
              const StepClock* clock = nullptr, double* contact_ms = nullptr);

// Makes the caches derived from the model (the solver's blocks, the contact index, the embedding's
// rows, the contact allowances' fresh slots) rebuild from scratch at their next use instead of following the recorded cuts (tests
// compare the two).
void pbd_forget_caches(PbdData& data);

// Recomputes deformed positions of all live surface vertices (pbd_step calls it).
void pbd_embed(const CutState& cut, const PbdModel& pbd, PbdData& data, const TaskRunner& tasks = {});

// The piece slot holding rest point `rest` (the label of the fine node nearest to it, in the
// simulation voxel containing it), kDeadIndex when that node holds no material.
uint32_t piece_at_rest(const VoxelModel& model, const PbdModel& pbd, const Vec3d& rest);
// The piece slot a surface vertex slot is embedded in, kDeadIndex when none.
uint32_t vertex_sim_piece(const PbdModel& pbd, uint32_t slot);
// The piece slot of label `label` in simulation voxel sv, kDeadIndex when none.
uint32_t piece_slot(const PbdModel& pbd, uint32_t sv, uint8_t label);
// True when the fine node nearest to local point u ([0,1]^3 in the piece's simulation voxel, clamped
// to it) belongs to the piece: u is in the piece's material to within half a fine voxel.
bool piece_holds(const VoxelModel& model, const PbdModel& pbd, uint32_t piece, const Vec3d& u);
// The rest position of a piece's corner 0, and its 8 deformed corner positions.
Vec3d piece_rest_origin(const PbdModel& pbd, uint32_t piece);
void piece_corners(const PbdModel& pbd, const PbdData& data, uint32_t piece, Vec3d corners[8]);

// Grab. The tool holds particles, each on an XPBD attachment to the target plus its offset (per axis,
// solved serially after the shape matching in every iteration; its multipliers give the force).
// grab_begin: the single-particle grab of the recordings before the region grab (the live particle
// nearest to `point`, deformed space, on a spring of `compliance`; kept bit for bit). grab_begin_region:
// the tissue around a surface point — the 8 corner particles of `piece` (the piece whose material
// holds the point, kDeadIndex: none) and every live particle within `radius` of the point — each
// held at its offset from the point as the target moves. Its `stiffness` (N/m) is split over them in
// proportion to weights w_i = mass_i (1 - d_i / 2R) (d_i: distance to the point, R the region's
// largest), so they sum to the stiffness (parallel springs: compliance 1 / (stiffness w_i)) and the
// region moves as one; its force is clamped at `force_limit` N (0: none), w_i of it per particle.
// Anchored candidates are left out (counted in grab_anchored): a region all anchored holds nothing.
void grab_begin(const PbdModel& pbd, PbdData& data, const Vec3d& point, double compliance);
void grab_begin_region(const PbdModel& pbd, PbdData& data, const Vec3d& point, uint32_t piece, double stiffness,
                       double radius, double force_limit);
void grab_move(PbdData& data, const Vec3d& target);
void grab_end(PbdData& data);
// Whether a grab is on (begun and not ended; it may hold nothing: held by an anchor).
inline bool grab_active(const PbdData& data) { return !data.grab_particles.empty() || data.grab_anchored > 0; }

// Diagnostics.
double total_mass(const PbdModel& pbd);  // exact: density x (sum of eighths) x h^3 / 64
double kinetic_energy(const PbdModel& pbd, const PbdData& data);
uint64_t count_nonfinite(const PbdModel& pbd, const PbdData& data);
uint32_t sim_voxels_divided(const PbdModel& pbd);
uint32_t live_pieces(const PbdModel& pbd);
uint32_t live_particles(const PbdModel& pbd);
uint32_t stretch_count(const PbdModel& pbd);
uint32_t overflow_constraints(const PbdModel& pbd);  // stretch + shape constraints in the overflow colour

// Full consistency check (tests call it after every cut step, like check_cut_state): every
// simulation voxel's pieces are the material components of its block, recomputed from scratch;
// particle sharing equals material adjacency at every corner of a piece; every particle's mass is
// density x volume exactly and its references count its piece corners; stretch constraints are
// exactly the unique particle pairs along piece edges, each in one colour group whose members share
// no particle (overflow excepted); every live embedding slot names a live piece. Returns false with
// the first problem in `error`.
bool check_pbd_state(const VoxelModel& model, const CutState& cut, const PbdModel& pbd, const PbdData& data,
                     std::string& error);

}  // namespace dvx
