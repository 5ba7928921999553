// The blade's swept surface and the lattice edges it crosses.
//
// The scalpel is a segment (its cutting edge). Between two consecutive poses (a0,b0) -> (a1,b1)
// it sweeps the quad a0 b0 b1 a1, split into two triangles. A lattice edge is cut where it crosses
// one of these triangles. The search visits only the lattice lines the triangle's projection
// covers (2D scanline over the projection onto the plane perpendicular to each axis), so its cost
// is proportional to the number of edges crossed, not to the grid's size.
//
// Robustness rules (exact, never by luck):
// - Blade coordinates are snapped to a fixed-point grid of 2^-16 voxel in lattice units and all
//   side/inside tests are evaluated in integer arithmetic.
// - Point-in-triangle is inclusive: a lattice line through a triangle edge or vertex is reported by
//   every triangle that touches it (cutting is idempotent, so double reports are harmless, while a
//   missed line would leave a material bridge through the cut).
// - A lattice node exactly on a triangle's plane is given a side by symbolic perturbation: the node
//   is moved by eps * (1, eps, eps^2), i.e. its side is sign(n_x), else sign(n_y), else sign(n_z) of
//   the plane normal n. So the edges of a line are split consistently and every node ends up on
//   exactly one side of the sheet, whatever the axis of the query.
// - A triangle parallel to an axis (zero projected area) crosses no edge of that axis.
// - Coordinates are clamped to [-2^23, 2^23] lattice units per axis before snapping, which bounds
//   every exact product to 124 bits (__int128). Geometry within that window is exact and
//   untouched; a vertex farther out (a runaway or huge blade) is moved onto the window's box, so
//   only such triangles change shape, and nothing overflows. A lattice axis longer than 2^23
//   voxels (impossible for a non-degenerate lattice under the 32-bit id limit) is cut only up to
//   node 2^23. NaN coordinates make the triangle cross nothing.
#pragma once

#include "sim/lattice.h"

#include <cstdint>
#include <vector>

namespace dvx {

// One pose of the blade: its cutting edge from a to b, in scene coordinates.
struct BladePose {
  Vec3d a = Vec3d::Zero();
  Vec3d b = Vec3d::Zero();
};

// A lattice edge crossed by a swept triangle.
struct EdgeHit {
  uint32_t edge;  // lattice edge id (3 * node + axis)
  float t;        // crossing parameter along the edge from its lower node, in [0, 1]
  Vec3f normal;   // unit normal of the swept triangle (orientation arbitrary but consistent per triangle)
};

// Work counters of the scanline search (optional; for tests and benchmarks). Accumulated, never
// reset by the functions. The search is O(rows_scanned + lines_tested) and lines_tested exceeds
// the hits only by lines whose crossing lies on the lattice's end nodes.
struct SweepStats {
  uint64_t rows_scanned = 0;  // scanlines of a 2D projection visited (within the lattice)
  uint64_t lines_tested = 0;  // lattice lines whose crossing point was computed
};

// Appends the lattice edges crossed by triangle (p0, p1, p2) (scene coordinates). Edges outside
// the lattice are ignored. A degenerate triangle (zero area after snapping) crosses nothing.
// Each edge is reported at most once per triangle; order: axis, then scanline, then along it.
void triangle_edge_hits(const Lattice& lattice, const Vec3d& p0, const Vec3d& p1, const Vec3d& p2,
                        std::vector<EdgeHit>& out, SweepStats* stats = nullptr);

// Appends the hits of the quad swept from `from` to `to` (two triangles a0 b0 b1 and a0 b1 a1).
// A blade that did not move, or moved only along itself, sweeps no area and cuts nothing.
// An edge on the quad's diagonal a0 b1 may be reported by both triangles (callers dedupe).
void sweep_edge_hits(const Lattice& lattice, const BladePose& from, const BladePose& to, std::vector<EdgeHit>& out,
                     SweepStats* stats = nullptr);

}  // namespace dvx
