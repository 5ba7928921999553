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
  if (app.blade_sent && cutting != app.last_cutting) stamp = std::max(stamp, app.last_blade_stamp + 1);
  stamp = std::max(stamp, app.last_blade_stamp);
  StepCommands c;
  c.has_blade = true;
  c.blade = pose;
  c.cutting = cutting;
  app.sim->push({stamp, c});
  // Paused: each blade move runs one step, so the cut shows at once.
  if (app.status.paused) app.sim->step_once();
  app.blade_sent = true;
  app.last_cutting = cutting;
  app.last_blade_stamp = stamp;
  app.last_sent_pose = pose;
  if (cutting) {
    app.trail.push_back(pose);
    while (app.trail.size() > size_t(app.trail_length)) app.trail.pop_front();
    if (app.latency_probe_stamp == 0) {
      app.latency_probe_stamp = stamp + 1;  // the snapshot after this step shows the cut
      app.latency_probe_frame = app.frame;
      app.latency_probe_time = glfwGetTime();
    }
  }
}

void send_grab(AppState& app, GrabCommand::Kind kind, const Vec3f& target) {
  StepCommands c;
  c.grab.kind = kind;
  c.grab.target = target.cast<double>();
  c.grab.compliance = std::pow(10.0, -double(app.grab_strength));
  app.sim->push_now(c);
  if (app.status.paused) app.sim->step_once();
}

}  // namespace

void set_cut_depth(AppState& app, float depth) {
  app.cut_depth = std::clamp(depth, 0.5f * app.voxel_size, 2.0f * app.radius);
}

void handle_keys(AppState& app, InputEvents& events, GLFWwindow* window) {
  for (const auto& [key, mods] : events.keys) {
    const bool ctrl = (mods & GLFW_MOD_CONTROL) != 0, shift = (mods & GLFW_MOD_SHIFT) != 0;
    switch (key) {
      case GLFW_KEY_Z:
        if (ctrl) request_undo(app, shift);
        break;
      case GLFW_KEY_Y:
        if (ctrl) request_undo(app, true);
        break;
      case GLFW_KEY_R:
      case GLFW_KEY_HOME: frame_camera(app); break;
      case GLFW_KEY_G: select_tool(app, Tool::kGrab); break;
      case GLFW_KEY_S:
      case GLFW_KEY_C: select_tool(app, Tool::kScalpel); break;
      case GLFW_KEY_EQUAL:
      case GLFW_KEY_KP_ADD: camera_zoom(app.camera, 0.9f, app.radius); break;
      case GLFW_KEY_MINUS:
      case GLFW_KEY_KP_SUBTRACT: camera_zoom(app.camera, 1.0f / 0.9f, app.radius); break;
      case GLFW_KEY_RIGHT_BRACKET: set_cut_depth(app, app.cut_depth * 1.15f); break;
      case GLFW_KEY_LEFT_BRACKET: set_cut_depth(app, app.cut_depth / 1.15f); break;
      case GLFW_KEY_SPACE: app.sim->set_paused(!app.status.paused); break;
      case GLFW_KEY_PERIOD: app.sim->step_once(); break;
      case GLFW_KEY_W: app.draw.wireframe = !app.draw.wireframe; break;
      case GLFW_KEY_T: app.show_trail = !app.show_trail; break;
      case GLFW_KEY_F1: app.show_help = !app.show_help; break;
      case GLFW_KEY_F12:
        if (shift) {
          app.window_screenshot_request = default_screenshot_name();
        } else {
          app.screenshot_request = default_screenshot_name();
        }
        break;
      case GLFW_KEY_ESCAPE:
        if (mods & GLFW_MOD_SHIFT) glfwSetWindowShouldClose(window, GLFW_TRUE);
        break;
      default: break;
    }
  }
  events.keys.clear();
}

