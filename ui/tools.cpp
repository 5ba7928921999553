#include "ui/tools.h"

#include "render/camera.h"
#include "ui/input.h"
#include "ui/view.h"

#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#include <imgui.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace dvx {

namespace {

// One blade command from the mouse. A change of `cutting` never merges with the previous command
// into one step (a press must not sweep from the last release, a release must not drop the last move).
void send_blade(AppState& app, const BladePose& pose, bool cutting) {
  uint32_t stamp = app.sim->next_step();
  if (app.tools.blade_sent && cutting != app.tools.last_cutting)
    stamp = std::max(stamp, app.tools.last_blade_stamp + 1);
  stamp = std::max(stamp, app.tools.last_blade_stamp);
  StepCommands c;
  c.has_blade = true;
  c.blade = pose;
  c.cutting = cutting;
  app.sim->push({stamp, c});
  // Paused: each blade move runs one step, so the cut shows at once.
  if (app.status.paused) app.sim->step_once();
  app.tools.blade_sent = true;
  app.tools.last_cutting = cutting;
  app.tools.last_blade_stamp = stamp;
  app.tools.last_sent_pose = pose;
  app.tools.last_sent_cursor = app.tools.cursor;
  if (cutting) {
    app.tools.trail.push_back(pose);
    while (app.tools.trail.size() > size_t(app.view.trail_length)) app.tools.trail.pop_front();
    if (app.history.latency_probe_stamp == 0) {
      app.history.latency_probe_stamp = stamp + 1;  // the snapshot after this step shows the cut
      app.history.latency_probe_frame = app.history.frame;
      app.history.latency_probe_time = glfwGetTime();
    }
  }
}

void send_grab(AppState& app, GrabCommand::Kind kind, const Vec3f& target) {
  StepCommands c;
  c.grab.kind = kind;
  c.grab.target = target.cast<double>();
  // The region grab: the Tools panel's stiffness (N/m) and force limit (N), the scene's radius.
  c.grab.stiffness = std::max(1e-3, double(app.tools.grab_stiffness));
  c.grab.force_limit = std::max(0.0, double(app.tools.grab_force_limit));
  c.grab.radius = std::max(0.0, double(app.tools.grab_radius));
  app.sim->push_now(c);
  if (app.status.paused) app.sim->step_once();
}

}  // namespace

void set_cut_depth(AppState& app, float depth) {
  app.tools.cut_depth = std::clamp(depth, 0.5f * app.view.voxel_size, 2.0f * app.view.radius);
}

void handle_keys(AppState& app, InputEvents& events, GLFWwindow* window) {
  for (const auto& [key, mods] : events.keys) {
    const bool ctrl = (mods & GLFW_MOD_CONTROL) != 0, shift = (mods & GLFW_MOD_SHIFT) != 0;
    // clang-format off
    switch (key) {
      case GLFW_KEY_Z: if (ctrl) request_undo(app, shift); break;
      case GLFW_KEY_Y: if (ctrl) request_undo(app, true); break;
      case GLFW_KEY_R:
      case GLFW_KEY_HOME: frame_camera(app); break;
      case GLFW_KEY_G: select_tool(app, Tool::kGrab); break;
      case GLFW_KEY_S:
      case GLFW_KEY_C: select_tool(app, Tool::kScalpel); break;
      case GLFW_KEY_EQUAL:
      case GLFW_KEY_KP_ADD: camera_zoom(app.view.camera, 0.9f, app.view.radius); break;
      case GLFW_KEY_MINUS:
      case GLFW_KEY_KP_SUBTRACT: camera_zoom(app.view.camera, 1.0f / 0.9f, app.view.radius); break;
      case GLFW_KEY_RIGHT_BRACKET: set_cut_depth(app, app.tools.cut_depth * 1.15f); break;
      case GLFW_KEY_LEFT_BRACKET: set_cut_depth(app, app.tools.cut_depth / 1.15f); break;
      case GLFW_KEY_SPACE: app.sim->set_paused(!app.status.paused); break;
      case GLFW_KEY_PERIOD: app.sim->step_once(); break;
      case GLFW_KEY_W: app.view.draw.wireframe = !app.view.draw.wireframe; break;
      case GLFW_KEY_T: app.view.show_trail = !app.view.show_trail; break;
      case GLFW_KEY_F1: app.panel.show_help = !app.panel.show_help; break;
      // F12: the view's image; shift+F12: the whole window, panel included.
      case GLFW_KEY_F12:
        (shift ? app.panel.window_screenshot_request : app.panel.screenshot_request) = default_screenshot_name();
        break;
      case GLFW_KEY_ESCAPE:
        if (shift) glfwSetWindowShouldClose(window, GLFW_TRUE);
        break;
      default: break;
    }
    // clang-format on
  }
  events.keys.clear();
}

