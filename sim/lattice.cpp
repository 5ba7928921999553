#include "sim/lattice.h"

#include <algorithm>
#include <cmath>

namespace dvx {

bool make_lattice(const Aabb& box, int resolution, int padding, Lattice& out) {
  if (box.empty() || resolution < 1 || padding < 0) return false;
  const Vec3d extent = box.extent();
  const double longest = extent.maxCoeff();
  if (!(longest > 0.0) || !std::isfinite(longest)) return false;

  // Cubic voxels: `resolution` of them span the longest axis exactly.
  Lattice lattice;
  lattice.voxel_size = longest / resolution;
  int32_t counts[3];
  for (int a = 0; a < 3; ++a) {
    // Shorter axes get enough voxels to cover the box (at least one).
    const double cells = std::ceil(extent[a] / lattice.voxel_size - 1e-9);
    counts[a] = std::max<int32_t>(1, int32_t(std::min(cells, 2.0e9))) + 2 * padding;
  }
  lattice.nx = counts[0];
  lattice.ny = counts[1];
  lattice.nz = counts[2];

  // Centre the box in the grid.
  const Vec3d grid_extent = lattice.voxel_size * Vec3d(lattice.nx, lattice.ny, lattice.nz);
  lattice.origin = 0.5 * (box.min + box.max) - 0.5 * grid_extent;
  out = lattice;
  return true;
}

}  // namespace dvx