namespace {

// The scalpel under the cursor: the entry is the deformed surface point under it (while dragging,
// the outer surface only, so the blade does not dive into the slit it opens); off the tissue the
// entry keeps its last eye distance (a drag that leaves the object stays at its depth).
void aim_scalpel(AppState& app, const Ray& ray, const Eigen::Vector2f& delta) {
  app.hover_hit = false;
  if (app.current && app.cursor_in_view) {
    // While dragging: the outer faces the ray enters through only. Through the slit the blade opens
    // the ray crosses cut faces and then the tissue's far side from within; taking either as the
    // entry would move the blade deep behind the surface it is cutting (a gap in the incision).
    const uint8_t skip = app.left_down ? kTriangleCut : 0;
    app.hover_hit = pick_surface(ray, app.current->positions, app.current->triangles, app.current->triangle_flags, skip,
                                 app.camera.z_near, app.hover, &app.pick_scratch,
                                 app.left_down ? Facing::kEntering : Facing::kBoth);
  }
  if (app.hover_hit) {
    app.entry_t = app.hover.t;
  } else if (!app.left_down || !app.drag_touched || app.entry_t <= 0.0f) {
    // Nothing under the cursor, before the stroke has touched the tissue: the depth of the surface
    // nearest the cursor on screen (the blade sweeps into the tissue from the side); else the depth of
    // the object's centre. A stroke that has left the tissue keeps its depth.
    const Vec3f centre = (0.5 * (app.bounds.min + app.bounds.max)).cast<float>();
    app.entry_t = std::max((centre - ray.origin).dot(ray.direction) - 0.5f * app.radius, app.camera.z_near);
    float nearest = 0.0f;
    if (app.current && nearest_surface_depth(ray, app.current->positions, app.current->triangles, app.camera.z_near, nearest)) {
      app.entry_t = nearest;
    }
  }
  const Vec3f entry = ray.origin + app.entry_t * ray.direction;
  // The edge faces the drag's direction on screen.
  if (delta.squaredNorm() > 0.25f) {
    const Vec3f d = delta.x() * camera_right(app.camera) - delta.y() * camera_up(app.camera);
    app.edge_dir = d.normalized();
  }
  // The far side of the tissue under the cursor: from the entry along the blade's direction, the
  // first surface it crosses (where the blade leaves the tissue; the same faces skipped as for the
  // entry). The stroke cuts what it crosses: the blade reaches at least a voxel past it (a drag that
  // leaves the tissue keeps the last reach).
  app.through_depth = 0.0f;
  if (app.hover_hit) {
    const BladePose aim = scalpel_pose(app.camera, ray, entry, 1.0, 0.0);
    const Ray inward{entry, (aim.b - aim.a).cast<float>().normalized()};
    const uint8_t skip = app.left_down ? kTriangleCut : 0;
    if (pick_surface(inward, app.current->positions, app.current->triangles, app.current->triangle_flags, skip,
                     0.5f * app.voxel_size, app.exit_hit, &app.pick_scratch, Facing::kLeaving)) {
      app.through_depth = app.exit_hit.t + app.voxel_size;
    }
  }
  if (app.hover_hit) app.reach_depth = std::max(app.cut_depth, app.through_depth);
  if (!app.left_down && !app.hover_hit) app.reach_depth = app.cut_depth;
  app.blade_pose = scalpel_pose(app.camera, ray, entry, std::max(app.cut_depth, app.reach_depth), 2.0 * app.voxel_size);
}

// The end of a scalpel stroke: the blade's last pose, not cutting; its cut is reported once the
// step after it has run (report_cut).
void scalpel_release(AppState& app) {
  app.left_down = false;
  send_blade(app, app.blade_pose, false);
  app.cut_pending = true;
  app.cut_release_stamp = app.last_blade_stamp;
}

// The end of a grab drag: the tissue is let go (the grab's marker and line go with it).
void grab_release(AppState& app) {
  app.left_down = false;
  if (app.grabbing) {
    send_grab(app, GrabCommand::kRelease, Vec3f::Zero());
    app.grabbing = false;
  }
}

void scalpel_mouse(AppState& app, bool left, bool free_mouse) {
  if (left && !app.left_down && free_mouse && app.cursor_in_view) {
    app.left_down = true;
    app.trail.clear();
    app.sim->keep_state();
    app.cut_voxels_before = app.status.voxels_cut;
    app.cut_pending = false;
    app.drag_touched = app.hover_hit;
    send_blade(app, app.blade_pose, false);  // the cut starts here
  } else if (left && app.left_down) {
    app.drag_touched |= app.hover_hit;
    const BladePose& p = app.blade_pose;
    if (p.a != app.last_sent_pose.a || p.b != app.last_sent_pose.b) send_blade(app, p, true);
  } else if (!left && app.left_down) {
    scalpel_release(app);
  }
}

void grab_mouse(AppState& app, bool left, bool free_mouse, const Ray& ray) {
  if (left && !app.left_down && free_mouse && app.cursor_in_view) {
    app.left_down = true;
    SurfaceHit hit;
    if (app.current && pick_surface(ray, app.current->positions, app.current->triangles, app.current->triangle_flags, 0,
                                    app.camera.z_near, hit, &app.pick_scratch)) {
      // The picked triangle's corner nearest the hit is the point highlighted while it moves.
      const Tri& t = app.current->triangles[hit.triangle];
      uint32_t best = t[0];
      for (uint32_t v : t) {
        if ((app.current->positions[v] - hit.point).squaredNorm() < (app.current->positions[best] - hit.point).squaredNorm()) best = v;
      }
      app.sim->keep_state();
      app.grabbing = true;
      app.grab_vertex = best;
      app.grab_anchor = app.grab_target = hit.point;
      send_grab(app, GrabCommand::kTarget, hit.point);
    } else {
      show_message(app, "grab: no tissue under the cursor");
    }
  } else if (left && app.left_down && app.grabbing) {
    const Vec3f target = drag_target(app.camera, app.viewport, app.cursor, app.grab_anchor);
    if (target != app.grab_target) {
      send_grab(app, GrabCommand::kTarget, target);
      app.grab_target = target;
    }
  } else if (!left && app.left_down) {
    grab_release(app);
  }
}

}  // namespace

