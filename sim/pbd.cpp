// The solver of sim/pbd.h (its blocks, the batches of a step, the step) and the public functions. The
// pieces themselves live in pbd_labels.cpp (labelling, relabelling), pbd_topology.cpp (slots, colour
// groups, corner particles) and pbd_embedding.cpp (embedding, edits, embedding rows); their shared
// internals in pbd_internal.h; check_pbd_state in pbd_check.cpp.
#include "sim/pbd.h"

#include "sim/pbd_global.h"
#include "sim/pbd_internal.h"
#include "sim/pbd_kernels.h"
#include "sim/union_find.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

namespace dvx {
using namespace pbd_internal;
namespace {

// ---- Solver step -----------------------------------------------------------------------------

// ---- Solver blocks ----------------------------------------------------------------------------

// Where a piece's cluster sits in the shape blocks (PbdCache::shape_lane): its lane in the low
// kLaneBits, its block above, its colour in the top 6 bits.
constexpr int kLaneBits = 3;
static_assert(kShapeLanes <= 1 << kLaneBits && kColourGroups <= 64, "a lane code holds every lane and colour");
constexpr uint32_t kLaneMask = (1u << kLaneBits) - 1;
uint32_t lane_code(uint32_t colour, size_t block, int lane) {
  return colour << 26 | uint32_t(block) << kLaneBits | uint32_t(lane);
}

// Copies lane `from` of block `src` into lane `to` of block `dst`.
void copy_lane(ShapeBlock& dst, int to, const ShapeBlock& src, int from) {
  dst.piece[to] = src.piece[from];
  dst.inv_total[to] = src.inv_total[from];
  for (int k = 0; k < kShapeMaxParticles; ++k) {
    dst.index[k][to] = src.index[k][from];
    dst.mass[k][to] = src.mass[k][from];
    dst.moves[k][to] = src.moves[k][from];
    for (int e = 0; e < 3; ++e) dst.offset[k][e][to] = src.offset[k][e][from];
  }
}

// Adds a live piece's cluster (its rest frame from the particles' rest positions and masses) at the
// end of its colour's blocks; the overflow colour's clusters may share particles: one per block,
// solved in order. A cluster without a rest frame (no mass) joins no block.
void add_cluster(const PbdModel& s, PbdData& data, uint32_t slot) {
  const SimPiece& piece = s.pieces[slot];
  const uint32_t* particles = piece.particles;
  double rest[24];
  for (int k = 0; k < 8; ++k) {
    for (int a = 0; a < 3; ++a) rest[3 * k + a] = s.rest[particles[k]][a];
  }
  ShapeRest r;
  if (!shape_matching_rest(s.inv_mass.data(), particles, rest, 8, r)) return;
  std::vector<ShapeBlock>& blocks = data.cache.shape_blocks[piece.colour];
  const int lanes = piece.colour == kOverflowColour ? 1 : kShapeLanes;
  if (blocks.empty() || blocks.back().lanes == lanes) blocks.emplace_back();
  data.cache.shape_lane[slot] = lane_code(piece.colour, blocks.size() - 1, blocks.back().lanes);
  shape_block_add(blocks.back(), slot, particles, r);
}

// Takes a piece's cluster out of its block: the colour's last lane moves into its place (the unused
// lanes of the last block repeat its last, as shape_block_add leaves them).
void remove_cluster(PbdData& data, uint32_t slot) {
  const uint32_t code = data.cache.shape_lane[slot];
  const uint32_t colour = code >> 26, block = (code & ((1u << 26) - 1)) >> kLaneBits;
  const int lane = int(code & kLaneMask);
  std::vector<ShapeBlock>& blocks = data.cache.shape_blocks[colour];
  ShapeBlock& last = blocks.back();
  const int last_lane = last.lanes - 1;
  if (block + 1 != blocks.size() || lane != last_lane) {
    copy_lane(blocks[block], lane, last, last_lane);
    data.cache.shape_lane[blocks[block].piece[lane]] = code;
  }
  if (--last.lanes == 0) {
    blocks.pop_back();
  } else {
    for (int l = last.lanes; l < kShapeLanes; ++l) copy_lane(last, l, last, last.lanes - 1);
  }
  data.cache.shape_lane[slot] = kDeadIndex;
}

// Shape-matching rest frames of the live pieces in blocks of kShapeLanes per colour, from scratch
// (in their colour groups' order).
void build_shape_blocks(const PbdModel& s, PbdData& data) {
  data.cache.shape_lane.assign(s.pieces.size(), kDeadIndex);
  for (int c = 0; c < kColourGroups; ++c) {
    data.cache.shape_blocks[c].clear();
    for (const uint32_t slot : s.piece_groups[c]) add_cluster(s, data, slot);
  }
}

// The same from the recorded cuts: the clusters of the pieces freed or using a changed particle
// (rest position, mass, or the piece's particles and colour) leave their blocks and the live ones
// join again at the end of their colour; the overflow colour is rebuilt in its group's order.
void update_shape_blocks(const PbdModel& s, PbdData& data) {
  const PbdEdits& e = s.edits;
  const EditRange from = edits_after(e, data.cache.blocks_edits);
  std::vector<uint8_t>& mark = data.cache.blocks_mark;
  mark.resize(data.position.size(), 0);
  for (size_t i = from.particles; i < e.particles.size(); ++i) mark[e.particles[i]] = 1;
  data.cache.shape_lane.resize(s.pieces.size(), kDeadIndex);
  for (const ShapeBlock& b : data.cache.shape_blocks[kOverflowColour]) {
    for (int l = 0; l < b.lanes; ++l) data.cache.shape_lane[b.piece[l]] = kDeadIndex;
  }
  data.cache.shape_blocks[kOverflowColour].clear();
  std::vector<uint32_t>& dirty = data.cache.blocks_dirty;
  dirty.clear();
  for (uint32_t slot = 0; slot < s.pieces.size(); ++slot) {
    const SimPiece& piece = s.pieces[slot];
    const bool live = piece.sim_voxel != kDeadIndex;
    bool changed = !live;
    for (int k = 0; live && k < 8 && !changed; ++k) changed = mark[piece.particles[k]] != 0;
    if (!changed) continue;
    if (data.cache.shape_lane[slot] != kDeadIndex) remove_cluster(data, slot);
    if (live && piece.colour != kOverflowColour) dirty.push_back(slot);
  }
  for (const uint32_t slot : dirty) add_cluster(s, data, slot);
  for (const uint32_t slot : s.piece_groups[kOverflowColour]) add_cluster(s, data, slot);
  for (size_t i = from.particles; i < e.particles.size(); ++i) mark[e.particles[i]] = 0;
}

// The clusters of each parallel colour in the order of their smallest particle (unique: they share
// no particle), kShapeLanes to a block, their lanes' codes renumbered; the unused lanes of the last
// block repeat its last, as shape_block_add leaves them. The order never changes a result (a colour's
// clusters are independent); it is for the task pool, which gives each thread the same share of
// every colour (task_pool.h): with the clusters, and the stretch rows, in particle order that share
// covers about the same particles in every colour, so their cache lines stay on one core. Without
// it the blocks mix clusters from all over after a few cuts (remove_cluster moves the colour's last
// lane into each hole).
void sort_shape_lanes(PbdData& data) {
  std::vector<std::pair<uint32_t, uint32_t>> order;  // (key, block << kLaneBits | lane)
  std::vector<ShapeBlock> sorted;
  for (int c = 0; c < kOverflowColour; ++c) {
    std::vector<ShapeBlock>& blocks = data.cache.shape_blocks[c];
    order.clear();
    for (uint32_t b = 0; b < blocks.size(); ++b) {
      for (int l = 0; l < blocks[b].lanes; ++l) {
        uint32_t key = ~0u;
        for (int k = 0; k < kShapeMaxParticles; ++k) key = std::min(key, blocks[b].index[k][l]);
        order.emplace_back(key, b << kLaneBits | uint32_t(l));
      }
    }
    if (std::is_sorted(order.begin(), order.end())) continue;
    std::sort(order.begin(), order.end());
    sorted.assign((order.size() + kShapeLanes - 1) / kShapeLanes, ShapeBlock{});
    for (uint32_t i = 0; i < order.size(); ++i) {
      ShapeBlock& dst = sorted[i / kShapeLanes];
      const int lane = int(i % kShapeLanes);
      copy_lane(dst, lane, blocks[order[i].second >> kLaneBits], int(order[i].second & kLaneMask));
      dst.lanes = lane + 1;
      data.cache.shape_lane[dst.piece[lane]] = lane_code(uint32_t(c), i / kShapeLanes, lane);
    }
    if (!sorted.empty()) {
      ShapeBlock& last = sorted.back();
      for (int l = last.lanes; l < kShapeLanes; ++l) copy_lane(last, l, last, last.lanes - 1);
    }
    blocks.swap(sorted);
  }
}

void refresh_halves(const PbdModel& s, PbdData& data);

// The solver's blocks, when the model changed: the shape-matching blocks from the recorded cuts when
// they can follow them, else from scratch; the stretch constraints' rows (with the particles'
// masses: O(constraints), a copy each), those of the parallel colours in particle order (as the
// blocks above; a row's multiplier is its substep's, so they follow the rows), the overflow's in its
// group's order (it is solved in order).
void refresh_blocks(const CutState& cut, const PbdModel& s, PbdData& data) {
  if (data.cache.blocks_revision != s.revision) {
    if (edits_replayable(s, cut, data.cache.blocks_edits, data.cache.blocks_revision, 0, false) &&
        data.cache.shape_lane.size() <= s.pieces.size()) {
      update_shape_blocks(s, data);
    } else {
      build_shape_blocks(s, data);
    }
    sort_shape_lanes(data);
    for (int c = 0; c < kColourGroups; ++c) {
      std::vector<StretchRow>& rows = data.cache.stretch_rows[c];
      rows.clear();
      for (const StretchConstraint& k : s.stretch_groups[c]) rows.push_back(stretch_row(s.inv_mass.data(), k.a, k.b, k.rest));
      if (c != kOverflowColour) {
        std::sort(rows.begin(), rows.end(), [](const StretchRow& x, const StretchRow& y) { return x.a != y.a ? x.a < y.a : x.b < y.b; });
      }
    }
    // The hexahedra of the material model (kNeoHookean): each colour's pieces in their group's order
    // (a parallel colour's rows share no particle, so their order does not change the bits).
    const bool elastic = s.params.elastic == ElasticModel::kNeoHookean;
    const double eighth = s.fine_size * s.fine_size * s.fine_size / 8.0;
    for (int c = 0; c < kColourGroups; ++c) {
      std::vector<ElasticRow>& rows = data.cache.elastic_rows[c];
      rows.clear();
      for (const uint32_t slot : s.piece_groups[c]) {
        if (!elastic) break;
        const SimPiece& piece = s.pieces[slot];
        ElasticRow row;
        row.piece = slot;
        for (int a = 0; a < 8; ++a) {
          row.p[a] = piece.particles[a];
          row.w[a] = s.inv_mass[piece.particles[a]];
        }
        row.volume = double(piece.eighths) * eighth;
        // Each Gauss point's share of it: half uniform, half its octant's material. Octant weights
        // alone leave a partly filled piece's empty octants without a shear term, and its corners
        // there without stiffness (zero-energy modes: measured, the liver's surface wrinkled); the
        // uniform half keeps every mode stiff, the other half puts stiffness where the material is.
        uint64_t counted = 0;
        for (int g = 0; g < 8; ++g) counted += piece.octants[g];
        for (int g = 0; g < 8; ++g) {
          const double share = counted > 0 ? double(piece.octants[g]) / double(counted) : 0.125;
          row.octant[g] = row.volume * (0.5 * 0.125 + 0.5 * share);
        }
        rows.push_back(row);
      }
      data.cache.elastic_lambda[c].assign(rows.size() * kElasticConstraints, 0.0);
    }
    refresh_halves(s, data);
    data.cache.blocks_revision = s.revision;
  }
  data.cache.blocks_edits = s.edits.count();
}

// Grains of the step's batches: a batch below its grain is one chunk (one thread, no barrier inside
// a run of such batches). Each grain is the items of about PbdData::chunk_work instructions, from the
// costs measured on the default recording (callgrind): a stretch constraint ~36 instructions, a block
// of 8 shape-matching clusters ~2 800, a particle's velocity + predict ~30, a contact group (a piece's
// contacts with the planes, or the contacts between two pieces, often 10 or more) ~4 000. A stage
// shared by two threads costs a barrier plus the particle lines the other core wrote in the stage
// before: ~5-8 µs a stage on the 2-core machine, so a chunk under ~10 µs of work loses
// (kDefaultChunkWork). Measured with 2 workers (issue 17, bench replay / bench deform, deform p50):
// with the former grains (chunks of ~5 000-15 000 instructions) the default recording (bunny at 128,
// sim 16) ran 193 stages a step and took 1.2-1.4 ms against 0.85-0.9 ms on one thread; with these it
// runs as one stage, and liver at 64 with sim 32 (5 200 clusters) is within noise of the former
// grains (2.5 against 2.1-2.5 ms).
constexpr uint32_t kParticleCost = 30, kStretchCost = 36, kShapeBlockCost = kShapeLanes * 350, kContactGroupCost = 4000;
constexpr uint32_t kElasticCost = 2500;  // a hexahedron's 9 constraints (estimated from its operations)
constexpr uint32_t kSerial = ~0u;

// The smaller half's least share of the work for the split (PbdCache::halves): below it, one thread
// would wait at every iteration's barrier for most of the step.
constexpr double kMinHalfShare = 0.25;

// Appends lane `from` of `src` to `blocks` (a new block when the last is full).
void append_lane(std::vector<ShapeBlock>& blocks, const ShapeBlock& src, int from) {
  if (blocks.empty() || blocks.back().lanes == kShapeLanes) blocks.emplace_back();
  ShapeBlock& b = blocks.back();
  copy_lane(b, b.lanes++, src, from);
}

// The solver's halves (PbdCache::halves) from the model and the blocks just built: the bodies by
// union-find over the live pieces' corners, each body's work per iteration (the grains' costs), the
// bodies largest first (ties: the lowest particle) each to the half with less work so far; then each
// half's particle runs and its part of every colour's rows and blocks, in the colour's order (the
// overflow colour's blocks whole: one cluster each, solved in order). Off when the bodies do not
// split with kMinHalfShare in the smaller half, or with the material's global step (it solves all
// particles at once between the predict and the iterations), and not built at all where the solver
// may not use them (PbdData::body_halves: one worker), so a cut step there does not pay for them.
void refresh_halves(const PbdModel& s, PbdData& data) {
  PbdCache& c = data.cache;
  c.halves_on = false;
  // Emptied, their capacity kept: the halves are rebuilt at every model change, and rebuilt from
  // fresh arrays they grew by doubling each time. On the sliced bunny at 256 (bench contact) a
  // stroke step's rebuild took 0.39-0.43 ms, now 0.18-0.25; the whole run's 6.0-6.4 ms, now 4.2-4.6.
  for (SolverHalf& h : c.halves) {
    h.runs.clear();
    h.particles.clear();
    h.pieces.clear();
    h.x.clear();
    h.previous.clear();
    h.rotation.clear();
    for (int k = 0; k < kColourGroups; ++k) {
      h.stretch_rows[k].clear();
      h.stretch_lambda[k].clear();
      h.shape_blocks[k].clear();
      h.elastic_rows[k].clear();
      h.elastic_lambda[k].clear();
    }
    h.work = 0;
  }
  const uint32_t n = uint32_t(data.position.size());
  const bool elastic = s.params.elastic == ElasticModel::kNeoHookean;
  if (!data.body_halves || n == 0 || (elastic && s.params.global_step)) return;
  // Bodies: particles joined through the corners of each live piece.
  std::vector<uint32_t>& root = c.body_root;
  root.resize(n);
  for (uint32_t p = 0; p < n; ++p) root[p] = p;
  for (const SimPiece& piece : s.pieces) {
    if (piece.sim_voxel == kDeadIndex) continue;
    for (int k = 1; k < 8; ++k) uf_unite(root.data(), piece.particles[0], piece.particles[k]);
  }
  for (uint32_t p = 0; p < n; ++p) root[p] = uf_find(root.data(), p);
  // Work per body (at its root): particles, clusters or hexahedra, stretch rows; its low bit marks a
  // body with a piece (every cost is even).
  static_assert(kParticleCost % 2 == 0 && kElasticCost % 2 == 0 && kShapeBlockCost / kShapeLanes % 2 == 0 &&
                    kStretchCost % 2 == 0,
                "even costs: the low bit is a mark");
  std::vector<uint64_t>& work = c.body_work;
  work.assign(n, 0);
  for (uint32_t p = 0; p < n; ++p) work[root[p]] += kParticleCost;
  uint32_t solid_bodies = 0;
  for (const SimPiece& piece : s.pieces) {
    if (piece.sim_voxel == kDeadIndex) continue;
    uint64_t& w = work[root[piece.particles[0]]];
    if ((w & 1) == 0) ++solid_bodies;
    w |= 1;
    w += elastic ? kElasticCost : kShapeBlockCost / kShapeLanes;
  }
  if (solid_bodies < 2) return;
  for (int k = 0; k < kColourGroups && !elastic; ++k) {
    for (const StretchRow& r : c.stretch_rows[k]) work[root[r.a]] += kStretchCost;
  }
  // The bodies largest first, each to the lighter half.
  std::vector<std::pair<uint64_t, uint32_t>> order;
  for (uint32_t p = 0; p < n; ++p) {
    if (root[p] == p) order.emplace_back(work[p], p);
  }
  std::sort(order.begin(), order.end(),
            [](const auto& a, const auto& b) { return a.first != b.first ? a.first > b.first : a.second < b.second; });
  uint64_t total = 0;
  for (const auto& [w, r] : order) {
    const int h = c.halves[1].work < c.halves[0].work ? 1 : 0;
    c.halves[h].work += w;
    total += w;
    work[r] = uint64_t(h);  // from here on: the body's half
  }
  if (double(std::min(c.halves[0].work, c.halves[1].work)) < kMinHalfShare * double(total)) return;
  const auto half_of = [&](uint32_t particle) -> SolverHalf& { return c.halves[work[root[particle]]]; };
  // Particle runs.
  for (uint32_t p = 0; p < n; ++p) {
    std::vector<uint32_t>& runs = half_of(p).runs;
    if (!runs.empty() && runs.back() == p) {
      runs.back() = p + 1;
    } else {
      runs.push_back(p);
      runs.push_back(p + 1);
    }
  }
  // Each half's numbering of its particles (ascending: a colour's rows keep their order).
  std::vector<uint32_t>& number = c.half_number;
  number.resize(std::max<size_t>(n, s.pieces.size()));
  for (uint32_t p = 0; p < n; ++p) {
    SolverHalf& h = half_of(p);
    number[p] = uint32_t(h.particles.size());
    h.particles.push_back(p);
  }
  // Each colour's rows and blocks, in its order.
  for (int k = 0; k < kColourGroups; ++k) {
    for (const StretchRow& r : c.stretch_rows[k]) half_of(r.a).stretch_rows[k].push_back(r);
    for (const ElasticRow& r : c.elastic_rows[k]) half_of(r.p[0]).elastic_rows[k].push_back(r);
    for (const ShapeBlock& b : c.shape_blocks[k]) {
      if (k == kOverflowColour) {
        half_of(b.index[0][0]).shape_blocks[k].push_back(b);
        continue;
      }
      for (int l = 0; l < b.lanes; ++l) append_lane(half_of(b.index[0][l]).shape_blocks[k], b, l);
    }
    for (SolverHalf& h : c.halves) {
      h.stretch_lambda[k].assign(h.stretch_rows[k].size(), 0.0);
      h.elastic_lambda[k].assign(h.elastic_rows[k].size() * kElasticConstraints, 0.0);
      if (h.shape_blocks[k].empty() || k == kOverflowColour) continue;
      ShapeBlock& last = h.shape_blocks[k].back();  // its unused lanes repeat its last (shape_block_add)
      for (int l = last.lanes; l < kShapeLanes; ++l) copy_lane(last, l, last, last.lanes - 1);
    }
  }
  // The rows and blocks in the halves' numbers: particles, then pieces (numbered as first met).
  for (SolverHalf& h : c.halves) {
    for (int k = 0; k < kColourGroups; ++k) {
      for (StretchRow& r : h.stretch_rows[k]) {
        r.a = number[r.a];
        r.b = number[r.b];
      }
      for (ElasticRow& r : h.elastic_rows[k]) {
        for (uint32_t& p : r.p) p = number[p];
      }
      for (ShapeBlock& b : h.shape_blocks[k]) {
        for (int q = 0; q < kShapeMaxParticles; ++q) {
          for (int l = 0; l < kShapeLanes; ++l) b.index[q][l] = number[b.index[q][l]];
        }
      }
    }
  }
  std::fill(number.begin(), number.end(), kDeadIndex);
  const auto piece_number = [&](SolverHalf& h, uint32_t& piece) {
    if (number[piece] == kDeadIndex) {
      number[piece] = uint32_t(h.pieces.size());
      h.pieces.push_back(piece);
    }
    piece = number[piece];
  };
  for (SolverHalf& h : c.halves) {
    for (int k = 0; k < kColourGroups; ++k) {
      for (ElasticRow& r : h.elastic_rows[k]) piece_number(h, r.piece);
      for (ShapeBlock& b : h.shape_blocks[k]) {
        for (int l = 0; l < kShapeLanes; ++l) piece_number(h, b.piece[l]);
      }
    }
    h.x.resize(3 * h.particles.size());
    h.previous.resize(elastic ? h.x.size() : 0);
    h.rotation.resize(h.pieces.size());
  }
  c.halves_on = true;
}

// Grab: whether held particle i is solved (a region grab skips particles a cut freed; the
// single-particle grab keeps its former rule, a particle with mass).
bool grab_holds(const PbdModel& s, const PbdData& data, size_t i) {
  const uint32_t p = data.grab_particles[i];
  return p < data.position.size() && s.inv_mass[p] > 0.0 && (!data.grab_region || s.refs[p] > 0);
}
bool grab_moves(const PbdModel& s, const PbdData& data) {
  for (size_t i = 0; i < data.grab_particles.size(); ++i) {
    if (grab_holds(s, data, i)) return true;
  }
  return false;
}

// The batches of a whole step (all substeps: one TaskRunner job, one wake-up of the workers), in
// order: predict; per iteration the stretch colours (overflow last, serially), the shape-matching
// colours, the grab, the contact batches between pieces and with the planes; kFinalContactSweeps
// more sweeps of the piece contacts and one of the planes; then the velocities fused with the next
// substep's predict (index 1; one pass over the particles, both per particle), or alone after the
// last substep (index 0). The first chunk of each predict batch resets the substep's multipliers.
void build_step_batches(const PbdModel& s, PbdData& data, bool stretch_on, int substeps) {
  std::vector<StepBatch>& steps = data.cache.step_batches;
  std::vector<TaskBatch>& batches = data.cache.task_batches;
  steps.clear();
  batches.clear();
  const auto add = [&](uint8_t kind, uint32_t index, uint32_t count, uint32_t grain) {
    if (count == 0) return;
    steps.push_back(StepBatch{kind, index});
    batches.push_back(TaskBatch{count, grain});
  };
  const auto grain = [&](uint32_t cost) { return std::max<uint32_t>(1, data.chunk_work / cost); };
  const uint32_t particle_grain = grain(kParticleCost), stretch_grain = grain(kStretchCost);
  const uint32_t shape_grain = grain(kShapeBlockCost), contact_grain = grain(kContactGroupCost);
  const uint32_t elastic_grain = grain(kElasticCost);
  const bool elastic = s.params.elastic == ElasticModel::kNeoHookean;
  const auto add_contacts = [&](uint8_t kind, const ContactSet& set) {
    for (uint32_t b = 0; b < contact_batches(set); ++b) {
      const bool serial = b == kOverflowColour || set.points.size() < 256;
      add(kind, b, set.batch_begin[b + 1] - set.batch_begin[b], serial ? kSerial : contact_grain);
    }
  };
  const uint32_t n = uint32_t(data.position.size());
  if (n == 0) return;
  // With the halves (PbdCache::halves), each half's particles and constraints in one batch of two
  // items: the first iteration's with the predict (and, after the first substep, the velocities).
  const bool halves = data.body_halves && data.cache.halves_on;
  const auto add_halves = [&](uint32_t work) { add(StepBatch::kHalves, work, 2, 1); };
  // The first substep: its predict, then the rest of its batches (the body).
  if (halves) {
    add_halves(StepBatch::kHalfPredict | StepBatch::kHalfSolve);
  } else {
    add(StepBatch::kPredict, 0, n, particle_grain);
  }
  // The material's global step (sim/pbd_global.h), before the iterations correct it.
  if (elastic && stretch_on && s.params.global_step) add(StepBatch::kGlobal, 0, 1, kSerial);
  for (int it = 0; it < s.params.iterations; ++it) {
    if (halves && it > 0) add_halves(StepBatch::kHalfSolve);
    // The material's hexahedra (kNeoHookean), or the paper's stretch and shape matching.
    for (int c = 0; !halves && elastic && stretch_on && c < kColourGroups; ++c) {
      add(StepBatch::kElastic, uint32_t(c), uint32_t(data.cache.elastic_rows[c].size()),
          c == kOverflowColour ? kSerial : elastic_grain);
    }
    for (int c = 0; !halves && !elastic && stretch_on && c < kColourGroups; ++c) {
      add(StepBatch::kStretch, uint32_t(c), uint32_t(s.stretch_groups[c].size()), c == kOverflowColour ? kSerial : stretch_grain);
    }
    for (int c = 0; !halves && !elastic && c < kColourGroups; ++c) {
      add(StepBatch::kShape, uint32_t(c), uint32_t(data.cache.shape_blocks[c].size()),
          c == kOverflowColour ? kSerial : shape_grain);
    }
    if (grab_moves(s, data)) add(StepBatch::kGrab, 0, 1, kSerial);
    // Contact between pieces, then with the static planes, last so each iteration ends with the
    // surface above them.
    static_assert(kContactOverflow == kOverflowColour, "one overflow batch for both contact sets");
    add_contacts(StepBatch::kPieceContact, data.piece_contacts.set);
    add_contacts(StepBatch::kPlaneContact, data.contacts);
  }
  // The piece contacts' own sweeps (sim/contact.h, "Resting offset"), then the planes again so the
  // substep still ends with the surface above them.
  if (!data.piece_contacts.set.points.empty()) {
    for (int sweep = 0; sweep < kFinalContactSweeps; ++sweep)
      add_contacts(StepBatch::kPieceContact, data.piece_contacts.set);
    add_contacts(StepBatch::kPlaneContact, data.contacts);
  }
  // The other substeps: velocities fused with the next predict, then the body again.
  const size_t body = steps.size() - 1;
  for (int sub = 1; sub < substeps; ++sub) {
    if (halves) {
      add_halves(StepBatch::kHalfVelocity | StepBatch::kHalfPredict | StepBatch::kHalfSolve);
    } else {
      add(StepBatch::kVelocity, 1, n, particle_grain);
    }
    for (size_t i = 1; i <= body; ++i) {
      const StepBatch step = steps[i];
      const TaskBatch batch = batches[i];
      steps.push_back(step);
      batches.push_back(batch);
    }
  }
  if (halves) {
    add_halves(StepBatch::kHalfVelocity);
  } else {
    add(StepBatch::kVelocity, 0, n, particle_grain);
  }
}

// Grab: each held particle's compliant attachment to target + offset (XPBD, per axis), in order. A
// particle's multipliers (lambda / h^2: the force on it) are clamped to its force limit by scaling the
// vector, the position following the clamped multipliers.
void solve_grab(const PbdModel& s, PbdData& data, double h, double* lambda) {
  for (size_t i = 0; i < data.grab_particles.size(); ++i) {
    if (!grab_holds(s, data, i)) continue;
    const uint32_t p = data.grab_particles[i];
    const double w = s.inv_mass[p];
    const double alpha = data.grab_compliance[i] / (h * h);
    const Vec3d goal = data.grab_target + data.grab_offsets[i];
    double* l = lambda + 3 * i;
    double dl[3];
    for (int a = 0; a < 3; ++a) {
      const double constraint = data.position[p][a] - goal[a];
      dl[a] = (-constraint - alpha * l[a]) / (w + alpha);
    }
    const double limit = data.grab_limit[i] * (h * h);
    const double l_new[3] = {l[0] + dl[0], l[1] + dl[1], l[2] + dl[2]};
    const double norm = std::sqrt(l_new[0] * l_new[0] + l_new[1] * l_new[1] + l_new[2] * l_new[2]);
    if (!(norm > limit)) {
      for (int a = 0; a < 3; ++a) {
        l[a] += dl[a];
        data.position[p][a] += w * dl[a];
      }
    } else {
      // Over the limit: the multipliers scaled back onto it.
      const double scale = limit / norm;
      for (int a = 0; a < 3; ++a) {
        const double clamped = l_new[a] * scale;
        data.position[p][a] += w * (clamped - l[a]);
        l[a] = clamped;
      }
    }
  }
}

}  // namespace

// ---- Public API ----------------------------------------------------------------------------

bool init_pbd(const VoxelModel& model, const CutState& cut, const PbdParams& params, PbdModel& s, PbdData& data,
              std::string& error) {
  if (params.sim_resolution < 1 || params.resolution < params.sim_resolution ||
      params.resolution % params.sim_resolution != 0 ||
      ((params.resolution / params.sim_resolution) & (params.resolution / params.sim_resolution - 1)) != 0) {
    error = "resolution / sim_resolution must be a power of two (" + std::to_string(params.resolution) + " / " +
            std::to_string(params.sim_resolution) + ")";
    return false;
  }
  s = PbdModel{};
  data = PbdData{};
  s.params = params;
  ++s.revision;
  const Lattice& l = model.lattice;
  s.ratio = params.resolution / params.sim_resolution;
  s.sx = (l.nx + s.ratio - 1) / s.ratio;
  s.sy = (l.ny + s.ratio - 1) / s.ratio;
  s.sz = (l.nz + s.ratio - 1) / s.ratio;
  s.sim_size = l.voxel_size * s.ratio;
  s.fine_size = l.voxel_size;
  s.origin = l.origin;
  const uint32_t voxels = uint32_t(s.sx) * uint32_t(s.sy) * uint32_t(s.sz);
  s.voxel_piece.assign(voxels, kDeadIndex);
  s.voxel_divided.assign(voxels, kDeadIndex);
  s.pieces_in_voxel.assign(voxels, 0);

  // Pieces: the material components of every block (cuts made before init included).
  warm_block_arrays(s, true);
  for (const DividedVoxel& dv : cut.divided) note_cut_voxel(model, s, dv);
  s.scratch.labels.resize(block_nodes(s));
  for (uint32_t sv = 0; sv < voxels; ++sv) {
    const uint8_t count = s.ratio <= kSpanRatio ? label_block_spans(model, cut, s, sv, s.scratch.spans, s.scratch.labels.data())
                                                : label_block(model, cut, s, sv, s.scratch.parent, s.scratch.labels.data());
    if (count > 0) set_voxel_pieces(model, s, data, sv, s.scratch.labels.data(), count, nullptr, nullptr, 0);
  }
  // Octants of every piece (the material model's quadrature weights).
  for (uint32_t sv = 0; sv < voxels; ++sv) {
    if (has_pieces(s, sv)) piece_octants(model, s, sv);
  }
  // Particles: one per material group at every coarse corner.
  CornerMembers members;
  for (int32_t K = 0; K <= s.sz; ++K) {
    for (int32_t J = 0; J <= s.sy; ++J) {
      for (int32_t I = 0; I <= s.sx; ++I) assign_corner(model, s, data, I, J, K, members);
    }
  }
  s.scratch.face_cache = FaceCache{};
  // Constraints, colours and masses.
  for (uint32_t slot = 0; slot < s.pieces.size(); ++slot) {
    if (s.pieces[slot].sim_voxel != kDeadIndex) attach_piece(s, data, slot);
  }
  for (uint32_t p = 0; p < s.rest.size(); ++p) update_mass(s, p);
  // The embedding of every live vertex.
  grow_embedding(cut, s, data);
  for (uint32_t slot = 0; slot < cut.surface.positions.size(); ++slot) embed_vertex(model, cut, s, slot);
  warm_block_arrays(s, true);
  reserve_edits(s.edits);
  s.edits.base_revision = s.revision;  // the caches follow the cuts from here
  s.edits.base_cut_steps = cut.steps;
  pbd_embed(cut, s, data);
  return true;
}

void pbd_embed(const CutState& cut, const PbdModel& s, PbdData& data, const TaskRunner& tasks) {
  // Each piece's 8 corners in float, once (a piece serves ~40 surface vertices), padded to 4 floats
  // a corner so one corner is one 4-float vector.
  data.cache.piece_corners.resize(s.pieces.size() * 32);
  for (uint32_t slot = 0; slot < s.pieces.size(); ++slot) {
    if (s.pieces[slot].sim_voxel == kDeadIndex) continue;
    float* out = &data.cache.piece_corners[32 * size_t(slot)];
    for (int c = 0; c < 8; ++c) {
      const Vec3d& p = data.position[s.pieces[slot].particles[c]];
      for (int a = 0; a < 3; ++a) out[4 * c + a] = float(p[a]);
      out[4 * c + 3] = 0.0f;
    }
  }
  refresh_embed_rows(cut, s, data);
  // The interpolation (pbd_kernels.h embed_rows); the deformed surface is float anyway and not part
  // of the state hash.
  static_assert(sizeof(Vec3f) == 3 * sizeof(float), "deformed positions are packed float triples");
  const float* corners = data.cache.piece_corners.data();
  const EmbedRow* rows = data.cache.embed_rows.data();
  float* out = data.deformed.empty() ? nullptr : data.deformed[0].data();
  const TaskBatch batch{uint32_t(data.cache.embed_rows.size()), 4096};
  run_batches(tasks, &batch, 1, [&](uint32_t, uint32_t begin, uint32_t end) { embed_rows(corners, rows, begin, end, out); });
}

void pbd_step(const CutState& cut, const PbdModel& s, PbdData& data, const TaskRunner& tasks, bool embed,
              const StepClock* clock, double* contact_ms) {
  const PbdParams& params = s.params;
  const int substeps = std::max(1, params.substeps);
  const double h = params.dt / substeps;
  double* x = data.position.empty() ? nullptr : data.position[0].data();
  const double* w = s.inv_mass.data();
  // The constraint blocks change only with the model (a cut, or init). After a cut the contact index
  // follows it too: the two touch disjoint caches (data.cache, data.piece_contacts) and each runs on
  // one thread, so they go side by side, one item each (with one worker, one after the other).
  if (data.cache.blocks_revision != s.revision && contacts_on(s)) {
    const TaskBatch both{2, 1};
    run_batches(tasks, &both, 1, [&](uint32_t, uint32_t begin, uint32_t end) {
      for (uint32_t item = begin; item < end; ++item) {
        if (item == 0) {
          refresh_blocks(cut, s, data);
        } else {
          refresh_contact_index(cut, s, data);
        }
      }
    });
  } else {
    refresh_blocks(cut, s, data);
  }
  // A soft constraint without a time step does nothing (solve_distance's rule).
  const bool stretch_on = !(params.stretch_compliance > 0.0) || h > 0.0;
  const double alpha = params.stretch_compliance > 0.0 && h > 0.0 ? params.stretch_compliance / (h * h) : 0.0;
  // Damping per unit time: `damping` of the velocity goes per time step dt whatever the substeps.
  // The material model damps through its constraints instead (strain rates only, not rigid motion).
  const bool elastic = params.elastic == ElasticModel::kNeoHookean;
  const double keep = elastic ? 1.0 : substeps == 1 ? 1.0 - params.damping : std::pow(1.0 - params.damping, 1.0 / substeps);
  const ElasticConstants material = elastic && h > 0.0 ? elastic_constants(params.youngs_modulus, params.poisson_ratio,
                                                                           params.stiffness_damping, s.sim_size, h)
                                                       : ElasticConstants{};
  const double t_contact = clock ? clock->now() : 0.0;
  gather_contacts(cut, s, data, tasks);  // contact (sim/contact.h)
  if (clock && contact_ms) *contact_ms = clock->now() - t_contact;
  build_step_batches(s, data, elastic ? h > 0.0 : stretch_on, substeps);
  data.cache.grab_lambda.assign(3 * data.grab_particles.size(), 0.0);
  double* grab_lambda = data.cache.grab_lambda.data();
  // A substep starts with zero multipliers (the first chunk of its predict pass resets them; nothing
  // else reads them then).
  // (With the halves: each half resets its own multipliers, the first the shared ones.)
  const auto begin_shared_substep = [&] {
    contacts_begin_substep(data.contacts);
    contacts_begin_substep(data.piece_contacts.set);
    std::fill(data.cache.grab_lambda.begin(), data.cache.grab_lambda.end(), 0.0);
  };
  const auto begin_substep = [&] {
    for (std::vector<double>& lambda : data.stretch_lambda) std::fill(lambda.begin(), lambda.end(), 0.0);
    for (std::vector<double>& lambda : data.cache.elastic_lambda) std::fill(lambda.begin(), lambda.end(), 0.0);
    begin_shared_substep();
  };
  // Per particle: the end of a substep (the planes' backstop, velocities), then the start of the next
  // (previous positions, gravity, prediction), in one pass over the particles (raw arrays: Eigen's
  // packet stores may alias anything, so its loops reload every array pointer per particle);
  // anchored particles stay and keep no velocity. The same operations as Eigen's per axis.
  const double gravity_h[3] = {h * params.gravity.x(), h * params.gravity.y(), h * params.gravity.z()};
  const double keep_h = keep / h;
  double* __restrict xp = x;
  double* __restrict vp = data.velocity.empty() ? nullptr : data.velocity[0].data();
  double* __restrict pp = data.previous.empty() ? nullptr : data.previous[0].data();
  const auto advance = [&](uint32_t begin, uint32_t end, bool velocity, bool predict) {
    if (velocity && !params.planes.empty()) {
      project_particles_to_planes(x, w, begin, end, params.planes.data(), uint32_t(params.planes.size()), s.sim_size);
    }
    for (uint32_t p = begin; p < end; ++p) {
      double* xi = xp + 3 * size_t(p);
      double* vi = vp + 3 * size_t(p);
      double* pi = pp + 3 * size_t(p);
      if (w[p] == 0.0) {
        if (!predict) continue;
        for (int e = 0; e < 3; ++e) {
          pi[e] = xi[e];
          vi[e] = 0.0;
        }
        continue;
      }
      for (int e = 0; e < 3; ++e) {
        double v = vi[e];
        if (velocity) v = (xi[e] - pi[e]) * keep_h;
        if (predict) {
          pi[e] = xi[e];
          v += gravity_h[e];
          xi[e] += h * v;
        }
        vi[e] = v;
      }
    }
  };
  // One half's particles, then its constraints colour by colour, as the batches above would solve
  // them (PbdCache::halves).
  const auto run_half = [&](uint32_t index, uint32_t work) {
    SolverHalf& half = data.cache.halves[index];
    const bool velocity = (work & StepBatch::kHalfVelocity) != 0, predict = (work & StepBatch::kHalfPredict) != 0;
    if (predict) {
      for (std::vector<double>& lambda : half.stretch_lambda) std::fill(lambda.begin(), lambda.end(), 0.0);
      for (std::vector<double>& lambda : half.elastic_lambda) std::fill(lambda.begin(), lambda.end(), 0.0);
      if (index == 0) begin_shared_substep();
    }
    if (velocity || predict) {
      for (size_t r = 0; r < half.runs.size(); r += 2) advance(half.runs[r], half.runs[r + 1], velocity, predict);
    }
    if ((work & StepBatch::kHalfSolve) == 0) return;
    // Its own copy of its positions and rotations (SolverHalf), then back.
    const size_t count = half.particles.size();
    double* hx = half.x.data();
    for (size_t i = 0; i < count; ++i) std::memcpy(hx + 3 * i, xp + 3 * size_t(half.particles[i]), 3 * sizeof(double));
    for (size_t i = 0; i < half.previous.size() / 3; ++i) {
      std::memcpy(&half.previous[3 * i], pp + 3 * size_t(half.particles[i]), 3 * sizeof(double));
    }
    for (size_t j = 0; j < half.pieces.size(); ++j) half.rotation[j] = data.rotation[half.pieces[j]];
    for (int c = 0; elastic && stretch_on && c < kColourGroups; ++c) {
      solve_elastic_blocks(hx, half.previous.data(), half.elastic_rows[c].data(), half.elastic_lambda[c].data(), 0,
                           uint32_t(half.elastic_rows[c].size()), material, half.rotation.data(), nullptr,
                           c != kOverflowColour);
    }
    for (int c = 0; !elastic && stretch_on && c < kColourGroups; ++c) {
      solve_stretch_rows(hx, half.stretch_rows[c].data(), half.stretch_lambda[c].data(), 0,
                         uint32_t(half.stretch_rows[c].size()), alpha, c != kOverflowColour);
    }
    for (int c = 0; !elastic && c < kColourGroups; ++c) {
      solve_shape_blocks(hx, half.shape_blocks[c].data(), 0, uint32_t(half.shape_blocks[c].size()), params.shape_stiffness,
                         half.rotation.data(), c != kOverflowColour);
    }
    for (size_t i = 0; i < count; ++i) std::memcpy(xp + 3 * size_t(half.particles[i]), hx + 3 * i, 3 * sizeof(double));
    for (size_t j = 0; j < half.pieces.size(); ++j) data.rotation[half.pieces[j]] = half.rotation[j];
  };
  // One job for the whole step: the batches of build_step_batches in order (a barrier between batches).
  const auto run = [&](uint32_t batch, uint32_t begin, uint32_t end) {
    const StepBatch& b = data.cache.step_batches[batch];
    switch (b.kind) {
      case StepBatch::kHalves:
        for (uint32_t h = begin; h < end; ++h) run_half(h, b.index);
        break;
      case StepBatch::kPredict:
        if (begin == 0) begin_substep();
        advance(begin, end, false, true);
        break;
      case StepBatch::kGlobal:
        global_elastic_step(s, data, material);
        break;
      case StepBatch::kStretch: {
        // Four at a time where a colour shares no particle (pbd_kernels.h); the overflow group in order.
        solve_stretch_rows(x, data.cache.stretch_rows[b.index].data(), data.stretch_lambda[b.index].data(), begin, end,
                           alpha, b.index != kOverflowColour);
        break;
      }
      case StepBatch::kShape:
        // Two blocks at once where a colour shares no particle (pbd_kernels.h); the overflow's in order.
        solve_shape_blocks(x, data.cache.shape_blocks[b.index].data(), begin, end, params.shape_stiffness,
                           data.rotation.data(), b.index != kOverflowColour);
        break;
      case StepBatch::kElastic:
        // One colour's hexahedra share no particle: four or eight at once; the overflow's in order
        // (pbd_kernels.h).
        solve_elastic_blocks(x, data.previous[0].data(), data.cache.elastic_rows[b.index].data(),
                             data.cache.elastic_lambda[b.index].data(), begin, end, material, data.rotation.data(),
                             params.global_step ? data.enhancement.data() : nullptr, b.index != kOverflowColour);
        break;
      case StepBatch::kGrab:
        solve_grab(s, data, h, grab_lambda);
        break;
      case StepBatch::kPieceContact:
      case StepBatch::kPlaneContact: {
        ContactSet& set = b.kind == StepBatch::kPieceContact ? data.piece_contacts.set : data.contacts;
        const uint32_t first = set.batch_begin[b.index];
        for (uint32_t g = begin; g < end; ++g) solve_contact_group(x, data.previous[0].data(), w, set, first + g);
        break;
      }
      case StepBatch::kVelocity:
        if (b.index != 0 && begin == 0) begin_substep();
        advance(begin, end, true, b.index != 0);
        break;
    }
  };
  run_batches(tasks, data.cache.task_batches.data(), uint32_t(data.cache.task_batches.size()), run);
  // The grab's force: its multipliers of the last substep over h^2, summed in order.
  data.grab_force = Vec3d::Zero();
  if (h > 0.0) {
    for (size_t i = 0; i < data.grab_particles.size(); ++i) {
      for (int a = 0; a < 3; ++a) data.grab_force[a] += data.cache.grab_lambda[3 * i + a] / (h * h);
    }
  }
  ++data.steps;
  // Without the embedding, its rows still follow the cut (a few slots a step), so the next
  // pbd_embed interpolates without rebuilding them.
  if (embed) {
    pbd_embed(cut, s, data, tasks);
  } else {
    pbd_internal::refresh_embed_rows(cut, s, data);
  }
}

void pbd_forget_caches(PbdData& data) {
  data.cache.blocks_revision = data.cache.blocks_edits = ~uint64_t(0);
  data.cache.embed_revision = kNoRows;
  data.piece_contacts.index.revision = data.piece_contacts.index.edits = ~uint64_t(0);
  data.piece_contacts.seen_steps = ~uint64_t(0);  // the allowances compare every slot
}

uint32_t piece_slot(const PbdModel& s, uint32_t sv, uint8_t label) { return slot_of_label(s, sv, label); }

uint32_t vertex_sim_piece(const PbdModel& s, uint32_t slot) {
  return slot < s.embedding.size() ? embedded_piece(s, s.embedding[slot]) : kDeadIndex;
}

uint32_t piece_at_rest(const VoxelModel& model, const PbdModel& s, const Vec3d& rest) {
  const Vec3d g = (rest - s.origin) / s.sim_size;
  if (!g.allFinite()) return kDeadIndex;
  const int32_t c[3] = {int32_t(std::floor(g.x())), int32_t(std::floor(g.y())), int32_t(std::floor(g.z()))};
  if (!sim_in_range(s, c[0], c[1], c[2])) return kDeadIndex;
  const uint32_t sv = sim_voxel_id(s, c[0], c[1], c[2]);
  if (!has_pieces(s, sv)) return kDeadIndex;
  // The nearest fine node, kept in the block.
  const Vec3d f = (rest - s.origin) / s.fine_size;
  int32_t node[3];
  for (int a = 0; a < 3; ++a) {
    node[a] = std::clamp(int32_t(std::lround(f[a])), c[a] * s.ratio, c[a] * s.ratio + s.ratio);
  }
  (void)model;
  return slot_of_label(s, sv, node_label(model, s, sv, c, node[0], node[1], node[2]));
}

bool piece_holds(const VoxelModel& model, const PbdModel& s, uint32_t piece, const Vec3d& u) {
  const SimPiece& p = s.pieces[piece];
  if (p.sim_voxel == kDeadIndex || !u.allFinite()) return false;
  int32_t c[3], node[3];
  sim_voxel_coords(s, p.sim_voxel, c);
  for (int a = 0; a < 3; ++a) {
    // Nearest node: the value is in [0, ratio], so truncating x + 0.5 rounds it (inline, where
    // lround is a library call; the mapping asks this for every blade sample in material).
    node[a] = c[a] * s.ratio + int32_t(std::clamp(u[a], 0.0, 1.0) * s.ratio + 0.5);
  }
  return node_label(model, s, p.sim_voxel, c, node[0], node[1], node[2]) == p.piece;
}

Vec3d piece_rest_origin(const PbdModel& s, uint32_t piece) {
  int32_t c[3];
  sim_voxel_coords(s, s.pieces[piece].sim_voxel, c);
  return corner_rest(s, c[0], c[1], c[2]);
}

void piece_corners(const PbdModel& s, const PbdData& data, uint32_t piece, Vec3d corners[8]) {
  for (int c = 0; c < 8; ++c) corners[c] = data.position[s.pieces[piece].particles[c]];
}

void grab_begin(const PbdModel& s, PbdData& data, const Vec3d& point, double compliance) {
  grab_end(data);
  double best = std::numeric_limits<double>::infinity();
  uint32_t nearest = ~0u;
  for (uint32_t p = 0; p < data.position.size(); ++p) {
    if (s.refs[p] == 0) continue;
    const double d = (data.position[p] - point).squaredNorm();
    if (d < best) {
      best = d;
      nearest = p;
    }
  }
  data.grab_target = point;
  if (nearest == ~0u) return;
  data.grab_particles.push_back(nearest);
  data.grab_offsets.push_back(Vec3d::Zero());
  data.grab_compliance.push_back(compliance);
  data.grab_limit.push_back(std::numeric_limits<double>::infinity());
}

void grab_begin_region(const PbdModel& s, PbdData& data, const Vec3d& point, uint32_t piece, double stiffness,
                       double radius, double force_limit) {
  grab_end(data);
  data.grab_region = true;
  data.grab_target = point;
  // The candidates: the piece's corners, the live particles within the radius (in slot order, once
  // each), or else the nearest live particle.
  std::vector<uint32_t>& held = data.grab_particles;
  if (piece < s.pieces.size() && s.pieces[piece].sim_voxel != kDeadIndex) {
    for (int c = 0; c < 8; ++c) held.push_back(s.pieces[piece].particles[c]);
  }
  double best = std::numeric_limits<double>::infinity();
  uint32_t nearest = ~0u;
  for (uint32_t p = 0; p < data.position.size(); ++p) {
    if (s.refs[p] == 0) continue;
    const double d = (data.position[p] - point).squaredNorm();
    if (d <= radius * radius) held.push_back(p);
    if (d < best) {
      best = d;
      nearest = p;
    }
  }
  if (held.empty() && nearest != ~0u) held.push_back(nearest);
  std::sort(held.begin(), held.end());
  held.erase(std::unique(held.begin(), held.end()), held.end());
  // Anchored candidates are left out (they do not move; a region all anchored holds nothing).
  size_t kept = 0;
  for (uint32_t p : held) {
    if (s.inv_mass[p] > 0.0) {
      held[kept++] = p;
    } else {
      ++data.grab_anchored;
    }
  }
  held.resize(kept);
  // Weights: mass x (1 - d / 2R), R the farthest held particle's distance; normalised to sum 1.
  double reach = 0.0;
  for (uint32_t p : held) reach = std::max(reach, (data.position[p] - point).norm());
  std::vector<double> weight(held.size());
  double total = 0.0;
  for (size_t i = 0; i < held.size(); ++i) {
    const double d = (data.position[held[i]] - point).norm();
    weight[i] = s.mass[held[i]] * (reach > 0.0 ? 1.0 - 0.5 * d / reach : 1.0);
    total += weight[i];
  }
  const double limit = force_limit > 0.0 ? force_limit : std::numeric_limits<double>::infinity();
  for (size_t i = 0; i < held.size(); ++i) {
    const double w = weight[i] / total;
    data.grab_offsets.push_back(data.position[held[i]] - point);
    data.grab_compliance.push_back(1.0 / (stiffness * w));
    data.grab_limit.push_back(limit * w);
  }
}

void grab_move(PbdData& data, const Vec3d& target) { data.grab_target = target; }

void grab_end(PbdData& data) {
  data.grab_particles.clear();
  data.grab_offsets.clear();
  data.grab_compliance.clear();
  data.grab_limit.clear();
  data.grab_region = false;
  data.grab_anchored = 0;
  data.grab_force = Vec3d::Zero();
}

double total_mass(const PbdModel& s) {
  uint64_t eighths = 0;
  for (size_t p = 0; p < s.mass_eighths.size(); ++p) eighths += s.refs[p] ? s.mass_eighths[p] : 0;
  const double h = s.fine_size;
  return s.params.density * (double(eighths) * (h * h * h / 64.0));
}

double kinetic_energy(const PbdModel& s, const PbdData& data) {
  double e = 0.0;
  for (size_t p = 0; p < data.position.size(); ++p) {
    if (s.inv_mass[p] > 0.0) e += 0.5 * s.mass[p] * data.velocity[p].squaredNorm();
  }
  return e;
}

uint64_t count_nonfinite(const PbdModel& s, const PbdData& data) {
  uint64_t bad = 0;
  for (size_t p = 0; p < data.position.size(); ++p) {
    if (s.refs[p] == 0) continue;
    bad += !data.position[p].allFinite() + !data.velocity[p].allFinite();
  }
  for (size_t v = 0; v < s.embedding.size(); ++v) {
    if (s.embedding[v].sim_voxel != kDeadIndex && !data.deformed[v].allFinite()) ++bad;
  }
  return bad;
}

uint32_t sim_voxels_divided(const PbdModel& s) { return uint32_t(s.divided.size()); }
uint32_t live_pieces(const PbdModel& s) { return uint32_t(s.pieces.size() - s.free_pieces.size()); }
uint32_t live_particles(const PbdModel& s) { return uint32_t(s.rest.size() - s.free_particles.size()); }

uint32_t stretch_count(const PbdModel& s) {
  size_t n = 0;
  for (const auto& group : s.stretch_groups) n += group.size();
  return uint32_t(n);
}

uint32_t overflow_constraints(const PbdModel& s) {
  return uint32_t(s.stretch_groups[kOverflowColour].size() + s.piece_groups[kOverflowColour].size());
}

}  // namespace dvx