namespace {

// The scalpel under the cursor: the entry is the deformed surface point under it (while dragging,
// the outer surface only, so the blade does not dive into the slit it opens); off the tissue the
// entry keeps its last eye distance (a drag that leaves the object stays at its depth).
void aim_scalpel(AppState& app, const Ray& ray, const Eigen::Vector2f& delta) {
  // The tissue under the cursor: the entry and the far side under it (while dragging, outer faces
  // only: see tissue_under_ray).
  TissueUnderRay tissue;
  if (app.current && app.tools.cursor_in_view) {
    tissue = tissue_under_ray(app.view.camera, ray, app.current->positions, app.current->triangles,
                              app.current->triangle_flags, app.tools.left_down, app.view.voxel_size,
                              &app.tools.pick_scratch);
  }
  app.tools.hover_hit = tissue.hit;
  if (tissue.hit) app.tools.hover = tissue.entry;
  if (app.tools.hover_hit) {
    app.tools.entry_t = app.tools.hover.t;
  } else if (!app.tools.left_down || !app.tools.drag_touched || app.tools.entry_t <= 0.0f) {
    // Nothing under the cursor, before the stroke has touched the tissue: the depth of the surface
    // nearest the cursor on screen (the blade sweeps into the tissue from the side); else the depth of
    // the object's centre. A stroke that has left the tissue keeps its depth.
    const Vec3f centre = (0.5 * (app.view.bounds.min + app.view.bounds.max)).cast<float>();
    app.tools.entry_t =
        std::max((centre - ray.origin).dot(ray.direction) - 0.5f * app.view.radius, app.view.camera.z_near);
    float nearest = 0.0f;
    if (app.current &&
        nearest_surface_depth(ray, app.current->positions, app.current->triangles, app.view.camera.z_near, nearest)) {
      app.tools.entry_t = nearest;
    }
  }
  const Vec3f entry = ray.origin + app.tools.entry_t * ray.direction;
  // The edge faces the drag's direction on screen.
  if (delta.squaredNorm() > 0.25f) {
    const Vec3f d = delta.x() * camera_right(app.view.camera) - delta.y() * camera_up(app.view.camera);
    app.tools.edge_dir = d.normalized();
  }
  // The stroke cuts what it crosses: the blade reaches at least a voxel past the far side of the
  // tissue under the cursor (a drag that leaves the tissue keeps the last reach).
  app.tools.through_depth = tissue.through;
  if (tissue.exits) app.tools.exit_hit = tissue.exit;
  if (app.tools.hover_hit) app.tools.reach_depth = std::max(app.tools.cut_depth, app.tools.through_depth);
  if (!app.tools.left_down && !app.tools.hover_hit) app.tools.reach_depth = app.tools.cut_depth;
  app.tools.blade_pose = scalpel_pose(app.view.camera, ray, entry, std::max(app.tools.cut_depth, app.tools.reach_depth),
                                      2.0 * app.view.voxel_size);
  // Off the tissue during a stroke the kept reach can end inside tissue along the blade's line (a lobe
  // swinging under it): the blade reaches through it (by at most its own length again).
  if (app.tools.left_down && !app.tools.hover_hit && app.current) {
    const BladePose& b = app.tools.blade_pose;
    app.tools.blade_pose = reach_through_along_blade(b, app.current->positions, app.current->triangles,
                                                     app.current->triangle_flags, app.view.voxel_size,
                                                     (b.b - b.a).norm(), &app.tools.pick_scratch);
  }
}

// The end of a scalpel stroke: the blade's last pose, not cutting; its cut is reported once the
// step after it has run (report_cut).
void scalpel_release(AppState& app) {
  app.tools.left_down = false;
  send_blade(app, app.tools.blade_pose, false);
  app.tools.cut_pending = true;
  app.tools.cut_release_stamp = app.tools.last_blade_stamp;
}

// The end of a grab drag: the tissue is let go (the grab's marker and line go with it).
void grab_release(AppState& app) {
  app.tools.left_down = false;
  if (app.tools.grabbing) {
    send_grab(app, GrabCommand::kRelease, Vec3f::Zero());
    app.tools.grabbing = false;
  }
}

void scalpel_mouse(AppState& app, bool left, bool free_mouse) {
  if (left && !app.tools.left_down && free_mouse && app.tools.cursor_in_view) {
    app.tools.left_down = true;
    app.tools.trail.clear();
    app.sim->keep_state();
    app.tools.cut_voxels_before = app.status.voxels_cut;
    app.tools.cut_pending = false;
    app.tools.drag_touched = app.tools.hover_hit;
    send_blade(app, app.tools.blade_pose, false);  // the cut starts here
  } else if (left && app.tools.left_down) {
    app.tools.drag_touched |= app.tools.hover_hit;
    const BladePose& p = app.tools.blade_pose;
    if (p.a != app.tools.last_sent_pose.a || p.b != app.tools.last_sent_pose.b) {
      // A fast drag: the sweep from the last pose covers the surface the cursor crossed since.
      BladePose pose = p;
      if (app.current && app.tools.drag_touched) {
        pose = cover_crossed_path(app.view.camera, app.view.viewport, app.tools.last_sent_cursor, app.tools.cursor,
                                  app.tools.last_sent_pose, p, app.current->positions, app.current->triangles,
                                  app.current->triangle_flags, app.tools.cut_depth, app.view.voxel_size,
                                  &app.tools.pick_scratch);
      }
      send_blade(app, pose, true);
    }
  } else if (!left && app.tools.left_down) {
    scalpel_release(app);
  }
}

void grab_mouse(AppState& app, bool left, bool free_mouse, const Ray& ray) {
  if (left && !app.tools.left_down && free_mouse && app.tools.cursor_in_view) {
    app.tools.left_down = true;
    SurfaceHit hit;
    if (app.current && pick_surface(ray, app.current->positions, app.current->triangles, app.current->triangle_flags, 0,
                                    app.view.camera.z_near, hit, &app.tools.pick_scratch)) {
      // The picked triangle's corner nearest the hit is the point highlighted while it moves.
      const Tri& t = app.current->triangles[hit.triangle];
      uint32_t best = t[0];
      for (uint32_t v : t) {
        if ((app.current->positions[v] - hit.point).squaredNorm() <
            (app.current->positions[best] - hit.point).squaredNorm())
          best = v;
      }
      app.sim->keep_state();
      app.tools.grabbing = true;
      app.tools.grab_vertex = best;
      app.tools.grab_anchor = app.tools.grab_target = hit.point;
      app.tools.grab_anchor_said = false;
      send_grab(app, GrabCommand::kTarget, hit.point);
    } else {
      show_message(app, "grab: no tissue under the cursor");
    }
  } else if (left && app.tools.left_down && app.tools.grabbing) {
    const Vec3f target = drag_target(app.view.camera, app.view.viewport, app.tools.cursor, app.tools.grab_anchor);
    if (target != app.tools.grab_target) {
      send_grab(app, GrabCommand::kTarget, target);
      app.tools.grab_target = target;
    }
  } else if (!left && app.tools.left_down) {
    grab_release(app);
  }
}

}  // namespace

