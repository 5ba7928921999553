// The render thread's state of the window (camera, tools, view options, panel fields, frame
// statistics), shared by ui/app.cpp (the frame loop), ui/tools.cpp (input), ui/view.cpp (drawing),
// ui/frame_stats.cpp and ui/panels.cpp (ImGui).
#pragma once

#include "render/camera.h"
#include "render/renderer.h"
#include "ui/app.h"
#include "ui/input.h"
#include "ui/sim_pace.h"
#include "ui/sim_runner.h"

#include <deque>
#include <string>
#include <vector>

namespace dvx {

enum class Tool { kScalpel, kGrab };

struct PlayPose {
  uint32_t step;
  BladePose pose;
  bool cutting;
};

// The 3D view and the window's layout: the view fills the window right of the docked panel
// (`view_x` framebuffer pixels in); the renderer's image is the view's size, so the camera frames
// what is visible.
struct ViewState {
  Camera camera;
  Viewport viewport;  // the 3D view (not the window)
  int view_x = 0, panel_width = 0;
  float panel_drawn_width = 0.0f;  // the panel's width as ImGui drew it (tests: it never changes)
  // The panel's sections (below the status line, scrolling when they outgrow it): their height and
  // the room they have, in pixels, as last drawn (printed at exit: tests check they fit at 1280x720).
  float panel_sections_height = 0.0f, panel_sections_room = 0.0f;
  bool panel_cleared = false;  // the window cleared the panel's strip in its colour (ImGui draws no background)
  Aabb bounds;
  float radius = 1.0f, voxel_size = 0.1f;
  DrawOptions draw;
  bool show_anchors = true;  // View: "Show anchors" (the anchored particles' pins)
  bool show_trail = false;
  int trail_length = 48;
  std::vector<PlayPose> play_poses;  // the played recording's blade poses by step (drawn while playing)
};

// The tools (ui/tools.cpp): the cursor, the scalpel's aim and stroke, the grab.
struct ToolState {
  Tool tool = Tool::kScalpel;
  Eigen::Vector2f cursor = Eigen::Vector2f::Zero();  // view pixels
  bool have_cursor = false, cursor_in_view = false, left_down = false, camera_drag = false;
  // A tool switch ended the drag while the button was still held (select_tool): the new tool starts
  // nothing until it is released (else the held button would start a stroke, or a grab, at once).
  bool await_release = false;
  // The scalpel: aimed at the surface point under the cursor (`hover`), `cut_depth` into the tissue.
  bool hover_hit = false;
  SurfaceHit hover;
  std::vector<Eigen::Vector2f> pick_scratch;  // pick_surface's per-vertex buffer, kept between frames
  float entry_t = 0.0f;                       // eye distance of the blade's entry (kept while a drag leaves the object)
  float cut_depth = 1.0f;                     // scene units, set live (ctrl+wheel, [ and ], the Tools slider)
  // The blade reaches through the tissue under the cursor: the depth along the blade to the far side
  // of that tissue (where the blade's line leaves it) and a voxel; 0: none found.
  float through_depth = 0.0f;
  SurfaceHit exit_hit;              // where the blade's line leaves the tissue it entered
  float reach_depth = 0.0f;         // the blade's depth now: cut_depth, or through_depth when deeper
  BladePose blade_pose;             // the pose under the cursor now
  Vec3f edge_dir = Vec3f(1, 0, 0);  // world direction the blade's edge faces (the drag's direction)
  bool blade_sent = false, last_cutting = false;
  uint32_t last_blade_stamp = 0;
  BladePose last_sent_pose;
  Eigen::Vector2f last_sent_cursor = Eigen::Vector2f::Zero();  // the cursor then (a fast drag covers the path since)
  std::deque<BladePose> trail;
  // A drag's outcome: voxels cut between its press and the step after its release.
  bool cut_pending = false;
  uint32_t cut_release_stamp = 0;
  uint64_t cut_voxels_before = 0;
  bool drag_touched = false;  // the cursor was over the tissue during the drag
  // Grab: the surface vertex slot picked (highlighted as it moves) and where it is pulled.
  bool grabbing = false;
  uint32_t grab_vertex = 0;
  Vec3f grab_anchor = Vec3f::Zero(), grab_target = Vec3f::Zero();
  // The region grab's strength (sim/pbd.h "Grab"; from the scene's "grab" block, set live in Tools):
  // total stiffness N/m, force limit N (0: none), the radius of the tissue held (scene lengths).
  float grab_stiffness = 500.0f, grab_force_limit = 30.0f, grab_radius = 0.015f;
  bool grab_anchor_said = false;  // the status line said this grab is held by an anchor
};

// The panel's fields (ui/panels.cpp): the status line's message, text fields, scene and solver edits.
struct PanelFields {
  SceneEdit edit;
  std::string edit_error, message;
  double message_until = 0.0;  // glfw time when `message` stops showing (0: until replaced)
  char scene_path[512] = {};
  char record_path[512] = {};
  char play_path[512] = {};
  char screenshot_path[512] = {};
  // A screenshot asked for (F12, the View panel's Save): taken by the next frame once the view is
  // drawn (in direct mode the image is the back buffer, good only between the view's draw and the swap).
  std::string screenshot_request;
  std::string window_screenshot_request;  // shift+F12: the whole window, panel included (after the panels)
  float ui_dt = 1.0f / 60.0f, ui_gravity[3] = {0, -9.81f, 0};
  int ui_iterations = 10;
  bool show_help = false;
};

// The recent frames' figures the Performance section plots, the input-to-cut latency, the pace.
struct FrameHistory {
  static constexpr size_t kFrames = 300;

