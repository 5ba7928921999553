// Deformation: position-based dynamics on coarse simulation voxels, kept in correspondence with the
// cut surface through every cut without remapping (paper section 5, DESIGN §3 "Deformation").
//
// Simulation voxels. The fine lattice is grouped into blocks of ratio^3 fine voxels (ratio = 2^l =
// resolution / sim_resolution). A block with material is a simulation voxel. Like a fine voxel, an
// uncut simulation voxel is one implicit *sim piece*; once a fine edge inside it is cut, its pieces
// are the connected components of the fine material graph inside the block (fine inside nodes
// joined by uncut fine edges), stored as one label per fine node of the block. Each sim piece is a
// shape-matching cluster with a particle at each of its 8 corners and stretching constraints along
// its 12 edges.
//
// Particles. Pieces meeting at a coarse corner share its particle when material joins them near that
// corner: the pieces of the (up to) 8 simulation voxels around the corner are united whenever a fine
// node on their common boundary belongs to both; each resulting group has one particle. So a cut
// through a region duplicates the corner particles there (the paper's divide at the coarse level),
// while a partially cut simulation voxel keeps shared particles and the cut opens only up to its
// front. Particle masses come from the material volume of the pieces using them (density x volume,
// an eighth of each piece per corner); volumes partition under cuts, so total mass is conserved.
//
// Embedding. A surface vertex belongs to a fine piece, which lies in exactly one sim piece; its
// deformed position is the trilinear interpolation of that piece's 8 particles at the vertex's rest
// position. Only surface vertices are deformed: interior fine nodes are never materialised.
//
// Threads. The solver runs constraint colour groups through a TaskRunner the caller provides (sim/
// owns no threads); constraints of one colour share no particle, so results are bit-identical for
// any number of workers.
#pragma once

#include "sim/cut.h"
#include "sim/flat_map.h"
#include "sim/voxel_model.h"

#include <Eigen/Geometry>

#include <cstdint>
#include <string>
#include <vector>

namespace dvx {

// The task interface: run fn(begin, end, user) over chunks of [0, count), possibly concurrently,
// and return when all are done. A null parallel_for runs serially.
struct TaskRunner {
  void* context = nullptr;
  void (*parallel_for)(void* context, uint32_t count, uint32_t grain,
                       void (*fn)(uint32_t begin, uint32_t end, void* user), void* user) = nullptr;
};

struct PbdParams {
  int resolution = 128;              // fine voxels along the longest axis (the scene's resolution)
  int sim_resolution = 16;           // simulation voxels along the longest axis of the object
  double density = 1000.0;
  double stretch_compliance = 1e-6;  // XPBD compliance of the edge constraints (inverse stiffness)
  double shape_stiffness = 1.0;      // shape-matching stiffness in [0, 1]
  double dt = 1.0 / 60.0;
  int substeps = 1;
  int iterations = 10;
  Vec3d gravity = Vec3d(0.0, -9.81, 0.0);
  double damping = 0.01;             // fraction of velocity removed per substep
  std::vector<Aabb> fixed;           // particles whose rest position lies in a box are anchored
};

// A shape-matching cluster: one piece of one simulation voxel.
struct SimPiece {
  uint32_t sim_voxel;
  uint8_t piece;                // piece number inside its simulation voxel
  uint8_t colour;               // shape-matching colour group
  uint32_t particles[8];        // corner particles (corner c = dx | dy<<1 | dz<<2)
  double volume;                // material volume
  Eigen::Quaterniond rotation;  // warm start of the rotation extraction
};

// A simulation voxel holding a cut: one label per fine node of its block.
struct SimDivided {
  uint32_t sim_voxel;
  uint32_t first_label;  // offset into PbdState::labels ((ratio+1)^3 labels), kNoPiece for outside nodes
  uint8_t piece_count;
};

// A stretching constraint along a simulation-voxel edge (shared by the pieces using both particles).
struct StretchConstraint {
  uint32_t a, b;
  double rest;
};

// Where a surface vertex sits: its simulation voxel and the piece there (indices into `pieces` shift
// when pieces are rebuilt; (sim voxel, piece) does not).
struct VertexEmbedding {
  uint32_t sim_voxel;  // kDeadIndex: not embedded (free slot)
  uint8_t piece;
  Vec3f local;         // rest position in the sim voxel's frame ([0,1]^3 inside it)
};

struct PbdState {
  // Simulation grid.
  int32_t ratio = 1;                 // fine voxels per simulation voxel side
  int32_t sx = 0, sy = 0, sz = 0;    // simulation voxels per axis
  double sim_size = 1.0;             // simulation voxel edge length
  Vec3d origin = Vec3d::Zero();      // = fine lattice origin

