// Synthetic shapes written once and used by the tests (sim, engine, render): each a closed,
// outward-wound triangle mesh unless stated otherwise.
#pragma once

#include "sim/mesh.h"

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <vector>

namespace dvx {

// UV sphere of radius r with `segments` around and segments/2 rings.
TriMesh make_sphere(const Vec3d& centre, double radius, int segments);
// Icosphere (subdivided icosahedron), well-shaped triangles.
TriMesh make_icosphere(const Vec3d& centre, double radius, int subdivisions);
// Box with half extents, each face split into n x n quads, rotated by `rotation` about centre.
TriMesh make_box(const Vec3d& centre, const Vec3d& half_extent, const Eigen::Matrix3d& rotation, int n = 1);
// Torus around the z axis (genus 1).
TriMesh make_torus(const Vec3d& centre, double major_radius, double minor_radius, int major_segments,
                   int minor_segments);
// The same mesh with every triangle's winding reversed.
TriMesh flip_winding(const TriMesh& mesh);
// Concatenation of two meshes (several components).
TriMesh merge_meshes(const TriMesh& a, const TriMesh& b);
// Removes the triangles whose centroid lies within `radius` of `centre` (makes a hole).
TriMesh cut_hole(const TriMesh& mesh, const Vec3d& centre, double radius);
// A U-shaped block (two arms joined at the bottom): for cut tests across both arms.
TriMesh make_u_shape(const Vec3d& centre, double width, double height, double depth, double arm_width);

// The boundary of a union of unit cells (integer cell coordinates, cells sharing only an edge or a
// corner are not allowed), scaled by `cell`, rotated by `rotation` about the origin and moved to
// `centre`: closed and outward-wound, with any genus. The shapes below are built with it.
TriMesh make_cell_union(const std::vector<std::array<int, 3>>& cells, double cell, const Eigen::Matrix3d& rotation,
                        const Vec3d& centre);
// A plate of nx x ny cells, `thickness` cells thick, with `holes` square through-holes of one cell
// in a row along x (genus = holes).
TriMesh make_holed_plate(int holes, double cell, int thickness, const Eigen::Matrix3d& rotation, const Vec3d& centre);
// A lollipop: a 4x4x4-cell head on a 1x1-cell stem `stem` cells long (genus 0, one component).
TriMesh make_lollipop(int stem, double cell, const Eigen::Matrix3d& rotation, const Vec3d& centre);
// Two nested closed shells: a sphere of radius r_out wound outward around one of radius r_in wound
// inward (a hollow ball: one solid, two boundary components).
TriMesh make_two_shells(const Vec3d& centre, double r_out, double r_in, int subdivisions);

}  // namespace dvx
