// The window's tools (ui/tools.cpp): keys, the mouse's camera moves, the scalpel and the grab, sent
// as commands to the simulation thread. No GL or ImGui types here; GLFW only as an opaque window.
#pragma once

#include "ui/app_state.h"

#include <utility>
#include <vector>

struct GLFWwindow;

namespace dvx {

// Input events gathered by the GLFW callbacks (ui/app.cpp) since the last frame.
struct InputEvents {
  double scroll = 0.0;
  std::vector<std::pair<int, int>> keys;  // (key, mods) presses
};

// The mouse's state for a frame, read before the scene is drawn (the camera moves first) and used
// after it is handed to the rasteriser (picking and the tools: handle_tools).
struct MouseFrame {
  Eigen::Vector2f pixel = Eigen::Vector2f::Zero(), delta = Eigen::Vector2f::Zero();  // view pixels
  bool left = false, free_mouse = false;
};

// The frame's key presses (shortcuts); consumes events.keys.
void handle_keys(AppState& app, InputEvents& events, GLFWwindow* window);
// The cursor, the camera's mouse moves and the wheel; consumes events.scroll.
MouseFrame handle_mouse(AppState& app, InputEvents& events, GLFWwindow* window);
// The scalpel aimed at the surface under the cursor, and the current tool's commands.
void handle_tools(AppState& app, const MouseFrame& mouse);
// Switches the tool (keys, the Tools panel). A drag in progress ends first, as its tool's release
// (a grab lets go, a scalpel stroke ends and reports its cut); the button still held starts nothing.
void select_tool(AppState& app, Tool tool);
// Ends the drag in progress (if any) as a release of the tool that started it.
void end_drag(AppState& app);
void set_cut_depth(AppState& app, float depth);
// A finished scalpel stroke says what it cut ("cut: N voxels" on stdout and the status line), once
// its last step has run.
void report_cut(AppState& app);
// The mouse's commands start afresh (a new session, or an undo / redo: stamps from the new step).
void reset_mouse_commands(AppState& app);

}  // namespace dvx
