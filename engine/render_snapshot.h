// A Snapshot drawn with the shared renderer (render/renderer.h): the bridge between the engine's data
// product and render/, used by the headless render thread (engine/headless_render.h) and the window
// (ui/app.cpp) alike. render/ itself knows no engine type.
#pragma once

#include "engine/snapshot.h"
#include "render/renderer.h"

#include <vector>

namespace dvx {

// A snapshot as the renderer's mesh view: every vertex slot (they all move), the triangle slots of
// its dirty range unless `full`; no normals (the caller adds them).
RenderMesh snapshot_render_mesh(const Snapshot& snapshot, bool full);

// Uploads a snapshot to the renderer: positions and normals (area-weighted, computed here into
// `normals`) in full, triangles by the snapshot's dirty range unless `full`.
void upload_snapshot(Renderer& renderer, const Snapshot& snapshot, bool full, std::vector<Vec3f>& normals);

}  // namespace dvx
