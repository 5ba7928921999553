// Small fixtures shared by the sim tests.
#pragma once

#include "sim/voxelize.h"

#include <doctest/doctest.h>

#include <string>

namespace dvx_test {

// The voxel model of a mesh at a resolution (fails the test when voxelization refuses it).
inline dvx::VoxelModel voxelized(const dvx::TriMesh& mesh, int resolution) {
  dvx::VoxelModel model;
  std::string error;
  dvx::VoxelizeParams params;
  params.resolution = resolution;
  REQUIRE_MESSAGE(dvx::voxelize(mesh, params, model, error), error);
  return model;
}

}  // namespace dvx_test
