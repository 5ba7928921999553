// The render thread's state of the window (camera, tools, view options, panel fields, frame
// statistics), shared by ui/app.cpp (input, drawing) and ui/panels.cpp (ImGui).
#pragma once

#include "render/camera.h"
#include "render/renderer.h"
#include "ui/app.h"
#include "ui/input.h"
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

struct AppState {
  static constexpr size_t kFrameHistory = 300;

  SimRunner* sim = nullptr;
  Renderer* renderer = nullptr;
  std::string gl_renderer;
  WindowOptions window_options;
  SimStatus status;                  // copied from the simulation thread each frame
  const Snapshot* current = nullptr;  // the snapshot on screen (valid until the next take)

  // View.
  Camera camera;
  Viewport viewport;
  Aabb bounds;
  float radius = 1.0f;
  DrawOptions draw;
  bool show_trail = true, show_help = false;
  int trail_length = 48;

  // Tools.
  Tool tool = Tool::kScalpel;
  Eigen::Vector2f cursor = Eigen::Vector2f::Zero();
  bool have_cursor = false, left_down = false, camera_drag = false;
  CursorBlade cursor_blade;
  float blade_depth = 0.0f;  // > 0: set with ctrl+wheel
  bool blade_sent = false, last_cutting = false;
  uint32_t last_blade_stamp = 0;
  BladePose last_sent_pose;
  std::deque<BladePose> trail;
  bool grabbing = false;
  Vec3f grab_anchor = Vec3f::Zero(), grab_target = Vec3f::Zero();
  std::vector<PlayPose> play_poses;

  // Panels.
  SceneEdit edit;
  std::string edit_error, message;
  char scene_path[512] = {};
  char record_path[512] = {};
  char play_path[512] = {};
  char screenshot_path[512] = {};
  float ui_dt = 1.0f / 60.0f, ui_gravity[3] = {0, -9.81f, 0};
  int ui_iterations = 10;

  // Statistics.
  uint64_t frame = 0;
  uint64_t triangles = 0;
  double last_coverage = 0.0;
  std::vector<float> upload_ms, draw_ms, render_ms, fps;
  std::vector<double> latency_frames;  // frames from a cutting command to the snapshot showing it
  uint32_t latency_probe_stamp = 0;
  uint64_t latency_probe_frame = 0;

  void push_frame(double upload, double draw_, double render, double interval_ms) {
    const auto push = [](std::vector<float>& v, double x) {
      v.push_back(float(x));
      if (v.size() > kFrameHistory) v.erase(v.begin());
    };
    push(upload_ms, upload);
    push(draw_ms, draw_);
    push(render_ms, render);
    push(fps, interval_ms > 0 ? 1000.0 / interval_ms : 0.0);
  }
};

// The ImGui panels (ui/panels.cpp).
void draw_panels(AppState& app);
// Reads the last scene image back and writes it as PNG; `message` says what happened.
bool take_screenshot(AppState& app, const std::string& path, std::string& message);
std::string default_screenshot_name();

}  // namespace dvx
