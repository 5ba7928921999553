#include "sim/voxel_model.h"

#include <algorithm>
#include <cmath>

namespace dvx {

const EdgeCrossing* VoxelModel::find_crossing(uint32_t edge) const {
  auto first = crossings.begin(), last = crossings.end();
  const uint64_t rows = uint64_t(lattice.ny + 1) * uint64_t(lattice.nz + 1);
  const uint64_t row = edge / (3 * uint64_t(lattice.nx + 1));
  if (crossing_rows.size() == rows + 1 && crossing_rows.back() == crossings.size() && row < rows) {
    first = crossings.begin() + crossing_rows[row];
    last = crossings.begin() + crossing_rows[row + 1];
  }
  auto it = std::lower_bound(first, last, edge, [](const EdgeCrossing& c, uint32_t e) { return c.edge < e; });
  if (it == last || it->edge != edge) return nullptr;
  return &*it;
}

void VoxelModel::index_crossings() {
  const uint64_t rows = uint64_t(lattice.ny + 1) * uint64_t(lattice.nz + 1);
  const uint64_t row_edges = 3 * uint64_t(lattice.nx + 1);
  crossing_rows.assign(rows + 1, 0);
  size_t c = 0;
  for (uint64_t r = 0; r <= rows; ++r) {
    while (c < crossings.size() && crossings[c].edge / row_edges < r) ++c;
    crossing_rows[r] = uint32_t(c);
  }
}

uint64_t VoxelModel::memory_bytes() const {
  return uint64_t(sizeof(VoxelModel)) + uint64_t(inside.capacity()) * sizeof(uint64_t) +
         uint64_t(crossings.capacity()) * sizeof(EdgeCrossing) + uint64_t(crossing_rows.capacity()) * sizeof(uint32_t);
}

void encode_normal(const Vec3d& n, int16_t out[3]) {
  for (int a = 0; a < 3; ++a) {
    double x = n[a];
    if (!(x == x)) x = 0.0;  // NaN
    x = std::clamp(x, -1.0, 1.0);
    out[a] = int16_t(std::lround(x * 32767.0));
  }
}

Vec3d decode_normal(const int16_t in[3]) {
  Vec3d n(std::max(in[0] / 32767.0, -1.0), std::max(in[1] / 32767.0, -1.0),
          std::max(in[2] / 32767.0, -1.0));
  const double len = n.norm();
  return len > 0.0 ? Vec3d(n / len) : n;
}

Vec3d crossing_position(const Lattice& lattice, const EdgeCrossing& c) {
  const uint32_t node = c.edge / 3u;
  const int axis = int(c.edge % 3u);
  int32_t ijk[3];
  lattice.node_coords(node, ijk);
  Vec3d p = lattice.node_position(ijk[0], ijk[1], ijk[2]);
  p[axis] += double(c.t) * lattice.voxel_size;
  return p;
}

}  // namespace dvx
