// The window's 3D view (ui/view.cpp): the snapshot handed to the renderer, the scene drawn (or its
// cached image reused), the trays and their shadow, the overlays (scalpel, trail, grab), the cursor's
// label, screenshots. WindowContext holds what the frame loop (ui/app.cpp) works with.
#pragma once

#include "engine/timing.h"
#include "render/camera.h"
#include "render/renderer.h"
#include "ui/app_state.h"
#include "ui/frame_stats.h"
#include "ui/overlay.h"
#include "ui/sim_runner.h"
#include "ui/tools.h"

#include <string>
#include <vector>

struct GLFWwindow;

namespace dvx {

// What a drawn view shows (scene_key_of): equal keys, equal images.
struct SceneKey {
  uint64_t sequence = 0;
  Camera camera;
  int width = 0, height = 0, x = 0;
  DrawOptions options;
};

// Everything the window's frame loop works with: the GLFW window, the renderer and overlays, the
// simulation thread, the frame statistics and the per-frame scratch.
struct WindowContext {
  GLFWwindow* window = nullptr;
  std::string gl_renderer;
  bool software = false;  // llvmpipe / softpipe: the frame runs on the same CPU cores as the simulation
  Renderer renderer;
  LineOverlay overlay;
  SolidOverlay solid_overlay;
  SimRunner sim;
  FrameStats stats;
  std::vector<LineVertex> lines;
  std::vector<SolidVertex> solids;
  uint64_t generation = 0, last_sequence = 0;
  Clock::time_point last_frame = Clock::now();
  bool profile = false;      // DIVVOX_FRAME_PROFILE=1
  bool gpu_normals = false;  // normals from the GPU passes (else from the simulation thread)
  bool idle = false;         // the last frame showed nothing new and the simulation is paused
  // Scene cache (software rasterisers): the view is drawn into the offscreen target only when what
  // it shows changed (scene_key), and copied into the back buffer every frame (renderer_present),
  // so a frame without a new snapshot or camera move costs the copy, the overlays and the panels.
  bool cache_scene = false;
  bool scene_valid = false;
  SceneKey scene_key;
  // Double-buffered cache (DIVVOX_SPLIT_FRAMES=1: on; off by default): a new snapshot is drawn over two frames
  // (scene_draw_for); split_pending: the first half is drawn, for pending_key, and the frame
  // after draws the rest before a new snapshot is taken.
  bool split_frames = false, split_pending = false;
  SceneKey pending_key;
  // The snapshot taken holds the latency probe's cut, sent at that frame and time (record_latency).
  bool latency_hit = false;
  uint64_t latency_hit_frame = 0;
  double latency_hit_time = 0.0;
  // What the tray's shadow was built for (draw_trays).
  uint64_t shadow_sequence = 0;
  std::vector<Vec3f> shadow_positions;  // the snapshot's vertices that cast the shadow (others NaN)
  float shadow_yaw = 0.0f, shadow_pitch = 0.0f;
  Eigen::Vector2f last_cursor = Eigen::Vector2f::Zero();
  bool font_nearest = false;  // the panel's font atlas set to nearest sampling (ui/app.cpp)
};

// The camera framing the object's bounds; ViewState::radius from them.
void frame_camera(AppState& app);
// The scene's contact planes as trays: centred under the object, a little wider than it.
void set_trays(AppState& app);
// The 3D view right of the docked panel, for a framebuffer size.
void layout_view(AppState& app, int fb_w, int fb_h);
// The newest snapshot to the renderer and the input-to-cut latency probe. Returns the normals' time
// (ms, on the simulation thread) of the snapshot taken, or -1 when none was new.
double take_snapshot(AppState& app, WindowContext& w);
// The window's back buffer cleared (direct and scene-cache modes); `view_covered`: the scene
// cache's copy covers the view.
void clear_window(AppState& app, int fb_w, int fb_h, bool view_covered);
// The view's surface, handed to the rasteriser at once.
void draw_surface(AppState& app, WindowContext& w);
// The trays with the surface's shadow.
void draw_trays(AppState& app, WindowContext& w);
// The scalpel, its entry mark and trail, the grabbed point, over the scene.
void draw_overlays(AppState& app, WindowContext& w);
// The 3D view of a frame (the tools aimed while it rasterises: handle_tools). Returns what it drew.
SceneDraw draw_view(AppState& app, WindowContext& w, int fb_w, int fb_h, const MouseFrame& mouse);
// The input-to-cut latency of a probed cut whose snapshot this frame showed.
void record_latency(AppState& app, WindowContext& w);
// The depth next to the cursor while aiming (ImGui's foreground layer).
void cursor_label(AppState& app);

}  // namespace dvx