void end_drag(AppState& app) {
  if (!app.tools.left_down) return;
  if (app.tools.tool == Tool::kScalpel) {
    scalpel_release(app);
  } else {
    grab_release(app);
  }
}

void select_tool(AppState& app, Tool tool) {
  if (tool == app.tools.tool) return;
  // Mid-drag: the drag ends as its own tool's release (a grab left pinned, or a grab's release
  // taken for the end of a scalpel stroke, were the bugs of issue 32).
  if (app.tools.left_down) {
    end_drag(app);
    app.tools.await_release = true;
  }
  app.tools.tool = tool;
}

MouseFrame handle_mouse(AppState& app, InputEvents& events, GLFWwindow* window) {
  double mx = 0, my = 0;
  glfwGetCursorPos(window, &mx, &my);
  int ww = 1, wh = 1, fw = 1, fh = 1;
  glfwGetWindowSize(window, &ww, &wh);
  glfwGetFramebufferSize(window, &fw, &fh);
  // Window coordinates -> framebuffer pixels (HiDPI) -> view pixels (right of the panel).
  const Eigen::Vector2f pixel(float(mx) * float(fw) / float(std::max(ww, 1)) - float(app.view.view_x),
                              float(my) * float(fh) / float(std::max(wh, 1)));
  const Eigen::Vector2f delta =
      app.tools.have_cursor ? Eigen::Vector2f(pixel - app.tools.cursor) : Eigen::Vector2f::Zero();
  app.tools.cursor = pixel;
  app.tools.have_cursor = true;
  app.tools.cursor_in_view =
      pixel.x() >= 0 && pixel.y() >= 0 && pixel.x() < app.view.viewport.width && pixel.y() < app.view.viewport.height;
  const ImGuiIO& io = ImGui::GetIO();
  const bool free_mouse = !io.WantCaptureMouse && app.tools.cursor_in_view;
  const bool shift =
      glfwGetKey(window, GLFW_KEY_LEFT_SHIFT) == GLFW_PRESS || glfwGetKey(window, GLFW_KEY_RIGHT_SHIFT) == GLFW_PRESS;
  const bool ctrl = glfwGetKey(window, GLFW_KEY_LEFT_CONTROL) == GLFW_PRESS ||
                    glfwGetKey(window, GLFW_KEY_RIGHT_CONTROL) == GLFW_PRESS;
  const bool left = glfwGetMouseButton(window, GLFW_MOUSE_BUTTON_LEFT) == GLFW_PRESS;
  const bool right = glfwGetMouseButton(window, GLFW_MOUSE_BUTTON_RIGHT) == GLFW_PRESS;
  const bool middle = glfwGetMouseButton(window, GLFW_MOUSE_BUTTON_MIDDLE) == GLFW_PRESS;
  // A click in the view takes the keyboard from any text field (so shortcuts work again).
  if (free_mouse && (left || right || middle) && io.WantCaptureKeyboard) ImGui::SetWindowFocus(nullptr);

  // Camera.
  if (free_mouse || app.tools.camera_drag) {
    app.tools.camera_drag = right || middle;
    if (middle || (right && shift)) {
      camera_pan(app.view.camera, app.view.viewport, delta.x(), delta.y());
    } else if (right) {
      camera_orbit(app.view.camera, delta.x(), delta.y());
    }
  }
  // Wheel: zoom, or the scalpel's depth with ctrl.
  if (events.scroll != 0.0) {
    if (ctrl) {
      set_cut_depth(app, app.tools.cut_depth * std::pow(1.15f, float(events.scroll)));
    } else {
      camera_zoom(app.view.camera, std::pow(0.9f, float(events.scroll)), app.view.radius);
    }
    events.scroll = 0.0;
  }

  return MouseFrame{pixel, delta, left, free_mouse};
}

