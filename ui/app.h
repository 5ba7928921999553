// The interactive window (DESIGN §1: `divvox [SCENE.json]`): GLFW + OpenGL 4.5 + Dear ImGui on
// the main (render) thread, the simulation on its own thread (ui/sim_runner.h). No GL, GLFW or
// ImGui types here, so the CLI can include it.
#pragma once

#include <string>

namespace dvx {

struct WindowOptions {
  std::string scene_path;       // the scene to open
  std::string record_path;      // record the session from step 0 to this recording
  std::string play_path;        // drive the window from this recording (prints "final hash X" after its last step)
  int exit_after_frames = 0;    // > 0: close after this many frames of a loaded scene (with --play: and not before
                                // the recording's last step)
  std::string screenshot_path;  // PNG of the last frame (the scene image, no panels)
  int width = 1280, height = 720;
};

// Runs the window until it is closed; returns the process exit code (0 ok, 2 bad input or no
// display, 1 internal failure). Never throws. Prints one-line errors on stderr.
int run_window(const WindowOptions& options);

}  // namespace dvx
