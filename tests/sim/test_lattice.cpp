#include "sim/lattice.h"

#include <doctest/doctest.h>

using namespace dvx;

TEST_SUITE("lattice") {
  TEST_CASE("resolution voxels along the longest axis, padding on every side, box centred") {
    Aabb box;
    box.grow(Vec3d(-1, 0, 2));
    box.grow(Vec3d(3, 1, 2.5));
    Lattice l;
    REQUIRE(make_lattice(box, 64, 1, l));
    CHECK(l.voxel_size == doctest::Approx(4.0 / 64));
    CHECK(l.nx == 66);
    CHECK(l.ny == 16 + 2);
    CHECK(l.nz == 8 + 2);
    const Vec3d grid_centre = l.origin + 0.5 * l.voxel_size * Vec3d(l.nx, l.ny, l.nz);
    CHECK((grid_centre - Vec3d(1, 0.5, 2.25)).norm() < 1e-12);
    // Every box corner is at least `padding` voxels inside the grid.
    for (int a = 0; a < 3; ++a) {
      CHECK(box.min[a] - l.origin[a] >= l.voxel_size * (1 - 1e-9));
    }
  }

  TEST_CASE("index round trips") {
    Lattice l;
    l.nx = 5;
    l.ny = 7;
    l.nz = 3;
    int32_t c[3];
    l.node_coords(l.node(4, 6, 2), c);
    CHECK(c[0] == 4);
    CHECK(c[1] == 6);
    CHECK(c[2] == 2);
    l.voxel_coords(l.voxel(4, 6, 2), c);
    CHECK(c[0] == 4);
    CHECK(c[1] == 6);
    CHECK(c[2] == 2);
    CHECK(Lattice::edge(l.node(1, 2, 0), 2) == 3 * l.node(1, 2, 0) + 2);
  }

  TEST_CASE("degenerate boxes and resolutions are refused") {
    Aabb flat;
    flat.grow(Vec3d(1, 1, 1));
    Lattice l;
    CHECK_FALSE(make_lattice(flat, 64, 1, l));
    CHECK_FALSE(make_lattice(Aabb{}, 64, 1, l));
    Aabb box;
    box.grow(Vec3d(0, 0, 0));
    box.grow(Vec3d(1, 1, 1));
    CHECK_FALSE(make_lattice(box, 0, 1, l));
    CHECK(make_lattice(box, 1, 1, l));
    CHECK(l.nx == 3);
  }
}
