// The orbit camera shared by the headless renderer, the window mode and mouse picking.
// Pure maths: no GL, unit-tested on its own.
#pragma once

#include "sim/mesh.h"

#include <Eigen/Core>

namespace dvx {

// An orbit camera: the eye sits on a sphere of radius `distance` around `target`, placed by two
// angles, with +y up. Angles rather than an eye/up pair because the window mode turns the camera
// by mouse drags (yaw, pitch) and zooms by changing the distance; nothing can go degenerate at the
// poles (the basis is built from the angles, not from a cross product with +y).
struct Camera {
  Vec3f target = Vec3f::Zero();  // the point looked at (orbit centre)
  float distance = 1.0f;         // eye to target
  float yaw = 0.0f;              // radians about +y; 0: the eye is on +z of the target, looking along -z
  float pitch = 0.0f;            // radians; > 0: the eye is above the target, looking down
  float fov_y = 0.7853982f;      // vertical field of view, radians (45 degrees)
  float z_near = 0.01f;          // clip planes (distances along the view direction)
  float z_far = 100.0f;
};

// Size of the image drawn, in pixels.
struct Viewport {
  int width = 1;
  int height = 1;
  float aspect() const { return height > 0 ? float(width) / float(height) : 1.0f; }
};

// Eye position and the orthonormal view basis (forward: from the eye toward the target).
Vec3f camera_eye(const Camera& camera);
Vec3f camera_forward(const Camera& camera);
Vec3f camera_right(const Camera& camera);
Vec3f camera_up(const Camera& camera);

// World -> eye space (OpenGL convention: the eye looks along -z).
Eigen::Matrix4f view_matrix(const Camera& camera);
// Eye space -> clip space (OpenGL perspective, depth -1..1 between z_near and z_far).
Eigen::Matrix4f projection_matrix(const Camera& camera, float aspect);

// The default view of an object: looks at the box centre slightly from above and from the front-right
// (yaw 25, pitch 20 degrees), as close as keeps all 8 box corners inside the image with a 10 %
// margin on each side. Clip planes leave room to zoom in and out.
Camera frame_box(const Aabb& box, float aspect);

// Unit direction of the ray from the eye through `pixel`, given in image coordinates: x to the
// right, y downward, (0,0) the top-left corner of the image, pixel (i,j) covering [i,i+1)x[j,j+1)
// (so its centre is (i+0.5, j+0.5)). For mouse picking.
Vec3f ray_direction(const Camera& camera, const Viewport& viewport, const Eigen::Vector2f& pixel);

}  // namespace dvx