void end_drag(AppState& app) {
  if (!app.left_down) return;
  if (app.tool == Tool::kScalpel) {
    scalpel_release(app);
  } else {
    grab_release(app);
  }
}

void select_tool(AppState& app, Tool tool) {
  if (tool == app.tool) return;
  // Mid-drag: the drag ends as its own tool's release (a grab left pinned, or a grab's release
  // taken for the end of a scalpel stroke, were the bugs of issue 32).
  if (app.left_down) {
    end_drag(app);
    app.await_release = true;
  }
  app.tool = tool;
}

MouseFrame handle_mouse(AppState& app, InputEvents& events, GLFWwindow* window) {
  double mx = 0, my = 0;
  glfwGetCursorPos(window, &mx, &my);
  int ww = 1, wh = 1, fw = 1, fh = 1;
  glfwGetWindowSize(window, &ww, &wh);
  glfwGetFramebufferSize(window, &fw, &fh);
  // Window coordinates -> framebuffer pixels (HiDPI) -> view pixels (right of the panel).
  const Eigen::Vector2f pixel(float(mx) * float(fw) / float(std::max(ww, 1)) - float(app.view_x),
                              float(my) * float(fh) / float(std::max(wh, 1)));
  const Eigen::Vector2f delta = app.have_cursor ? Eigen::Vector2f(pixel - app.cursor) : Eigen::Vector2f::Zero();
  app.cursor = pixel;
  app.have_cursor = true;
  app.cursor_in_view = pixel.x() >= 0 && pixel.y() >= 0 && pixel.x() < app.viewport.width && pixel.y() < app.viewport.height;
  const ImGuiIO& io = ImGui::GetIO();
  const bool free_mouse = !io.WantCaptureMouse && app.cursor_in_view;
  const bool shift = glfwGetKey(window, GLFW_KEY_LEFT_SHIFT) == GLFW_PRESS || glfwGetKey(window, GLFW_KEY_RIGHT_SHIFT) == GLFW_PRESS;
  const bool ctrl = glfwGetKey(window, GLFW_KEY_LEFT_CONTROL) == GLFW_PRESS ||
                    glfwGetKey(window, GLFW_KEY_RIGHT_CONTROL) == GLFW_PRESS;
  const bool left = glfwGetMouseButton(window, GLFW_MOUSE_BUTTON_LEFT) == GLFW_PRESS;
  const bool right = glfwGetMouseButton(window, GLFW_MOUSE_BUTTON_RIGHT) == GLFW_PRESS;
  const bool middle = glfwGetMouseButton(window, GLFW_MOUSE_BUTTON_MIDDLE) == GLFW_PRESS;
  // A click in the view takes the keyboard from any text field (so shortcuts work again).
  if (free_mouse && (left || right || middle) && io.WantCaptureKeyboard) ImGui::SetWindowFocus(nullptr);

  // Camera.
  if (free_mouse || app.camera_drag) {
    app.camera_drag = right || middle;
    if (middle || (right && shift)) {
      camera_pan(app.camera, app.viewport, delta.x(), delta.y());
    } else if (right) {
      camera_orbit(app.camera, delta.x(), delta.y());
    }
  }
  // Wheel: zoom, or the scalpel's depth with ctrl.
  if (events.scroll != 0.0) {
    if (ctrl) {
      set_cut_depth(app, app.cut_depth * std::pow(1.15f, float(events.scroll)));
    } else {
      camera_zoom(app.camera, std::pow(0.9f, float(events.scroll)), app.radius);
    }
    events.scroll = 0.0;
  }

  return MouseFrame{pixel, delta, left, free_mouse};
}