  // Particles (SoA; dead particles have mass 0 and sit in free_particles).
  std::vector<Vec3d> position, velocity, previous, rest;
  std::vector<double> mass, inv_mass;
  std::vector<uint8_t> anchored;
  std::vector<uint32_t> free_particles;

  // Pieces and topology.
  std::vector<SimPiece> pieces;
  std::vector<uint32_t> piece_of_voxel;  // (sim voxels) first piece index, kDeadIndex: no material
  std::vector<uint8_t> pieces_in_voxel;  // (sim voxels) piece count
  std::vector<SimDivided> divided;
  FlatMap divided_of;                    // sim voxel -> index in divided
  std::vector<uint8_t> labels;           // labels of divided simulation voxels

  // Constraints, grouped by colour (offsets into the arrays).
  std::vector<StretchConstraint> stretch;
  std::vector<double> stretch_lambda;
  std::vector<uint32_t> stretch_colour_begin;  // (colours + 1)
  std::vector<uint32_t> piece_order;           // piece indices sorted by colour
  std::vector<uint32_t> piece_colour_begin;    // (colours + 1)

  // Grab tool: one particle pulled towards a target through a compliant attachment.
  uint32_t grab_particle = ~0u;
  Vec3d grab_target = Vec3d::Zero();
  double grab_compliance = 1e-4;
  double grab_lambda[3] = {0, 0, 0};

  // Surface embedding (per vertex slot of the cut surface) and the deformed positions.
  std::vector<VertexEmbedding> embedding;
  std::vector<Vec3f> deformed;  // (surface vertex slots)

  PbdParams params;
  uint64_t steps = 0;
};

// Builds simulation voxels, particles, constraints and the embedding of the current surface.
// Returns false with a reason when sim_resolution does not divide the lattice into 2^l blocks.
bool init_pbd(const VoxelModel& model, const CutState& cut, const PbdParams& params, PbdState& state,
              std::string& error);

// Updates the PBD model after a cut step (uses cut.changed_voxels / changed_vertices): re-divides the
// simulation voxels holding changed fine voxels, duplicates corner particles where material separated,
// rebuilds constraints and masses, re-embeds the changed vertices. Returns the number of simulation
// voxels re-divided.
uint32_t pbd_apply_cut(const VoxelModel& model, const CutState& cut, PbdState& state);

// One time step (substeps x iterations), then the deformed surface positions.
void pbd_step(const CutState& cut, PbdState& state, const TaskRunner& tasks = {});

// Recomputes deformed positions of all live surface vertices (pbd_step calls it).
void pbd_embed(const CutState& cut, PbdState& state, const TaskRunner& tasks = {});

// Maps a point in deformed (world) space to rest space, where cuts are made: minus the inverse-distance
// weighted displacement of the 8 nearest particles. Smooth in the point, exact for translated pieces,
// first order for smooth deformation; a piece that turned far from its rest orientation is cut as if
// it had only moved (a known limitation). The blade's poses go through it before they cut.
Vec3d pbd_world_to_rest(const PbdState& state, const Vec3d& world);

// Grab tool: attach the live particle nearest to `point` (deformed space); move; release.
void grab_begin(PbdState& state, const Vec3d& point, double compliance);
void grab_move(PbdState& state, const Vec3d& target);
void grab_end(PbdState& state);

// Diagnostics.
double total_mass(const PbdState& state);
double kinetic_energy(const PbdState& state);
uint64_t count_nonfinite(const PbdState& state);
uint32_t sim_voxels_divided(const PbdState& state);

}  // namespace dvx
