// A Snapshot drawn with the shared renderer (render/renderer.h): the bridge between the engine's data
// product and render/, used by the headless render thread (engine/headless_render.h) and the window
// (ui/app.cpp) alike. render/ itself knows no engine type.
#pragma once

#include "engine/snapshot.h"
#include "render/renderer.h"

#include <vector>

namespace dvx {

// Uploads a snapshot to the renderer: positions and normals (area-weighted, computed here into
// `normals`) in full, triangles by the snapshot's dirty range unless `full`.
void upload_snapshot(Renderer& renderer, const Snapshot& snapshot, bool full, std::vector<Vec3f>& normals);

}  // namespace dvx