  uint64_t frame = 0;
  uint64_t triangles = 0;
  double last_coverage = 0.0;
  std::vector<float> upload_ms, draw_ms, render_ms, fps;  // (up to kFrames) per frame
  std::vector<float> normals_ms;       // per snapshot shown: its normals' time (simulation thread or GPU passes)
  std::vector<double> latency_frames;  // frames from a cutting command to the snapshot showing it
  std::vector<double> latency_ms;      // the same in wall-clock ms (frame rates vary: the scene cache)
  double latency_probe_time = 0.0;     // glfwGetTime() when the probed command was sent
  uint32_t latency_probe_stamp = 0;
  uint64_t latency_probe_frame = 0;
  // The simulation's pace (ui/sim_pace.h), shown on the status line and printed at exit.
  SimPace pace;

  static void push(std::vector<float>& v, double x) {
    v.push_back(float(x));
    if (v.size() > kFrames) v.erase(v.begin());
  }
  void push_frame(double upload, double draw_, double render, double interval_ms) {
    push(upload_ms, upload);
    push(draw_ms, draw_);
    push(render_ms, render);
    push(fps, interval_ms > 0 ? 1000.0 / interval_ms : 0.0);
  }
};

// The render thread's state of the window, by what uses it.
struct AppState {
  SimRunner* sim = nullptr;
  Renderer* renderer = nullptr;
  std::string gl_renderer;
  WindowOptions window_options;
  SimStatus status;                                 // copied from the simulation thread each frame
  const Snapshot* current = nullptr;                // the snapshot on screen (valid until the next take)
  uint64_t restores_seen = 0, undo_notes_seen = 0;  // the simulation's undo / redo counts followed

  ViewState view;
  ToolState tools;
  PanelFields panel;
  FrameHistory history;
};

// The ImGui panels (ui/panels.cpp): docked on the left, `app.view.panel_width` wide, the window's height.
void draw_panels(AppState& app);
// The docked panel's width for a framebuffer width (fixed per window size: never dragged).
int panel_width_for(int framebuffer_width);
// A status-line message for `seconds` (0: until replaced).
void show_message(AppState& app, const std::string& text, double seconds = 6.0);
// Undo / redo requests (keys and buttons).
void request_undo(AppState& app, bool redo);
// Reads the last scene image back and writes it as PNG; `message` says what happened.
bool take_screenshot(AppState& app, const std::string& path, std::string& message);
// Reads the whole window's back buffer (fb_w x fb_h: the panel and the view) and writes it as PNG.
bool take_window_screenshot(int fb_w, int fb_h, const std::string& path, std::string& message);
// The window's output folder (F12 screenshots, the default recording), relative to the working
// directory like the other commands' out/ folders.
constexpr const char* kWindowOutputDir = "out/window";
// kWindowOutputDir/name, the folder created.
std::string default_output_path(const std::string& name);
std::string default_screenshot_name();

}  // namespace dvx