void handle_tools(AppState& app, const MouseFrame& mouse) {
  const Ray ray = cursor_ray(app.view.camera, app.view.viewport, mouse.pixel);
  aim_scalpel(app, ray, mouse.delta);
  if (app.status.playing && !app.status.play_done) return;  // the recording drives the tools
  if (!app.status.ready) return;
  // A drag ended by a tool switch: nothing starts until the button is released.
  if (app.tools.await_release) {
    if (mouse.left) return;
    app.tools.await_release = false;
  }
  if (app.tools.tool == Tool::kScalpel) scalpel_mouse(app, mouse.left, mouse.free_mouse);
  if (app.tools.tool == Tool::kGrab) grab_mouse(app, mouse.left, mouse.free_mouse, ray);
}

void report_cut(AppState& app) {
  if (!app.tools.cut_pending || app.status.step <= app.tools.cut_release_stamp) return;
  app.tools.cut_pending = false;
  const uint64_t cut = app.status.voxels_cut - std::min(app.status.voxels_cut, app.tools.cut_voxels_before);
  char text[256];
  if (cut > 0) {
    std::snprintf(text, sizeof text, "cut %llu voxels (ctrl+z undoes it)", static_cast<unsigned long long>(cut));
  } else if (!app.tools.drag_touched) {
    std::snprintf(text, sizeof text, "the cut hit nothing: the cursor never crossed the tissue");
  } else {
    std::snprintf(text, sizeof text, "the cut hit nothing: drag across the tissue (deeper: ctrl+wheel or ])");
  }
  show_message(app, text);
  std::printf("cut: %llu voxels\n", static_cast<unsigned long long>(cut));
  std::fflush(stdout);
}

void reset_mouse_commands(AppState& app) {
  app.tools.trail.clear();
  app.tools.blade_sent = false;
  app.tools.last_blade_stamp = 0;
  app.tools.grabbing = app.tools.cut_pending = false;
  app.history.latency_probe_stamp = 0;
}

void request_undo(AppState& app, bool redo) {
  if (app.tools.left_down) return;  // not in the middle of a drag
  if (redo) {
    app.sim->redo();
  } else {
    app.sim->undo();
  }
}

}  // namespace dvx
