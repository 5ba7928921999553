#include "sim/cut.h"
#include "sim/shapes.h"
#include "sim/state_hash.h"
#include "sim/voxelize.h"

#include <doctest/doctest.h>

using namespace dvx;

TEST_SUITE("state_hash") {
  TEST_CASE("equal states hash equal, a moved vertex, a different cut or a freed slot change it") {
    const TriMesh box = make_box(Vec3d(0.01, 0.02, 0.03), Vec3d(1, 0.7, 0.6), Eigen::Matrix3d::Identity(), 1);
    VoxelModel model;
    std::string error;
    VoxelizeParams params;
    params.resolution = 20;
    REQUIRE(voxelize(box, params, model, error));
    CutState a, b;
    init_cut_state(model, a);
    init_cut_state(model, b);
    CHECK(cut_state_hash(a) == cut_state_hash(b));
    const BladePose from{Vec3d(0.1, -1, -2), Vec3d(0.1, -1, 2)}, to{Vec3d(0.1, 0.2, -2), Vec3d(0.1, 0.2, 2)};
    cut_step(model, a, from, to);
    CHECK(cut_state_hash(a) != cut_state_hash(b));
    cut_step(model, b, from, to);
    CHECK(cut_state_hash(a) == cut_state_hash(b));
    // One vertex moved by one ulp.
    for (size_t i = 0; i < b.surface.positions.size(); ++i) {
      if (b.surface.vertex_piece[i] == CutSurface::kFreeKey) continue;
      b.surface.positions[i].x() = std::nextafter(b.surface.positions[i].x(), 10.0f);
      break;
    }
    CHECK(cut_state_hash(a) != cut_state_hash(b));
    CHECK(hash_hex(0x1234).size() == 16);
  }
}