void handle_tools(AppState& app, const MouseFrame& mouse) {
  const Ray ray = cursor_ray(app.camera, app.viewport, mouse.pixel);
  aim_scalpel(app, ray, mouse.delta);
  if (app.status.playing && !app.status.play_done) return;  // the recording drives the tools
  if (!app.status.ready) return;
  // A drag ended by a tool switch: nothing starts until the button is released.
  if (app.await_release) {
    if (mouse.left) return;
    app.await_release = false;
  }
  if (app.tool == Tool::kScalpel) scalpel_mouse(app, mouse.left, mouse.free_mouse);
  if (app.tool == Tool::kGrab) grab_mouse(app, mouse.left, mouse.free_mouse, ray);
}

void report_cut(AppState& app) {
  if (!app.cut_pending || app.status.step <= app.cut_release_stamp) return;
  app.cut_pending = false;
  const uint64_t cut = app.status.voxels_cut - std::min(app.status.voxels_cut, app.cut_voxels_before);
  char text[256];
  if (cut > 0) {
    std::snprintf(text, sizeof text, "cut %llu voxels (ctrl+z undoes it)", static_cast<unsigned long long>(cut));
  } else if (!app.drag_touched) {
    std::snprintf(text, sizeof text, "the cut hit nothing: the cursor never crossed the tissue");
  } else {
    std::snprintf(text, sizeof text, "the cut hit nothing: drag across the tissue (deeper: ctrl+wheel or ])");
  }
  show_message(app, text);
  std::printf("cut: %llu voxels\n", static_cast<unsigned long long>(cut));
  std::fflush(stdout);
}

void reset_mouse_commands(AppState& app) {
  app.trail.clear();
  app.blade_sent = false;
  app.last_blade_stamp = 0;
  app.grabbing = app.cut_pending = false;
  app.latency_probe_stamp = 0;
}

void request_undo(AppState& app, bool redo) {
  if (app.left_down) return;  // not in the middle of a drag
  if (redo) {
    app.sim->redo();
  } else {
    app.sim->undo();
  }
}

}  // namespace dvx
