// The real meshes of ../shared/assets through load -> voxelize -> dual contour -> error,
// exactly as `divvox voxelize` runs them. Skipped (with a message) where that folder is absent.
#include "engine/voxelize_job.h"
#include "support.h"

#include <doctest/doctest.h>

#include <cmath>

using namespace dvx;

namespace {

VoxelizeJobResult run(const std::string& path, int resolution) {
  VoxelizeJobOptions options;
  options.mesh_path = path;
  options.resolution = resolution;
  options.error_samples = 40000;
  options.seed = 11;
  return run_voxelize(options);
}

const char* kMeshes[] = {"bunny_npm.obj", "bunny_closed_70k.obj", "armadillo_100k.obj", "liver_sofa_smooth.obj",
                         "liver2_sofa.obj"};

}  // namespace

TEST_SUITE("real_meshes") {
  TEST_CASE("every shared mesh at 64 and 128: a closed 2-manifold of genus 0, one component at 128, volume and error bounds") {
    for (const char* name : kMeshes) {
      const std::string path = dvx_test::shared_asset(name);
      if (path.empty()) continue;
      for (int resolution : {64, 128}) {
        CAPTURE(name);
        CAPTURE(resolution);
        const VoxelizeJobResult r = run(path, resolution);
        CHECK(r.stats.boundary_edges == 0);
        CHECK(r.stats.misoriented_edges == 0);
        CHECK(r.stats.nonmanifold_edges == 0);
        // Genus 0 per component; at 128 the lattice resolves every shared mesh: one component (at 64
        // the armadillo's thinnest parts hold no lattice node and come apart).
        CHECK(r.stats.euler == 2 * int64_t(r.stats.components));
        if (resolution == 128) CHECK(r.stats.components == 1);
        CHECK(r.stats.volume > 0.0);
        CHECK(r.input_watertight);
        if (resolution == 128) {
          CHECK(std::abs(r.stats.volume - r.input_volume) / r.input_volume <= 0.02);
          CHECK(r.error.max <= 1.0);
          CHECK(r.error.rms <= 0.25);
        }
      }
    }
  }

  TEST_CASE("the shipped bunny runs without ../shared/assets") {
    const VoxelizeJobResult r = run(dvx_test::source_path("assets/meshes/bunny_npm.obj"), 64);
    CHECK(r.stats.boundary_edges == 0);
    CHECK(r.stats.components == 1);
    CHECK(r.model.occupied_voxels > 1000);
  }
}
