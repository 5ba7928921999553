#include "sim/pbd.h"

#include "sim/pbd_kernels.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace dvx {
namespace {

constexpr uint8_t kMaxSimPieces = 250;  // labels are uint8; more components than this merge into the last

// ---- Fine lattice access -------------------------------------------------------------------

bool fine_inside(const VoxelModel& model, int32_t i, int32_t j, int32_t k) {
  const Lattice& l = model.lattice;
  if (i < 0 || j < 0 || k < 0 || i > l.nx || j > l.ny || k > l.nz) return false;
  return model.is_inside(l.node(i, j, k));
}

// True when fine edge (node (i,j,k), axis) holds material: both ends inside and not cut.
bool fine_material_edge(const VoxelModel& model, const CutState& cut, int32_t i, int32_t j, int32_t k, int axis) {
  int32_t e[3] = {i, j, k};
  e[axis] += 1;
  if (!fine_inside(model, i, j, k) || !fine_inside(model, e[0], e[1], e[2])) return false;
  return cut.edge_cut_of.get(Lattice::edge(model.lattice.node(i, j, k), axis)) == kDeadIndex;
}

// ---- Simulation grid -----------------------------------------------------------------------

uint32_t sim_voxel_id(const PbdState& s, int32_t I, int32_t J, int32_t K) {
  return uint32_t(I) + uint32_t(s.sx) * (uint32_t(J) + uint32_t(s.sy) * uint32_t(K));
}

void sim_voxel_coords(const PbdState& s, uint32_t v, int32_t c[3]) {
  c[0] = int32_t(v % uint32_t(s.sx));
  v /= uint32_t(s.sx);
  c[1] = int32_t(v % uint32_t(s.sy));
  c[2] = int32_t(v / uint32_t(s.sy));
}

bool sim_in_range(const PbdState& s, int32_t I, int32_t J, int32_t K) {
  return I >= 0 && J >= 0 && K >= 0 && I < s.sx && J < s.sy && K < s.sz;
}

// Index of a fine node inside a simulation voxel's block ((ratio+1)^3 nodes).
uint32_t block_index(const PbdState& s, int32_t a, int32_t b, int32_t c) {
  const uint32_t n = uint32_t(s.ratio + 1);
  return uint32_t(a) + n * (uint32_t(b) + n * uint32_t(c));
}

// Local piece of a fine node (global fine coords) in simulation voxel sv, kNoPiece when outside.
uint8_t node_piece(const VoxelModel& model, const PbdState& s, uint32_t sv, const int32_t svc[3], int32_t i,
                   int32_t j, int32_t k) {
  if (s.piece_of_voxel[sv] == kDeadIndex) return kNoPiece;
  const uint32_t d = s.divided_of.get(sv);
  if (d == kDeadIndex) return fine_inside(model, i, j, k) ? 0 : kNoPiece;
  const SimDivided& div = s.divided[d];
  return s.labels[div.first_label + block_index(s, i - svc[0] * s.ratio, j - svc[1] * s.ratio, k - svc[2] * s.ratio)];
}

// Material volume of the pieces of a simulation voxel: each inside corner of each fine voxel of the
// block adds h^3 / 8 to its piece (so volumes partition exactly under cuts). Counted per node, not
// per voxel corner: a node adds one eighth for each of the block's fine voxels around it (1, 2, 4 or
// 8 of them), so each node's piece is looked up once; integer counts keep the sum exact.
void piece_volumes(const VoxelModel& model, const PbdState& s, uint32_t sv, double volumes[256]) {
  int32_t c[3];
  sim_voxel_coords(s, sv, c);
  const Lattice& l = model.lattice;
  uint64_t eighths[256] = {};
  // Fine voxels of the block along one axis around local node x: the voxels x - 1 and x when they are
  // in the block and in the lattice.
  const auto around = [&](int32_t x, int32_t first, int32_t n) {
    return uint64_t((x > 0 && first + x - 1 < n) + (x < s.ratio && first + x < n));
  };
  for (int32_t z = 0; z <= s.ratio; ++z) {
    const uint64_t wz = around(z, c[2] * s.ratio, l.nz);
    for (int32_t y = 0; y <= s.ratio; ++y) {
      const uint64_t wyz = wz * around(y, c[1] * s.ratio, l.ny);
      if (wyz == 0) continue;
      for (int32_t x = 0; x <= s.ratio; ++x) {
        const uint64_t w = wyz * around(x, c[0] * s.ratio, l.nx);
        if (w == 0) continue;
        const uint8_t p = node_piece(model, s, sv, c, c[0] * s.ratio + x, c[1] * s.ratio + y, c[2] * s.ratio + z);
        if (p != kNoPiece) eighths[p] += w;
      }
    }
  }
  const double eighth = l.voxel_size * l.voxel_size * l.voxel_size / 8.0;
  for (int p = 0; p < 256; ++p) volumes[p] = double(eighths[p]) * eighth;
}

// Labels the fine nodes of a simulation voxel's block by material component. Returns the count.
uint8_t label_block(const VoxelModel& model, const CutState& cut, const PbdState& s, uint32_t sv, uint8_t* labels) {
  int32_t c[3];
  sim_voxel_coords(s, sv, c);
  const int32_t n = s.ratio + 1;
  const uint32_t count = uint32_t(n * n * n);
  std::vector<uint32_t> parent(count);
  for (uint32_t i = 0; i < count; ++i) parent[i] = i;
  const auto find = [&](uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  for (int32_t z = 0; z < n; ++z) {
    for (int32_t y = 0; y < n; ++y) {
      for (int32_t x = 0; x < n; ++x) {
        const int32_t i = c[0] * s.ratio + x, j = c[1] * s.ratio + y, k = c[2] * s.ratio + z;
        const int32_t local[3] = {x, y, z};
        for (int axis = 0; axis < 3; ++axis) {
          if (local[axis] + 1 >= n || !fine_material_edge(model, cut, i, j, k, axis)) continue;
          int32_t o[3] = {x, y, z};
          o[axis] += 1;
          const uint32_t a = find(block_index(s, x, y, z)), b = find(block_index(s, o[0], o[1], o[2]));
          if (a != b) parent[std::max(a, b)] = std::min(a, b);
        }
      }
    }
  }
  // Number the components in node order.
  std::vector<uint8_t> id(count, kNoPiece);
  uint8_t pieces = 0;
  for (int32_t z = 0; z < n; ++z) {
    for (int32_t y = 0; y < n; ++y) {
      for (int32_t x = 0; x < n; ++x) {
        const uint32_t b = block_index(s, x, y, z);
        if (!fine_inside(model, c[0] * s.ratio + x, c[1] * s.ratio + y, c[2] * s.ratio + z)) {
          labels[b] = kNoPiece;
          continue;
        }
        const uint32_t r = find(b);
        if (id[r] == kNoPiece) id[r] = pieces < kMaxSimPieces ? pieces++ : uint8_t(kMaxSimPieces - 1);
        labels[b] = id[r];
      }
    }
  }
  return pieces;
}

// ---- Particles -----------------------------------------------------------------------------

// Arguments by value: they may point into the arrays this grows.
uint32_t new_particle(PbdState& s, const Vec3d rest, const Vec3d position, const Vec3d velocity) {
  uint32_t p;
  if (!s.free_particles.empty()) {
    p = s.free_particles.back();
    s.free_particles.pop_back();
  } else {
    p = uint32_t(s.position.size());
    s.position.emplace_back();
    s.velocity.emplace_back();
    s.previous.emplace_back();
    s.rest.emplace_back();
    s.mass.push_back(0.0);
    s.inv_mass.push_back(0.0);
    s.anchored.push_back(0);
  }
  s.rest[p] = rest;
  s.position[p] = position;
  s.previous[p] = position;
  s.velocity[p] = velocity;
  return p;
}

Vec3d corner_rest(const PbdState& s, int32_t I, int32_t J, int32_t K) {
  return s.origin + s.sim_size * Vec3d(I, J, K);
}

// Assigns particles at coarse corner (I,J,K): pieces of the simulation voxels around it joined by a
// shared inside fine node share a particle. Existing particles are kept where possible.
void assign_corner(const VoxelModel& model, PbdState& s, int32_t I, int32_t J, int32_t K) {
  // The pieces around the corner.
  struct Member {
    uint32_t piece;  // global index
    int corner;      // the corner's number in that piece's voxel
  };
  Member members[8 * 16];
  int member_count = 0;
  uint32_t voxels[8];
  int32_t voxel_coords[8][3];
  for (int q = 0; q < 8; ++q) {
    const int32_t c[3] = {I - 1 + (q & 1), J - 1 + ((q >> 1) & 1), K - 1 + ((q >> 2) & 1)};
    voxels[q] = kDeadIndex;
    if (!sim_in_range(s, c[0], c[1], c[2])) continue;
    const uint32_t sv = sim_voxel_id(s, c[0], c[1], c[2]);
    if (s.piece_of_voxel[sv] == kDeadIndex) continue;
    voxels[q] = sv;
    std::copy(c, c + 3, voxel_coords[q]);
    const int corner = (1 - (q & 1)) | ((1 - ((q >> 1) & 1)) << 1) | ((1 - ((q >> 2) & 1)) << 2);
    for (uint32_t p = 0; p < s.pieces_in_voxel[sv] && member_count < 8 * 16; ++p) {
      members[member_count++] = {s.piece_of_voxel[sv] + p, corner};
    }
  }
  if (member_count == 0) return;
  // Union-find over members joined by shared fine nodes on the planes through the corner.
  int parent[8 * 16];
  for (int m = 0; m < member_count; ++m) parent[m] = m;
  const auto find = [&](int x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  const auto member_of = [&](uint32_t piece) {
    for (int m = 0; m < member_count; ++m) {
      if (members[m].piece == piece) return m;
    }
    return -1;
  };
  // Each voxel's node labels (null: not divided, every inside node is its piece 0), looked up once.
  const uint8_t* voxel_labels[8];
  for (int q = 0; q < 8; ++q) {
    voxel_labels[q] = nullptr;
    if (voxels[q] == kDeadIndex) continue;
    const uint32_t d = s.divided_of.get(voxels[q]);
    if (d != kDeadIndex) voxel_labels[q] = s.labels.data() + s.divided[d].first_label;
  }
  const int32_t r = s.ratio;
  const int32_t ci = I * r, cj = J * r, ck = K * r;
  for (int32_t c = -r; c <= r; ++c) {
    for (int32_t b = -r; b <= r; ++b) {
      // Only nodes shared by several voxels: on one of the three planes through the corner. Off the
      // b = 0 and c = 0 planes that leaves a = 0 alone.
      const bool line_only = b != 0 && c != 0;
      for (int32_t a = line_only ? 0 : -r; a <= (line_only ? 0 : r); ++a) {
        const int32_t i = ci + a, j = cj + b, k = ck + c;
        if (!fine_inside(model, i, j, k)) continue;
        int first = -1;
        for (int q = 0; q < 8; ++q) {
          if (voxels[q] == kDeadIndex) continue;
          // Node inside this voxel's block?
          const int dx = q & 1, dy = (q >> 1) & 1, dz = (q >> 2) & 1;
          if ((dx == 0 ? a > 0 : a < 0) || (dy == 0 ? b > 0 : b < 0) || (dz == 0 ? c > 0 : c < 0)) continue;
          const int32_t* vc = voxel_coords[q];
          const uint8_t p = voxel_labels[q] ? voxel_labels[q][block_index(s, i - vc[0] * r, j - vc[1] * r, k - vc[2] * r)]
                                            : uint8_t(0);  // inside node of an undivided voxel
          if (p == kNoPiece) continue;
          const int m = member_of(s.piece_of_voxel[voxels[q]] + p);
          if (m < 0) continue;
          if (first < 0) {
            first = find(m);
          } else {
            const int x = find(m);
            if (x != first) {
              parent[std::max(x, first)] = std::min(x, first);
              first = std::min(x, first);
            }
          }
        }
      }
    }
  }
  // One particle per group: keep the smallest existing particle of the group not claimed yet.
  uint32_t claimed[8 * 16];
  int claimed_count = 0;
  for (int m = 0; m < member_count; ++m) {
    if (find(m) != m) continue;
    uint32_t best = kDeadIndex;
    for (int n = 0; n < member_count; ++n) {
      if (find(n) != m) continue;
      const uint32_t p = s.pieces[members[n].piece].particles[members[n].corner];
      if (p == kDeadIndex || std::find(claimed, claimed + claimed_count, p) != claimed + claimed_count) continue;
      best = std::min(best, p);
    }
    if (best == kDeadIndex) {
      // A new particle, starting where the group's previous particle was.
      const uint32_t from = s.pieces[members[m].piece].particles[members[m].corner];
      const Vec3d rest = corner_rest(s, I, J, K);
      best = from == kDeadIndex ? new_particle(s, rest, rest, Vec3d::Zero())
                                : new_particle(s, rest, s.position[from], s.velocity[from]);
    }
    claimed[claimed_count++] = best;
    for (int n = 0; n < member_count; ++n) {
      if (find(n) == m) s.pieces[members[n].piece].particles[members[n].corner] = best;
    }
  }
}

// ---- Constraints ---------------------------------------------------------------------------

constexpr int kCubeEdges[12][2] = {{0, 1}, {2, 3}, {4, 5}, {6, 7}, {0, 2}, {1, 3},
                                   {4, 6}, {5, 7}, {0, 4}, {1, 5}, {2, 6}, {3, 7}};

// Masses, anchors, stretch constraints and colour groups from the current pieces.
void rebuild_constraints(PbdState& s) {
  const size_t n = s.position.size();
  // Masses: an eighth of each piece's mass at each of its corners.
  std::vector<uint8_t> used(n, 0);
  std::fill(s.mass.begin(), s.mass.end(), 0.0);
  for (const SimPiece& piece : s.pieces) {
    const double m = s.params.density * piece.volume / 8.0;
    for (uint32_t p : piece.particles) {
      s.mass[p] += m;
      used[p] = 1;
    }
  }
  // Dead particles go to the free list; anchors from the fixed boxes.
  s.free_particles.clear();
  for (uint32_t p = 0; p < n; ++p) {
    if (!used[p]) {
      s.free_particles.push_back(p);
      s.mass[p] = 0.0;
      s.inv_mass[p] = 0.0;
      s.anchored[p] = 0;
      continue;
    }
    bool anchored = false;
    for (const Aabb& box : s.params.fixed) {
      anchored = anchored || ((s.rest[p].array() >= box.min.array()).all() && (s.rest[p].array() <= box.max.array()).all());
    }
    s.anchored[p] = anchored;
    s.inv_mass[p] = anchored || s.mass[p] <= 0.0 ? 0.0 : 1.0 / s.mass[p];
  }
  std::reverse(s.free_particles.begin(), s.free_particles.end());  // reuse low slots first

  // Stretch constraints: unique particle pairs along piece edges.
  std::vector<StretchConstraint> edges;
  edges.reserve(s.pieces.size() * 12);
  for (const SimPiece& piece : s.pieces) {
    for (const auto& e : kCubeEdges) {
      uint32_t a = piece.particles[e[0]], b = piece.particles[e[1]];
      if (a == b) continue;
      if (a > b) std::swap(a, b);
      edges.push_back({a, b, (s.rest[a] - s.rest[b]).norm()});
    }
  }
  std::sort(edges.begin(), edges.end(), [](const StretchConstraint& x, const StretchConstraint& y) {
    return x.a != y.a ? x.a < y.a : x.b < y.b;
  });
  edges.erase(std::unique(edges.begin(), edges.end(),
                          [](const StretchConstraint& x, const StretchConstraint& y) { return x.a == y.a && x.b == y.b; }),
              edges.end());

  // Greedy colouring: constraints of one colour share no particle.
  std::vector<uint64_t> busy(n, 0);
  std::vector<uint8_t> colour(edges.size());
  int colours = 0;
  for (size_t i = 0; i < edges.size(); ++i) {
    const uint64_t taken = busy[edges[i].a] | busy[edges[i].b];
    int c = 0;
    while (c < 63 && ((taken >> c) & 1u)) ++c;
    colour[i] = uint8_t(c);
    busy[edges[i].a] |= uint64_t(1) << c;
    busy[edges[i].b] |= uint64_t(1) << c;
    colours = std::max(colours, c + 1);
  }
  s.stretch_colour_begin.assign(size_t(colours) + 1, 0);
  for (uint8_t c : colour) ++s.stretch_colour_begin[c + 1];
  for (int c = 0; c < colours; ++c) s.stretch_colour_begin[c + 1] += s.stretch_colour_begin[c];
  s.stretch.resize(edges.size());
  {
    std::vector<uint32_t> next(s.stretch_colour_begin.begin(), s.stretch_colour_begin.end() - 1);
    for (size_t i = 0; i < edges.size(); ++i) s.stretch[next[colour[i]]++] = edges[i];
  }
  s.stretch_lambda.assign(s.stretch.size(), 0.0);

  // Shape-matching colours.
  std::fill(busy.begin(), busy.end(), 0);
  colours = 0;
  for (SimPiece& piece : s.pieces) {
    uint64_t taken = 0;
    for (uint32_t p : piece.particles) taken |= busy[p];
    int c = 0;
    while (c < 63 && ((taken >> c) & 1u)) ++c;
    piece.colour = uint8_t(c);
    for (uint32_t p : piece.particles) busy[p] |= uint64_t(1) << c;
    colours = std::max(colours, c + 1);
  }
  s.piece_colour_begin.assign(size_t(colours) + 1, 0);
  for (const SimPiece& piece : s.pieces) ++s.piece_colour_begin[piece.colour + 1];
  for (int c = 0; c < colours; ++c) s.piece_colour_begin[c + 1] += s.piece_colour_begin[c];
  s.piece_order.resize(s.pieces.size());
  {
    std::vector<uint32_t> next(s.piece_colour_begin.begin(), s.piece_colour_begin.end() - 1);
    for (uint32_t i = 0; i < s.pieces.size(); ++i) s.piece_order[next[s.pieces[i].colour]++] = i;
  }
}

// ---- Embedding -----------------------------------------------------------------------------

// Embeds a live surface vertex slot: its fine piece's simulation voxel and piece, and its local position.
void embed_vertex(const VoxelModel& model, const CutState& cut, PbdState& s, uint32_t slot) {
  const CutSurface& surface = cut.surface;
  if (s.embedding.size() < surface.positions.size()) {
    s.embedding.resize(surface.positions.size(), VertexEmbedding{kDeadIndex, 0, Vec3f::Zero()});
    s.deformed.resize(surface.positions.size(), Vec3f::Zero());
  }
  VertexEmbedding& e = s.embedding[slot];
  const uint64_t key = surface.vertex_piece[slot];
  if (key == CutSurface::kFreeKey) {
    e.sim_voxel = kDeadIndex;
    return;
  }
  const uint32_t voxel = uint32_t(key / 8);
  const uint8_t fine_piece = uint8_t(key % 8);
  int32_t vc[3];
  model.lattice.voxel_coords(voxel, vc);
  const int32_t svc[3] = {vc[0] / s.ratio, vc[1] / s.ratio, vc[2] / s.ratio};
  const uint32_t sv = sim_voxel_id(s, svc[0], svc[1], svc[2]);
  // The fine piece's corners all lie in one sim piece: take the first.
  uint8_t corner_piece[8], count = 0;
  voxel_pieces(model, cut, voxel, corner_piece, count);
  uint8_t sim_piece = kNoPiece;
  for (int c = 0; c < 8 && sim_piece == kNoPiece; ++c) {
    if (corner_piece[c] != fine_piece) continue;
    sim_piece = node_piece(model, s, sv, svc, vc[0] + (c & 1), vc[1] + ((c >> 1) & 1), vc[2] + ((c >> 2) & 1));
  }
  if (sim_piece == kNoPiece || s.piece_of_voxel[sv] == kDeadIndex) {
    e.sim_voxel = kDeadIndex;
    return;
  }
  e.sim_voxel = sv;
  e.piece = sim_piece;
  const Vec3d local = (surface.positions[slot].cast<double>() - corner_rest(s, svc[0], svc[1], svc[2])) / s.sim_size;
  e.local = local.cast<float>();
}

// Runs f(i) for i in [0, count) through the task runner (chunks of `grain`).
template <typename F>
void parallel(const TaskRunner& tasks, uint32_t count, uint32_t grain, F&& f) {
  if (count == 0) return;
  if (tasks.parallel_for == nullptr) {
    for (uint32_t i = 0; i < count; ++i) f(i);
    return;
  }
  tasks.parallel_for(
      tasks.context, count, grain,
      [](uint32_t begin, uint32_t end, void* user) {
        F& fn = *static_cast<F*>(user);
        for (uint32_t i = begin; i < end; ++i) fn(i);
      },
      &f);
}

// Rebuilds the pieces array: unaffected voxels keep their pieces; `relabelled` voxels get new pieces
// inheriting particles and rotation from the old piece that held the same fine node.
void rebuild_pieces(const VoxelModel& model, PbdState& s, const std::vector<uint32_t>& relabelled,
                    const std::vector<std::vector<uint8_t>>& old_labels, const std::vector<uint32_t>& old_first,
                    const std::vector<SimPiece>& old_pieces) {
  std::vector<SimPiece> pieces;
  pieces.reserve(old_pieces.size() + relabelled.size() * 2);
  const uint32_t voxels = uint32_t(s.sx) * uint32_t(s.sy) * uint32_t(s.sz);
  const int32_t n = s.ratio + 1;
  size_t r = 0;
  for (uint32_t sv = 0; sv < voxels; ++sv) {
    const uint32_t old = old_first[sv];
    const bool changed = r < relabelled.size() && relabelled[r] == sv;
    if (!changed) {
      if (s.piece_of_voxel[sv] == kDeadIndex) continue;
      const uint32_t first = uint32_t(pieces.size());
      for (uint32_t p = 0; p < s.pieces_in_voxel[sv]; ++p) pieces.push_back(old_pieces[old + p]);
      s.piece_of_voxel[sv] = first;
      continue;
    }
    // A relabelled voxel: one new piece per label, inheriting from the old piece of its first node.
    const std::vector<uint8_t>& before = old_labels[r];
    const SimDivided& div = s.divided[s.divided_of.get(sv)];
    const uint32_t first = uint32_t(pieces.size());
    s.piece_of_voxel[sv] = first;
    s.pieces_in_voxel[sv] = div.piece_count;
    for (uint8_t p = 0; p < div.piece_count; ++p) {
      SimPiece piece{};
      piece.sim_voxel = sv;
      piece.piece = p;
      piece.rotation = Eigen::Quaterniond::Identity();
      std::fill(piece.particles, piece.particles + 8, kDeadIndex);
      for (uint32_t b = 0; b < uint32_t(n * n * n); ++b) {
        if (s.labels[div.first_label + b] != p) continue;
        const uint8_t was = before.empty() ? 0 : before[b];
        if (was != kNoPiece && old != kDeadIndex) {
          const SimPiece& from = old_pieces[old + was];
          std::copy(from.particles, from.particles + 8, piece.particles);
          piece.rotation = from.rotation;
        }
        break;
      }
      pieces.push_back(piece);
    }
    ++r;
  }
  s.pieces.swap(pieces);
  // Volumes of the relabelled voxels' pieces.
  for (uint32_t sv : relabelled) {
    double volumes[256];
    piece_volumes(model, s, sv, volumes);
    for (uint32_t p = 0; p < s.pieces_in_voxel[sv]; ++p) s.pieces[s.piece_of_voxel[sv] + p].volume = volumes[p];
  }
}

}  // namespace

// ---- Public API ----------------------------------------------------------------------------

bool init_pbd(const VoxelModel& model, const CutState& cut, const PbdParams& params, PbdState& s, std::string& error) {
  if (params.sim_resolution < 1 || params.resolution < params.sim_resolution ||
      params.resolution % params.sim_resolution != 0 ||
      ((params.resolution / params.sim_resolution) & (params.resolution / params.sim_resolution - 1)) != 0) {
    error = "resolution / sim_resolution must be a power of two (" + std::to_string(params.resolution) + " / " +
            std::to_string(params.sim_resolution) + ")";
    return false;
  }
  s = PbdState{};
  s.params = params;
  const Lattice& l = model.lattice;
  s.ratio = params.resolution / params.sim_resolution;
  s.sx = (l.nx + s.ratio - 1) / s.ratio;
  s.sy = (l.ny + s.ratio - 1) / s.ratio;
  s.sz = (l.nz + s.ratio - 1) / s.ratio;
  s.sim_size = l.voxel_size * s.ratio;
  s.origin = l.origin;
  const uint32_t voxels = uint32_t(s.sx) * uint32_t(s.sy) * uint32_t(s.sz);
  s.piece_of_voxel.assign(voxels, kDeadIndex);
  s.pieces_in_voxel.assign(voxels, 0);

  // Simulation voxels with material: one piece each (cuts made before init are taken below).
  for (uint32_t sv = 0; sv < voxels; ++sv) {
    int32_t c[3];
    sim_voxel_coords(s, sv, c);
    bool material = false;
    for (int32_t z = 0; z <= s.ratio && !material; ++z) {
      for (int32_t y = 0; y <= s.ratio && !material; ++y) {
        for (int32_t x = 0; x <= s.ratio && !material; ++x) {
          material = fine_inside(model, c[0] * s.ratio + x, c[1] * s.ratio + y, c[2] * s.ratio + z);
        }
      }
    }
    if (!material) continue;
    s.piece_of_voxel[sv] = uint32_t(s.pieces.size());
    s.pieces_in_voxel[sv] = 1;
    SimPiece piece{};
    piece.sim_voxel = sv;
    piece.rotation = Eigen::Quaterniond::Identity();
    std::fill(piece.particles, piece.particles + 8, kDeadIndex);
    double volumes[256];
    piece_volumes(model, s, sv, volumes);
    piece.volume = volumes[0];
    s.pieces.push_back(piece);
  }
  // One particle per coarse corner with material around.
  for (int32_t K = 0; K <= s.sz; ++K) {
    for (int32_t J = 0; J <= s.sy; ++J) {
      for (int32_t I = 0; I <= s.sx; ++I) {
        uint32_t particle = kDeadIndex;
        for (int q = 0; q < 8; ++q) {
          const int32_t c[3] = {I - 1 + (q & 1), J - 1 + ((q >> 1) & 1), K - 1 + ((q >> 2) & 1)};
          if (!sim_in_range(s, c[0], c[1], c[2])) continue;
          const uint32_t sv = sim_voxel_id(s, c[0], c[1], c[2]);
          if (s.piece_of_voxel[sv] == kDeadIndex) continue;
          if (particle == kDeadIndex) {
            const Vec3d rest = corner_rest(s, I, J, K);
            particle = new_particle(s, rest, rest, Vec3d::Zero());
          }
          const int corner = (1 - (q & 1)) | ((1 - ((q >> 1) & 1)) << 1) | ((1 - ((q >> 2) & 1)) << 2);
          s.pieces[s.piece_of_voxel[sv]].particles[corner] = particle;
        }
      }
    }
  }
  rebuild_constraints(s);
  // Cuts already made: divide now; then embed every live vertex.
  if (!cut.divided.empty()) {
    CutState replayed = cut;  // changed_voxels: every divided voxel
    replayed.changed_voxels.clear();
    for (const DividedVoxel& dv : cut.divided) replayed.changed_voxels.push_back(dv.voxel);
    std::sort(replayed.changed_voxels.begin(), replayed.changed_voxels.end());
    replayed.changed_vertices.clear();
    pbd_apply_cut(model, replayed, s);
  }
  s.embedding.assign(cut.surface.positions.size(), VertexEmbedding{kDeadIndex, 0, Vec3f::Zero()});
  s.deformed.assign(cut.surface.positions.size(), Vec3f::Zero());
  for (uint32_t slot = 0; slot < cut.surface.positions.size(); ++slot) embed_vertex(model, cut, s, slot);
  pbd_embed(cut, s);
  return true;
}


uint32_t pbd_apply_cut(const VoxelModel& model, const CutState& cut, PbdState& s) {
  // Simulation voxels holding changed fine voxels.
  std::vector<uint32_t> affected;
  for (uint32_t voxel : cut.changed_voxels) {
    if (cut.divided_of.get(voxel) == kDeadIndex) continue;
    int32_t vc[3];
    model.lattice.voxel_coords(voxel, vc);
    const uint32_t sv = sim_voxel_id(s, vc[0] / s.ratio, vc[1] / s.ratio, vc[2] / s.ratio);
    if (s.piece_of_voxel[sv] != kDeadIndex) affected.push_back(sv);
  }
  std::sort(affected.begin(), affected.end());
  affected.erase(std::unique(affected.begin(), affected.end()), affected.end());

  if (!affected.empty()) {
    // Relabel each affected simulation voxel, remembering the old labels.
    const int32_t n = s.ratio + 1;
    const uint32_t block = uint32_t(n * n * n);
    std::vector<std::vector<uint8_t>> old_labels(affected.size());
    for (size_t a = 0; a < affected.size(); ++a) {
      const uint32_t sv = affected[a];
      uint32_t d = s.divided_of.get(sv);
      if (d == kDeadIndex) {
        d = uint32_t(s.divided.size());
        s.divided_of.set(sv, d);
        s.divided.push_back({sv, uint32_t(s.labels.size()), 1});
        s.labels.resize(s.labels.size() + block, kNoPiece);
        old_labels[a].clear();  // uncut before: every inside node was piece 0
      } else {
        old_labels[a].assign(s.labels.begin() + s.divided[d].first_label,
                             s.labels.begin() + s.divided[d].first_label + block);
      }
      SimDivided& div = s.divided[d];
      div.piece_count = label_block(model, cut, s, sv, s.labels.data() + div.first_label);
    }
    // Rebuild the pieces array (old per-voxel first indices kept for inheritance).
    const std::vector<uint32_t> old_first = s.piece_of_voxel;
    const std::vector<SimPiece> old_pieces = s.pieces;
    rebuild_pieces(model, s, affected, old_labels, old_first, old_pieces);
    // Corner particles of the affected voxels.
    std::vector<uint64_t> corners;
    for (uint32_t sv : affected) {
      int32_t c[3];
      sim_voxel_coords(s, sv, c);
      for (int q = 0; q < 8; ++q) {
        const uint64_t I = uint64_t(c[0] + (q & 1)), J = uint64_t(c[1] + ((q >> 1) & 1)), K = uint64_t(c[2] + ((q >> 2) & 1));
        corners.push_back(I + uint64_t(s.sx + 1) * (J + uint64_t(s.sy + 1) * K));
      }
    }
    std::sort(corners.begin(), corners.end());
    corners.erase(std::unique(corners.begin(), corners.end()), corners.end());
    for (uint64_t corner : corners) {
      const int32_t I = int32_t(corner % uint64_t(s.sx + 1));
      const int32_t J = int32_t((corner / uint64_t(s.sx + 1)) % uint64_t(s.sy + 1));
      const int32_t K = int32_t(corner / (uint64_t(s.sx + 1) * uint64_t(s.sy + 1)));
      assign_corner(model, s, I, J, K);
    }
    rebuild_constraints(s);
  }

  // Re-embed changed vertex slots and every vertex of an affected simulation voxel.
  const CutSurface& surface = cut.surface;
  if (s.embedding.size() < surface.positions.size()) {
    s.embedding.resize(surface.positions.size(), VertexEmbedding{kDeadIndex, 0, Vec3f::Zero()});
    s.deformed.resize(surface.positions.size(), Vec3f::Zero());
  }
  for (uint32_t slot : cut.changed_vertices) embed_vertex(model, cut, s, slot);
  if (!affected.empty()) {
    std::vector<uint8_t> hit(s.piece_of_voxel.size(), 0);
    for (uint32_t sv : affected) hit[sv] = 1;
    for (uint32_t slot = 0; slot < s.embedding.size(); ++slot) {
      const uint32_t sv = s.embedding[slot].sim_voxel;
      if (sv != kDeadIndex && hit[sv]) embed_vertex(model, cut, s, slot);
    }
  }
  return uint32_t(affected.size());
}

void pbd_embed(const CutState& cut, PbdState& s, const TaskRunner& tasks) {
  const uint32_t count = uint32_t(std::min(s.embedding.size(), cut.surface.positions.size()));
  parallel(tasks, count, 4096, [&](uint32_t slot) {
    const VertexEmbedding& e = s.embedding[slot];
    if (e.sim_voxel == kDeadIndex || s.piece_of_voxel[e.sim_voxel] == kDeadIndex ||
        e.piece >= s.pieces_in_voxel[e.sim_voxel]) {
      s.deformed[slot] = cut.surface.positions[slot];
      return;
    }
    const SimPiece& piece = s.pieces[s.piece_of_voxel[e.sim_voxel] + e.piece];
    const double u = e.local.x(), v = e.local.y(), w = e.local.z();
    Vec3d p = Vec3d::Zero();
    for (int c = 0; c < 8; ++c) {
      const double weight = ((c & 1) ? u : 1.0 - u) * (((c >> 1) & 1) ? v : 1.0 - v) * (((c >> 2) & 1) ? w : 1.0 - w);
      p += weight * s.position[piece.particles[c]];
    }
    s.deformed[slot] = p.cast<float>();
  });
}

void pbd_step(const CutState& cut, PbdState& s, const TaskRunner& tasks) {
  const PbdParams& params = s.params;
  const int substeps = std::max(1, params.substeps);
  const double h = params.dt / substeps;
  const uint32_t n = uint32_t(s.position.size());
  double* x = s.position[0].data();
  const double* w = s.inv_mass.data();
  for (int sub = 0; sub < substeps; ++sub) {
    // Predict.
    parallel(tasks, n, 4096, [&](uint32_t p) {
      s.previous[p] = s.position[p];
      if (s.inv_mass[p] == 0.0) {
        s.velocity[p].setZero();
        return;
      }
      s.velocity[p] += h * params.gravity;
      s.position[p] += h * s.velocity[p];
    });
    std::fill(s.stretch_lambda.begin(), s.stretch_lambda.end(), 0.0);
    double grab_lambda[3] = {0, 0, 0};
    for (int it = 0; it < params.iterations; ++it) {
      // Stretching, colour by colour.
      for (size_t c = 0; c + 1 < s.stretch_colour_begin.size(); ++c) {
        const uint32_t begin = s.stretch_colour_begin[c], end = s.stretch_colour_begin[c + 1];
        parallel(tasks, end - begin, 2048, [&](uint32_t i) {
          const StretchConstraint& k = s.stretch[begin + i];
          solve_distance(x, w, k.a, k.b, k.rest, params.stretch_compliance, h, s.stretch_lambda[begin + i]);
        });
      }
      // Shape matching, colour by colour.
      for (size_t c = 0; c + 1 < s.piece_colour_begin.size(); ++c) {
        const uint32_t begin = s.piece_colour_begin[c], end = s.piece_colour_begin[c + 1];
        parallel(tasks, end - begin, 256, [&](uint32_t i) {
          SimPiece& piece = s.pieces[s.piece_order[begin + i]];
          double rest[24];
          for (int k = 0; k < 8; ++k) {
            for (int a = 0; a < 3; ++a) rest[3 * k + a] = s.rest[piece.particles[k]][a];
          }
          solve_shape_matching(x, w, piece.particles, rest, 8, params.shape_stiffness, piece.rotation);
        });
      }
      // Grab: a compliant attachment of one particle to its target (XPBD, per axis).
      if (s.grab_particle < n && s.inv_mass[s.grab_particle] > 0.0) {
        const double alpha = s.grab_compliance / (h * h);
        for (int a = 0; a < 3; ++a) {
          const double constraint = s.position[s.grab_particle][a] - s.grab_target[a];
          const double dl = (-constraint - alpha * grab_lambda[a]) / (s.inv_mass[s.grab_particle] + alpha);
          grab_lambda[a] += dl;
          s.position[s.grab_particle][a] += s.inv_mass[s.grab_particle] * dl;
        }
      }
    }
    // Velocities from the positional change, with damping.
    const double keep = 1.0 - params.damping;
    parallel(tasks, n, 4096, [&](uint32_t p) {
      if (s.inv_mass[p] == 0.0) return;
      s.velocity[p] = (s.position[p] - s.previous[p]) * (keep / h);
    });
  }
  ++s.steps;
  pbd_embed(cut, s, tasks);
}

Vec3d pbd_world_to_rest(const PbdState& s, const Vec3d& world) {
  // Inverse-distance weighted displacement of the 8 nearest live particles (smooth in the point, so
  // a blade sliding along the body maps to a blade sliding along its rest shape).
  constexpr int k = 8;
  double best_d[k];
  uint32_t best_p[k];
  int found = 0;
  for (uint32_t p = 0; p < s.position.size(); ++p) {
    if (s.mass[p] <= 0.0) continue;
    const double d = (s.position[p] - world).squaredNorm();
    if (found < k) {
      best_d[found] = d;
      best_p[found++] = p;
    } else {
      int worst = 0;
      for (int i = 1; i < k; ++i) worst = best_d[i] > best_d[worst] ? i : worst;
      if (d < best_d[worst]) {
        best_d[worst] = d;
        best_p[worst] = p;
      }
    }
  }
  if (found == 0) return world;
  Vec3d displacement = Vec3d::Zero();
  double weight = 0.0;
  const double eps = 1e-6 * s.sim_size * s.sim_size;
  for (int i = 0; i < found; ++i) {
    const double w = 1.0 / (best_d[i] + eps);
    displacement += w * (s.position[best_p[i]] - s.rest[best_p[i]]);
    weight += w;
  }
  const Vec3d rest = world - displacement / weight;
  return rest.allFinite() ? rest : world;
}

void grab_begin(PbdState& s, const Vec3d& point, double compliance) {
  double best = std::numeric_limits<double>::infinity();
  s.grab_particle = ~0u;
  for (uint32_t p = 0; p < s.position.size(); ++p) {
    if (s.mass[p] <= 0.0) continue;
    const double d = (s.position[p] - point).squaredNorm();
    if (d < best) {
      best = d;
      s.grab_particle = p;
    }
  }
  s.grab_target = point;
  s.grab_compliance = compliance;
}

void grab_move(PbdState& s, const Vec3d& target) { s.grab_target = target; }
void grab_end(PbdState& s) { s.grab_particle = ~0u; }

double total_mass(const PbdState& s) {
  double m = 0.0;
  for (double x : s.mass) m += x;
  return m;
}

double kinetic_energy(const PbdState& s) {
  double e = 0.0;
  for (size_t p = 0; p < s.position.size(); ++p) {
    if (s.inv_mass[p] > 0.0) e += 0.5 * s.mass[p] * s.velocity[p].squaredNorm();
  }
  return e;
}

uint64_t count_nonfinite(const PbdState& s) {
  uint64_t bad = 0;
  for (size_t p = 0; p < s.position.size(); ++p) {
    if (s.mass[p] <= 0.0) continue;
    bad += !s.position[p].allFinite() + !s.velocity[p].allFinite();
  }
  for (size_t v = 0; v < s.embedding.size(); ++v) {
    if (s.embedding[v].sim_voxel != kDeadIndex && !s.deformed[v].allFinite()) ++bad;
  }
  return bad;
}

uint32_t sim_voxels_divided(const PbdState& s) { return uint32_t(s.divided.size()); }

}  // namespace dvx
