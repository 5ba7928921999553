// The finite-element reference of the elastic benchmarks (issue 30): CalculiX (`ccx`, Debian
// calculix-ccx) on the same geometry, anchors, gravity and material as a divvox run.
//
// Geometry. The reference meshes a structured grid of hexahedral cells (C3D8I: incompatible modes,
// so one element through the thickness does not lock in bending) with an occupancy per cell: a box
// fills its grid; a voxelized mesh fills the cells whose centre lies in the material of the fine
// lattice (the dual cell of an inside node, as divvox counts mass). A cut is meshed, not modelled:
// two cells that share a face whose centre-to-centre segment crosses a cut rectangle keep their own
// nodes there (a grid node is duplicated once per group of its cells still joined by faces), so a
// cut halfway opens and a cut through leaves two bodies.
//
// Deck. *NODE / *ELEMENT TYPE=C3D8I / *MATERIAL (*ELASTIC E, nu or *HYPERELASTIC NEO HOOKE
// C10, D1) / *DENSITY / *BOUNDARY of the nodes inside the anchored boxes / *DLOAD GRAV /
// *STATIC (with NLGEOM for large deformation) / *NODE PRINT U. The displacements are read from the
// .dat file (the last increment's table).
//
// Comparison. Displacements are interpolated trilinearly in the cell holding a point (or the
// nearest occupied cell, for points just outside the meshed cells).
#pragma once

#include "sim/mesh.h"

#include <array>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

namespace dvx {

// A cut the reference meshes: the rectangle {p : (p - point) . normal = 0} clipped to `box` (the
// blade's swept quad, which for the benchmark's cuts is axis-aligned).
struct CcxCut {
  Vec3d point = Vec3d::Zero();
  Vec3d normal = Vec3d::UnitX();
  Aabb box;  // the part of the plane that is cut
};

// A structured hexahedral mesh over cells of a grid.
struct HexMesh {
  Vec3d origin = Vec3d::Zero();     // corner of cell (0,0,0)
  Vec3d spacing = Vec3d::Ones();    // cell edge per axis
  int nx = 0, ny = 0, nz = 0;       // cells per axis
  std::vector<int32_t> cell_element;             // (cells) element index, -1 for an empty cell
  std::vector<Vec3d> nodes;                      // (nodes) rest positions
  std::vector<std::array<uint32_t, 8>> elements;  // (elements) node indices, CalculiX C3D8 order
  std::vector<std::array<int32_t, 3>> element_cell;  // (elements) cell coordinates

  uint32_t cell(int i, int j, int k) const { return uint32_t(i + nx * (j + ny * k)); }
};

// Builds the mesh: cells of `spacing` from `origin`, `n` per axis, occupied where `inside(centre)`;
// cells separated by one of `cuts` do not share nodes.
HexMesh make_hex_mesh(const Vec3d& origin, const Vec3d& spacing, const std::array<int, 3>& n,
                      const std::function<bool(const Vec3d&)>& inside, const std::vector<CcxCut>& cuts = {});

// Material and load of a reference problem (SI units).
struct CcxProblem {
  double youngs_modulus = 1e6, poisson_ratio = 0.45, density = 1000.0;
  Vec3d gravity = Vec3d(0.0, -9.81, 0.0);
  bool nlgeom = false;       // geometric nonlinearity (large deformation)
  bool neo_hookean = false;  // *HYPERELASTIC NEO HOOKE instead of linear *ELASTIC
  int increments = 10;       // with nlgeom: initial increment 1 / increments
  std::vector<Aabb> fixed;   // nodes whose rest position lies in a box are fixed (all 3 dofs)
};

// Writes the CalculiX input deck. Throws std::runtime_error for a problem it cannot express (no
// element, no fixed node, a material out of range).
std::string ccx_deck(const HexMesh& mesh, const CcxProblem& problem);

// The ccx binary: $DIVVOX_CCX, else `ccx` on the PATH; "" when there is none.
std::string find_ccx();

// Result of one CalculiX run.
struct CcxResult {
  bool ok = false;
  std::string error;                // why not (ccx missing, timed out, no displacement table, ...)
  std::vector<Vec3d> displacement;  // (mesh nodes)
  double seconds = 0.0;             // wall time of ccx
};

// Runs ccx on the deck in a fresh temporary folder (removed afterwards unless `keep_dir` names a
// folder to write into), with a time limit; reads the displacements of the last increment.
CcxResult run_ccx(const HexMesh& mesh, const std::string& deck, double timeout_seconds = 60.0,
                  const std::string& keep_dir = "");

// Parses a .dat file's last "displacements" table into (node count) vectors (1-based node ids in
// the file). False with `error` when none is complete.
bool parse_ccx_displacements(const std::string& dat_text, size_t node_count, std::vector<Vec3d>& out,
                             std::string& error);

// The displacement at a rest point: trilinear in the cell holding it, or in the nearest occupied
// cell (within `search` cells) for points outside every element; false when none is near. The cell
// is chosen at point + hint (a surface point nudged into its material, so a point on a cut face
// reads its own side), the interpolation is at the point.
bool interpolate_displacement(const HexMesh& mesh, const std::vector<Vec3d>& displacement, const Vec3d& point,
                              Vec3d& out, int search = 3, const Vec3d& hint = Vec3d::Zero());

}  // namespace dvx
