// Synthetic shapes written once and used by tests, benchmarks and scenes: each a closed,
// outward-wound triangle mesh unless stated otherwise.
#pragma once

#include "sim/mesh.h"

#include <cstdint>

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

}  // namespace dvx
