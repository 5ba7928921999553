// The render thread of a headless replay: EGL offscreen context, the shared renderer, frames to PNG,
// per-frame timings. Draws the newest snapshot the simulation thread published.
#pragma once

#include "engine/snapshot.h"
#include "sim/contact.h"

#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

namespace dvx {

struct HeadlessRenderOptions {
  int width = 1280, height = 720;
  std::string frames_dir;  // "" : no PNG files
  bool wireframe = false;
  Aabb framing;            // the camera frames this box (the rest shape of the object)
  std::vector<ContactPlane> planes;  // the scene's contact planes, drawn as trays with the surface's shadow
};

// Creates the EGL context and renderer on the calling thread (false with a one-line reason).
// Then renders snapshots until the exchange is finished and drained. Captures (readback + PNG) the
// snapshots marked capture; draws the others (for timing). Fills `rows`.
bool run_headless_render(SnapshotExchange& exchange, const HeadlessRenderOptions& options, std::vector<FrameRow>& rows,
                         std::string& error);

// Creates the context and renderer only (to fail fast before the simulation starts).
bool probe_headless_render(std::string& error);

}  // namespace dvx
