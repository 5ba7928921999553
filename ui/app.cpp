#include "ui/app.h"

#include "engine/errors.h"
#include "engine/options.h"
#include "engine/playback.h"
#include "engine/render_snapshot.h"
#include "engine/scene.h"
#include "engine/stats.h"
#include "engine/timing.h"
#include "render/camera.h"
#include "render/normals.h"
#include "render/renderer.h"
#include "ui/app_state.h"
#include "ui/frame_stats.h"
#include "ui/input.h"
#include "ui/overlay.h"
#include "ui/sim_runner.h"

#include <glad/gl.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#include <backends/imgui_impl_glfw.h>
#include <backends/imgui_impl_opengl3.h>
#include <imgui.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <limits>
#include <thread>
#include <unistd.h>

namespace dvx {
namespace {

std::string g_glfw_error;
int g_glfw_error_code = 0;
void on_glfw_error(int code, const char* message) {
  g_glfw_error_code = code;
  g_glfw_error = message ? message : "";
}

// Input events gathered by the GLFW callbacks (ImGui chains its own after these).
struct Events {
  double scroll = 0.0;
  std::vector<std::pair<int, int>> keys;  // (key, mods) presses
};
Events g_events;

void on_scroll(GLFWwindow*, double, double dy) {
  if (ImGui::GetCurrentContext() && ImGui::GetIO().WantCaptureMouse) return;
  g_events.scroll += dy;
}
void on_key(GLFWwindow*, int key, int, int action, int mods) {
  if (action != GLFW_PRESS && action != GLFW_REPEAT) return;
  if (ImGui::GetCurrentContext() && ImGui::GetIO().WantCaptureKeyboard) return;
  g_events.keys.emplace_back(key, mods);
}

void no_display_error() {
  std::fprintf(stderr,
               "divvox: error: no display (DISPLAY is not set or the X server refused); use 'divvox replay REC "
               "--headless'\n");
}

// Fraction of the image that is not background.
double coverage(const std::vector<uint8_t>& rgba, const Vec3f& background) {
  const int br = int(std::lround(background.x() * 255)), bg = int(std::lround(background.y() * 255)),
            bb = int(std::lround(background.z() * 255));
  size_t covered = 0, pixels = rgba.size() / 4;
  for (size_t i = 0; i < pixels; ++i) {
    const int d = std::abs(rgba[4 * i] - br) + std::abs(rgba[4 * i + 1] - bg) + std::abs(rgba[4 * i + 2] - bb);
    covered += d > 12 ? 1 : 0;
  }
  return pixels ? double(covered) / double(pixels) : 0.0;
}

}  // namespace

std::string default_output_path(const std::string& name) {
  std::error_code ec;
  std::filesystem::create_directories(kWindowOutputDir, ec);
  return (std::filesystem::path(kWindowOutputDir) / name).string();
}

bool take_screenshot(AppState& app, const std::string& path, std::string& message) {
  std::vector<uint8_t> rgba;
  std::string error;
  const std::filesystem::path parent = std::filesystem::path(path).parent_path();
  std::error_code ec;
  if (!parent.empty()) std::filesystem::create_directories(parent, ec);
  if (!renderer_read_pixels(*app.renderer, rgba)) {
    message = "screenshot: cannot read the frame back";
    return false;
  }
  if (!write_png(path, app.renderer->width, app.renderer->height, rgba, error)) {
    message = error;
    return false;
  }
  app.last_coverage = coverage(rgba, app.draw.background);
  char text[512];
  std::snprintf(text, sizeof text, "wrote screenshot %s (%dx%d, object coverage %.1f %%)", path.c_str(),
                app.renderer->width, app.renderer->height, 100.0 * app.last_coverage);
  message = text;
  return true;
}

std::string default_screenshot_name() {
  const std::time_t now = std::time(nullptr);
  char name[64];
  std::strftime(name, sizeof name, "divvox_%Y%m%d_%H%M%S.png", std::localtime(&now));
  return default_output_path(name);
}

namespace {

// The played recording's poses by step (for drawing the blade and its trail while playing), from the
// playback the simulation thread runs (read once).
void load_play_poses(AppState& app, const Playback& playback) {
  app.play_poses.clear();
  for (const PlaybackStep& s : playback.steps) {
    if (s.commands.has_blade) app.play_poses.push_back({s.step, s.commands.blade, s.commands.cutting});
  }
}

// The scene's contact planes as trays: centred under the object, a little wider than it.
void set_trays(AppState& app) {
  app.draw.trays.clear();
  for (const ContactPlane& p : app.status.scene.pbd.planes) {
    app.draw.trays.push_back(tray_under(app.bounds.min.cast<float>(), app.bounds.max.cast<float>(),
                                        p.point.cast<float>(), p.normal.cast<float>()));
  }
}

void frame_camera(AppState& app) {
  app.camera = frame_box(app.bounds, app.viewport.aspect());
  app.radius = float(0.5 * app.bounds.extent().norm());
}

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

void set_cut_depth(AppState& app, float depth) {
  app.cut_depth = std::clamp(depth, 0.5f * app.voxel_size, 2.0f * app.radius);
}

void handle_keys(AppState& app, GLFWwindow* window) {
  for (const auto& [key, mods] : g_events.keys) {
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
      case GLFW_KEY_G: app.tool = Tool::kGrab; break;
      case GLFW_KEY_S:
      case GLFW_KEY_C: app.tool = Tool::kScalpel; break;
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
      case GLFW_KEY_F12: app.screenshot_request = default_screenshot_name(); break;
      case GLFW_KEY_ESCAPE:
        if (mods & GLFW_MOD_SHIFT) glfwSetWindowShouldClose(window, GLFW_TRUE);
        break;
      default: break;
    }
  }
  g_events.keys.clear();
}

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
    app.left_down = false;
    send_blade(app, app.blade_pose, false);
    app.cut_pending = true;
    app.cut_release_stamp = app.last_blade_stamp;
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
    app.left_down = false;
    if (app.grabbing) {
      send_grab(app, GrabCommand::kRelease, Vec3f::Zero());
      app.grabbing = false;
    }
  }
}

// The mouse's state for a frame, read before the scene is drawn (the camera moves first) and used
// after it is handed to the rasteriser (picking and the tools: handle_tools).
struct MouseFrame {
  Eigen::Vector2f pixel = Eigen::Vector2f::Zero(), delta = Eigen::Vector2f::Zero();
  bool left = false, free_mouse = false;
};

MouseFrame handle_mouse(AppState& app, GLFWwindow* window) {
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
  if (g_events.scroll != 0.0) {
    if (ctrl) {
      set_cut_depth(app, app.cut_depth * std::pow(1.15f, float(g_events.scroll)));
    } else {
      camera_zoom(app.camera, std::pow(0.9f, float(g_events.scroll)), app.radius);
    }
    g_events.scroll = 0.0;
  }

  return MouseFrame{pixel, delta, left, free_mouse};
}

// The scalpel aimed at the surface under the cursor, and the tools' commands.
void handle_tools(AppState& app, const MouseFrame& mouse) {
  const Ray ray = cursor_ray(app.camera, app.viewport, mouse.pixel);
  aim_scalpel(app, ray, mouse.delta);
  if (app.status.playing && !app.status.play_done) return;  // the recording drives the tools
  if (!app.status.ready) return;
  if (app.tool == Tool::kScalpel) scalpel_mouse(app, mouse.left, mouse.free_mouse);
  if (app.tool == Tool::kGrab) grab_mouse(app, mouse.left, mouse.free_mouse, ray);
}

// A finished drag says what it cut, once its last step has run.
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

void add_line(std::vector<LineVertex>& lines, const Vec3d& a, const Vec3d& b, const Eigen::Vector4f& c) {
  lines.push_back({{float(a.x()), float(a.y()), float(a.z())}, {c.x(), c.y(), c.z(), c.w()}});
  lines.push_back({{float(b.x()), float(b.y()), float(b.z())}, {c.x(), c.y(), c.z(), c.w()}});
}

// The blade to draw: the recording's at the displayed step while playing, else the mouse's.
bool blade_to_draw(AppState& app, BladePose& blade, bool& cutting, std::vector<BladePose>& trail) {
  trail.clear();
  if (app.status.playing && !app.play_poses.empty() && app.current) {
    const uint32_t step = app.current->step;
    auto it = std::upper_bound(app.play_poses.begin(), app.play_poses.end(), step,
                               [](uint32_t s, const PlayPose& p) { return s < p.step; });
    if (it == app.play_poses.begin()) return false;
    const auto last = it - 1;
    blade = last->pose;
    cutting = last->cutting;
    for (auto k = last; k >= app.play_poses.begin() && int(last - k) < app.trail_length; --k) {
      if (!k->cutting) break;
      trail.insert(trail.begin(), k->pose);
      if (k == app.play_poses.begin()) break;
    }
    return true;
  }
  if (app.tool != Tool::kScalpel || !app.cursor_in_view) return false;
  blade = app.blade_pose;
  cutting = app.left_down;
  trail.assign(app.trail.begin(), app.trail.end());
  return true;
}

// The overlays: the scalpel (solid), its entry mark and trail, the grabbed point and its pull.
void overlay_geometry(AppState& app, std::vector<LineVertex>& lines, std::vector<SolidVertex>& solids) {
  lines.clear();
  solids.clear();
  std::vector<BladePose> trail;
  BladePose blade;
  bool cutting = false;
  if (blade_to_draw(app, blade, cutting, trail)) {
    if (app.show_trail && trail.size() > 1) {
      for (size_t k = 0; k + 1 < trail.size(); ++k) {
        const float alpha = 0.25f + 0.6f * float(k) / float(trail.size());
        add_line(lines, trail[k].b, trail[k + 1].b, Eigen::Vector4f(1.0f, 0.85f, 0.3f, alpha));
      }
    }
    ScalpelStyle style;
    style.blade_width = std::max(0.05f * app.radius, 2.0f * app.voxel_size);
    style.handle_length = 0.35f * app.radius;
    if (cutting) style.edge_color = Vec3f(1.0f, 0.35f, 0.3f);
    // The steel shows a quarter of the depth above the entry (drawn only: the cutting edge is a..b).
    const Vec3f a = blade.a.cast<float>(), b = blade.b.cast<float>();
    scalpel_mesh(a - 0.25f * (b - a), b, app.edge_dir, style, solids);
    // The entry mark: a ring in the view plane where the blade meets the surface.
    if (app.hover_hit && !app.status.playing) {
      const Vec3f c = app.hover.point, r = camera_right(app.camera), u = camera_up(app.camera);
      const float radius = 0.012f * app.hover.t;
      const Eigen::Vector4f colour = cutting ? Eigen::Vector4f(1.0f, 0.35f, 0.3f, 1.0f) : Eigen::Vector4f(0.4f, 0.95f, 1.0f, 1.0f);
      for (int k = 0; k < 16; ++k) {
        const float a0 = float(k) * 0.3926991f, a1 = float(k + 1) * 0.3926991f;
        add_line(lines, (c + radius * (std::cos(a0) * r + std::sin(a0) * u)).cast<double>(),
                 (c + radius * (std::cos(a1) * r + std::sin(a1) * u)).cast<double>(), colour);
      }
    }
  }
  if (app.grabbing && app.current && app.grab_vertex < app.current->positions.size()) {
    const Vec3f p = app.current->positions[app.grab_vertex];
    if (p.allFinite()) {
      marker_mesh(p, 0.03f * app.radius, Vec3f(0.3f, 1.0f, 0.45f), solids);
      add_line(lines, p.cast<double>(), app.grab_target.cast<double>(), Eigen::Vector4f(0.3f, 1.0f, 0.45f, 1.0f));
      marker_mesh(app.grab_target, 0.015f * app.radius, Vec3f(1.0f, 1.0f, 1.0f), solids);
    }
  }
}

// The depth next to the cursor while aiming (ImGui's foreground layer, so it is never hidden).
void cursor_label(AppState& app) {
  if (app.tool != Tool::kScalpel || !app.cursor_in_view || app.status.playing) return;
  char text[96];
  if (app.hover_hit || app.left_down) {
    if (app.reach_depth > app.cut_depth) {
      std::snprintf(text, sizeof text, "depth %.2f (through %.2f)", app.cut_depth, app.reach_depth);
    } else {
      std::snprintf(text, sizeof text, "depth %.2f", app.cut_depth);
    }
  } else {
    std::snprintf(text, sizeof text, "no tissue here");
  }
  const ImVec2 at(float(app.view_x) + app.cursor.x() + 18.0f, app.cursor.y() + 12.0f);
  ImGui::GetForegroundDrawList()->AddText(at, IM_COL32(230, 240, 255, 230), text);
}

// The mouse's commands start afresh (a new session, or an undo / redo: stamps from the new step).
void reset_mouse_commands(AppState& app) {
  app.trail.clear();
  app.blade_sent = false;
  app.last_blade_stamp = 0;
  app.grabbing = app.cut_pending = false;
  app.latency_probe_stamp = 0;
}

// Follows the simulation's status each frame: a new session reframes the camera and resets the
// tools; undo / redo and their notes; messages expire; a finished drag reports what it cut.
void follow_simulation(AppState& app, uint64_t& generation) {
  if (app.status.generation != generation && app.status.ready) {
    generation = app.status.generation;
    app.bounds = app.status.bounds;
    app.edit = scene_edit_of(app.status.scene);
    frame_camera(app);
    set_trays(app);
    app.voxel_size = float(app.bounds.extent().maxCoeff() / std::max(app.status.scene.pbd.resolution, 1));
    app.cut_depth = float(app.status.scene.scalpel.length);
    set_cut_depth(app, app.cut_depth);
    app.cut_pending = false;
    app.restores_seen = app.status.restores;
    std::printf("window: ready (%s, panel %d px, view %dx%d)\n", app.status.scene.file.c_str(), app.panel_width,
                app.viewport.width, app.viewport.height);
    std::fflush(stdout);
    app.undo_notes_seen = app.status.undo_notes;
    reset_mouse_commands(app);
    app.left_down = false;
    if (app.status.playing && app.status.playback) load_play_poses(app, *app.status.playback);
  }
  // An undo or redo ran: the mouse's stamps start again from the restored step.
  if (app.status.restores != app.restores_seen) {
    app.restores_seen = app.status.restores;
    reset_mouse_commands(app);
  }
  if (app.status.undo_notes != app.undo_notes_seen) {
    app.undo_notes_seen = app.status.undo_notes;
    show_message(app, app.status.undo_note, 4.0);
  }
  if (app.message_until > 0.0 && glfwGetTime() > app.message_until) {
    app.message.clear();
    app.message_until = 0.0;
  }
  report_cut(app);
}

}  // namespace

void show_message(AppState& app, const std::string& text, double seconds) {
  app.message = text;
  app.message_until = seconds > 0 ? glfwGetTime() + seconds : 0.0;
}

void request_undo(AppState& app, bool redo) {
  if (app.left_down) return;  // not in the middle of a drag
  if (redo) {
    app.sim->redo();
  } else {
    app.sim->undo();
  }
}

namespace {

// What a drawn view shows (scene_key_of): equal keys, equal images.
struct SceneKey {
  uint64_t sequence = 0;
  Camera camera;
  int width = 0, height = 0, x = 0;
  DrawOptions options;
};

bool same_trays(const std::vector<TrayPlane>& a, const std::vector<TrayPlane>& b) {
  if (a.size() != b.size()) return false;
  for (size_t k = 0; k < a.size(); ++k) {
    if (a[k].centre != b[k].centre || a[k].normal != b[k].normal || a[k].half_size != b[k].half_size) return false;
  }
  return true;
}

bool operator==(const SceneKey& a, const SceneKey& b) {
  const Camera &p = a.camera, &q = b.camera;
  const DrawOptions &o = a.options, &u = b.options;
  return a.sequence == b.sequence && a.width == b.width && a.height == b.height && a.x == b.x &&
         p.target == q.target && p.distance == q.distance && p.yaw == q.yaw && p.pitch == q.pitch &&
         p.fov_y == q.fov_y && p.z_near == q.z_near && p.z_far == q.z_far && o.wireframe == u.wireframe &&
         o.shadows == u.shadows && o.cull_back_faces == u.cull_back_faces && o.surface_color == u.surface_color &&
         o.cut_color == u.cut_color && o.wire_color == u.wire_color && o.background == u.background &&
         o.tray_color == u.tray_color && o.shadow_alpha == u.shadow_alpha && same_trays(o.trays, u.trays);
}

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
  // Double-buffered cache (DIVVOX_SPLIT_FRAMES=0: off): a new snapshot is drawn over two frames
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
};

// Reads the scene or the recording before any window opens (bad input: exit 2 at once).
// Returns -1 when both are fine, else the exit code.
int load_window_input(const WindowOptions& options, Scene& scene, std::shared_ptr<const Playback>& playback) {
  try {
    if (options.play_path.empty()) {
      scene = load_scene(options.scene_path);
    } else {
      playback = std::make_shared<const Playback>(load_playback(options.play_path));  // read once, validated
      for (const std::string& w : playback->warnings) std::fprintf(stderr, "divvox: warning: %s\n", w.c_str());
    }
  } catch (const InputError& e) {
    std::fprintf(stderr, "divvox: error: %s\n", e.what());
    return kExitBadInput;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "divvox: internal error: %s\n", e.what());
    return kExitInternal;
  }
  return -1;
}

// The GLFW window with a current GL 4.5 core context and its entry points loaded. Returns -1, or
// the exit code after a one-line error (no display, no GL 4.5).
int open_gl_window(const WindowOptions& options, WindowContext& w) {
  glfwSetErrorCallback(on_glfw_error);
  const char* display = std::getenv("DISPLAY");
  const char* wayland = std::getenv("WAYLAND_DISPLAY");
  if ((display == nullptr || *display == 0) && (wayland == nullptr || *wayland == 0)) {
    no_display_error();
    return kExitBadInput;
  }
  if (!glfwInit()) {
    no_display_error();
    return kExitBadInput;
  }
  glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 4);
  glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 5);
  glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
  glfwWindowHint(GLFW_DEPTH_BITS, 24);  // the view is drawn straight into the back buffer (renderer: direct)
  w.window = glfwCreateWindow(options.width, options.height, "divvox", nullptr, nullptr);
  if (w.window == nullptr) {
    if (g_glfw_error_code == GLFW_VERSION_UNAVAILABLE || g_glfw_error_code == GLFW_API_UNAVAILABLE) {
      std::fprintf(stderr, "divvox: error: the display offers no OpenGL 4.5 core context (%s); use 'divvox replay REC --headless'\n",
                   g_glfw_error.c_str());
    } else {
      no_display_error();
    }
    glfwTerminate();
    return kExitBadInput;
  }
  glfwMakeContextCurrent(w.window);
  glfwSwapInterval(1);
  if (gladLoadGL(reinterpret_cast<GLADloadfunc>(glfwGetProcAddress)) == 0) {
    std::fprintf(stderr, "divvox: error: cannot load OpenGL 4.5 entry points\n");
    glfwDestroyWindow(w.window);
    glfwTerminate();
    return kExitInternal;
  }
  w.gl_renderer = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
  w.software = w.gl_renderer.find("llvmpipe") != std::string::npos || w.gl_renderer.find("softpipe") != std::string::npos;
  return -1;
}

// The 3D view right of the docked panel, for a framebuffer size.
void layout_view(AppState& app, int fb_w, int fb_h) {
  app.panel_width = panel_width_for(fb_w);
  app.view_x = app.panel_width;
  app.viewport = {std::max(fb_w - app.view_x, 16), fb_h};
}

// Renderer, overlays and ImGui. False after a one-line error (the window is closed then).
bool init_graphics(AppState& app, WindowContext& w) {
  int fb_w = 0, fb_h = 0;
  glfwGetFramebufferSize(w.window, &fb_w, &fb_h);
  layout_view(app, std::max(fb_w, 16), std::max(fb_h, 16));
  // 4x MSAA on a GPU; none on a software rasteriser (llvmpipe), where 2x or 4x triples the
  // rasteriser's CPU time per frame (28 -> 79 ms at 896x720 on the bunny at 128). Without it, the
  // scene cache (WindowContext::cache_scene; DIVVOX_SCENE_CACHE=0: off), or else the view drawn
  // straight into the window's back buffer (no offscreen image to copy, but a full redraw per frame).
  const EnvOptions env = read_env_options();
  const int samples = env.msaa >= 0 ? env.msaa : w.software ? 0 : 4;
  w.cache_scene = samples == 0 && env.scene_cache;
  std::string error;
  if (!renderer_init(w.renderer, app.viewport.width, app.viewport.height, error, samples,
                     samples == 0 && !w.cache_scene)) {
    std::fprintf(stderr, "divvox: error: renderer: %s\n", error.c_str());
    glfwDestroyWindow(w.window);
    glfwTerminate();
    return false;
  }
  renderer_place(w.renderer, app.view_x, 0);
  if (w.cache_scene && w.software && env.split_frames) {
    w.split_frames = renderer_double_buffer(w.renderer, error);
    if (!w.split_frames && !error.empty()) {
      std::fprintf(stderr, "divvox: error: renderer: %s\n", error.c_str());
      glfwDestroyWindow(w.window);
      glfwTerminate();
      return false;
    }
  }
  if (!overlay_init(w.overlay, error)) std::fprintf(stderr, "divvox: warning: %s (no blade overlay)\n", error.c_str());
  if (!solid_overlay_init(w.solid_overlay, error)) std::fprintf(stderr, "divvox: warning: %s (no scalpel)\n", error.c_str());
  glfwSetScrollCallback(w.window, on_scroll);
  glfwSetKeyCallback(w.window, on_key);
  IMGUI_CHECKVERSION();
  ImGui::CreateContext();
  ImGui::GetIO().IniFilename = nullptr;
  ImGui::StyleColorsDark();
  ImGui_ImplGlfw_InitForOpenGL(w.window, true);  // chains the callbacks above
  ImGui_ImplOpenGL3_Init("#version 330 core");
  // DIVVOX_FRAME_PROFILE=1: glFinish after each phase, so the phase times are the GPU's too (costs
  // some pipelining; for measuring only).
  w.profile = env.frame_profile;
  w.stats.profiled = w.profile;
  w.stats.gl_renderer = w.gl_renderer;
  w.stats.scene_cache = w.cache_scene;
  // Normals on the GPU, except on a software rasteriser (there its compute passes run on the same
  // CPU cores, ~40x slower than the plain loop, which then runs on the simulation thread, once per
  // snapshot the renderer takes); DIVVOX_GPU_NORMALS=0/1 overrides.
  w.gpu_normals = env.gpu_normals >= 0 ? env.gpu_normals == 1 : !w.software;
  w.sim.set_cpu_normals(!w.gpu_normals);
  w.stats.normals_where = w.gpu_normals ? "GPU passes on the render thread" : "CPU, on the simulation thread";
  app.sim = &w.sim;
  app.renderer = &w.renderer;
  app.gl_renderer = w.gl_renderer;
  app.draw.cull_back_faces = true;
  app.draw.surface_pieces = w.software ? 4 : 1;  // DrawOptions::surface_pieces
  // DIVVOX_SHADOWS=0: start with the tray's shadow off (View panel: "shadow on the tray").
  if (env.shadows >= 0) app.draw.shadows = env.shadows == 1;
  return true;
}

// The newest snapshot to the renderer (what changed since the last one, its normals as the
// simulation thread computed them, else the GPU's), the input-to-cut latency probe. Returns the
// normals' time (ms, on the simulation thread) of the snapshot taken, or -1 when none was new.
double take_snapshot(AppState& app, WindowContext& w) {
  const Snapshot* s = w.sim.take();
  if (s == nullptr) return -1.0;
  app.current = s;
  const bool full = s->sequence != w.last_sequence + 1 || s->sequence == w.sim.generation_first_sequence();
  RenderMesh mesh = snapshot_render_mesh(*s, full);
  const bool have_normals = s->normals.size() == s->positions.size() && s->cut_normals.size() == s->positions.size();
  if (have_normals && !w.gpu_normals) {
    mesh.normals = s->normals.data();
    mesh.cut_normals = s->cut_normals.data();
  } else {
    mesh.gpu_normals = true;
  }
  renderer_upload(w.renderer, mesh);
  w.last_sequence = s->sequence;
  app.triangles = 0;
  for (const Tri& t : s->triangles) app.triangles += t[0] != kDeadIndex ? 1 : 0;
  // The probed cut is in this snapshot: counted once it shows (record_latency).
  if (app.latency_probe_stamp != 0 && s->step + 1 >= app.latency_probe_stamp) {
    w.latency_hit = true;
    w.latency_hit_frame = app.latency_probe_frame;  // a new probe may start before it shows
    w.latency_hit_time = app.latency_probe_time;
    app.latency_probe_stamp = 0;
  }
  return s->normals_ms;
}

// The window's back buffer, in direct and scene-cache modes: all of it cleared at once (colour and
// depth: on a software rasteriser a full clear is nearly free, a clear of a part draws a quad),
// then the panel's strip in the panel's colour (so ImGui draws no background of its own: a blended
// quad as large as the panel). With the scene cache (`view_covered`: its copy covers the view) all
// of it in the panel's colour at once.
void clear_window(AppState& app, int fb_w, int fb_h, bool view_covered) {
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
  glViewport(0, 0, fb_w, fb_h);
  glDisable(GL_SCISSOR_TEST);
  glDepthMask(GL_TRUE);
  glColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
  const ImVec4 panel = ImGui::GetStyleColorVec4(ImGuiCol_WindowBg);
  const Vec3f& background = app.draw.background;
  if (view_covered) {
    glClearColor(panel.x, panel.y, panel.z, 1.0f);
  } else {
    glClearColor(background.x(), background.y(), background.z(), 1.0f);
  }
  glClearDepth(1.0);
  glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
  if (view_covered) return;
  glEnable(GL_SCISSOR_TEST);
  glScissor(0, 0, std::min(app.view_x, fb_w), fb_h);
  glClearColor(panel.x, panel.y, panel.z, 1.0f);
  glClear(GL_COLOR_BUFFER_BIT);
  glDisable(GL_SCISSOR_TEST);
}

// The view's surface (into the back buffer in direct mode, else into the offscreen target, which
// the renderer clears), handed to the rasteriser at once (glFlush), so that on a software
// rasteriser it rasterises while this thread picks, builds the tray's shadow and the panels.
void draw_surface(AppState& app, WindowContext& w) {
  app.draw.clear = !w.renderer.direct;
  renderer_draw_surface(w.renderer, app.camera, app.draw);
  glFlush();
}

// What the scene cache's image shows: the snapshot, the camera, the view's size and every drawing
// option (the tray's shadow follows the snapshot and the camera).
SceneKey scene_key_of(const AppState& app, const WindowContext& w) {
  SceneKey k;
  k.sequence = app.current ? app.current->sequence : 0;
  k.camera = app.camera;
  k.width = w.renderer.width;
  k.height = w.renderer.height;
  k.x = app.view_x;
  k.options = app.draw;
  return k;
}

// The trays, with the surface's shadow: rebuilt only when the snapshot, the camera's orientation
// (the light follows it) or the shadow switch changed (while cutting, most frames show the
// snapshot of the frame before).
void draw_trays(AppState& app, WindowContext& w) {
  if (app.current != nullptr && app.draw.shadows &&
      (w.shadow_sequence != app.current->sequence || w.shadow_yaw != app.camera.yaw ||
       w.shadow_pitch != app.camera.pitch || !w.renderer.shadow_valid)) {
    shadow_casters(*app.current, w.shadow_positions);  // only vertices of live triangles
    tray_shadow_update(w.renderer, w.shadow_positions.data(), uint32_t(w.shadow_positions.size()), app.camera, app.draw);
    w.shadow_sequence = app.current->sequence;
    w.shadow_yaw = app.camera.yaw;
    w.shadow_pitch = app.camera.pitch;
  }
  if (w.renderer.triangle_count > 0) tray_draw(w.renderer, app.camera, app.draw);
}

// The scalpel, its entry mark and trail, the grabbed point, over the scene.
void draw_overlays(AppState& app, WindowContext& w) {
  overlay_geometry(app, w.lines, w.solids);
  const ViewTarget target = renderer_target(w.renderer);
  solid_overlay_draw(w.solid_overlay, target, app.camera, w.solids);
  overlay_draw(w.overlay, target, app.camera, w.lines);
}

// The input-to-cut latency of a probed cut whose snapshot this frame showed (with split frames, the
// frame that finished its image).
void record_latency(AppState& app, WindowContext& w) {
  if (!w.latency_hit || w.split_pending) return;
  w.latency_hit = false;
  app.latency_frames.push_back(double(app.frame - w.latency_hit_frame));
  app.latency_ms.push_back(1e3 * (glfwGetTime() - w.latency_hit_time));
  if (app.latency_frames.size() > 120) app.latency_frames.erase(app.latency_frames.begin());
  if (app.latency_ms.size() > 120) app.latency_ms.erase(app.latency_ms.begin());
}

// What this frame draws: with the scene cache, nothing while the cached image still shows the scene;
// a new snapshot seen from the same camera (while cutting) spread over two frames when
// double-buffered (the first half of the outer surface and the trays, then the rest and the cut faces),
// each frame presenting the last whole image, so no single frame pays for a whole redraw; anything
// else (a camera move, a changed option) drawn whole at once.
SceneDraw scene_draw_for(const WindowContext& w, const SceneKey& key) {
  if (!w.cache_scene) return SceneDraw::kWhole;
  if (w.split_pending) return key == w.pending_key ? SceneDraw::kSecondHalf : SceneDraw::kWhole;
  if (w.scene_valid && key == w.scene_key) return SceneDraw::kNone;
  SceneKey same_view = key;
  same_view.sequence = w.scene_key.sequence;
  return w.split_frames && w.scene_valid && same_view == w.scene_key ? SceneDraw::kFirstHalf : SceneDraw::kWhole;
}

// The 3D view: the back buffer cleared (direct and scene-cache modes), the scene (or part of it:
// scene_draw_for) drawn, the tools aimed while it rasterises, the cached image copied into the back
// buffer. Returns what it drew.
SceneDraw draw_view(AppState& app, WindowContext& w, int fb_w, int fb_h, const MouseFrame& mouse) {
  const bool window = w.renderer.direct || w.cache_scene;
  app.panel_cleared = window;
  if (window) clear_window(app, fb_w, fb_h, w.cache_scene);
  const SceneKey key = scene_key_of(app, w);
  const SceneDraw d = scene_draw_for(w, key);
  const int half = (app.draw.surface_pieces + 1) / 2;
  app.draw.pieces_begin = d == SceneDraw::kSecondHalf ? half : 0;
  app.draw.pieces_end = d == SceneDraw::kFirstHalf ? half : 64;
  if (d != SceneDraw::kNone) draw_surface(app, w);
  handle_tools(app, mouse);  // picks on the snapshot shown while the surface rasterises
  // The trays with the first half (the halves cost alike then; behind the second half's triangles
  // the tray is shaded and then overdrawn, a cheap shader).
  const bool complete = d == SceneDraw::kWhole || d == SceneDraw::kSecondHalf;
  if (d == SceneDraw::kWhole || d == SceneDraw::kFirstHalf) draw_trays(app, w);
  if (w.cache_scene) {
    if (complete) {
      renderer_show_drawn(w.renderer);  // double-buffered: the new image is the one shown
      w.scene_valid = true;
      w.scene_key = key;
    }
    w.split_pending = d == SceneDraw::kFirstHalf;
    if (w.split_pending) w.pending_key = key;
    renderer_present(w.renderer);
  }
  return d;
}

// AppState::sim_rate from the steps run in the last half second (a new session or an undo, which
// moves the step back, restarts the measurement).
void update_sim_rate(AppState& app) {
  const double now = glfwGetTime();
  if (app.rate_time < 0.0 || app.status.step < app.rate_step || app.status.paused || !app.status.ready) {
    app.rate_time = now;
    app.rate_step = app.status.step;
    if (app.status.paused || !app.status.ready) app.sim_rate = 1.0;
    return;
  }
  if (now - app.rate_time < 0.5) return;
  app.sim_rate = double(app.status.step - app.rate_step) * app.status.dt / (now - app.rate_time);
  app.rate_time = now;
  app.rate_step = app.status.step;
}

// One frame: input, the snapshot, the scene (only when something it shows changed), overlays,
// panels, swap; its phase times into the statistics.
void run_frame(AppState& app, WindowContext& w) {
  glfwPollEvents();
  app.status = w.sim.status();
  follow_simulation(app, w.generation);
  update_sim_rate(app);
  // Window resize: a new panel width and offscreen target.
  int fb_w = 0, fb_h = 0;
  glfwGetFramebufferSize(w.window, &fb_w, &fb_h);
  if (fb_w >= 16 && fb_h >= 16) {
    const Viewport before = app.viewport;
    layout_view(app, fb_w, fb_h);
    renderer_place(w.renderer, app.view_x, 0);
    std::string error;
    if ((app.viewport.width != w.renderer.width || app.viewport.height != w.renderer.height) &&
        !renderer_resize(w.renderer, app.viewport.width, app.viewport.height, error)) {
      app.viewport = before;
    }
  }
  ImGui_ImplOpenGL3_NewFrame();
  ImGui_ImplGlfw_NewFrame();
  ImGui::NewFrame();
  handle_keys(app, w.window);
  const MouseFrame mouse = handle_mouse(app, w.window);

  const Clock::time_point t0 = Clock::now();
  const Eigen::Vector2f cursor_before = w.last_cursor;
  w.last_cursor = app.cursor;
  // Half of a snapshot's image drawn: the same snapshot until the rest is.
  const double normals_ms = w.split_pending ? -1.0 : take_snapshot(app, w);
  w.idle = normals_ms < 0.0 && !w.split_pending && app.status.ready && app.status.paused && !app.left_down && !app.camera_drag &&
           cursor_before == app.cursor && app.message.empty();
  if (w.profile) glFinish();
  const Clock::time_point t1 = Clock::now();
  renderer_update_normals(w.renderer);  // GPU normals (a no-op when they came with the snapshot)
  if (w.profile) glFinish();
  const Clock::time_point t1n = Clock::now();
  const SceneDraw drawn = draw_view(app, w, fb_w, fb_h, mouse);
  record_latency(app, w);
  if (w.profile) glFinish();
  const Clock::time_point t1d = Clock::now();
  draw_overlays(app, w);
  // Multisampled (a GPU): the offscreen image, overlays included, into the window (direct mode and
  // the scene cache: nothing to copy).
  if (!w.cache_scene) renderer_blit(w.renderer, 0, w.renderer.width, w.renderer.height, app.view_x, 0);
  if (!app.screenshot_request.empty()) {
    std::string message;
    take_screenshot(app, app.screenshot_request, message);
    show_message(app, message);
    std::printf("%s\n", message.c_str());
    app.screenshot_request.clear();
  }
  w.sim.frame_done();  // the next snapshot may go out now
  if (w.profile) glFinish();
  const Clock::time_point t2 = Clock::now();

  cursor_label(app);
  draw_panels(app);
  ImGui::Render();
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
  glViewport(0, 0, fb_w, fb_h);
  ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());
  if (w.profile) glFinish();
  const Clock::time_point t3 = Clock::now();
  glfwSwapBuffers(w.window);
  const Clock::time_point t4 = Clock::now();

  // Frame statistics (normals: the simulation thread's time for the snapshot shown, or the GPU passes).
  const double render_ms = ms_between(t0, t3), interval = ms_between(w.last_frame, t4);
  w.last_frame = t4;
  app.push_frame(ms_between(t0, t1), ms_between(t1, t2), render_ms, interval);
  ++app.frame;
  if (app.status.ready && app.current != nullptr) {
    const double normals = w.gpu_normals ? ms_between(t1, t1n) : std::max(normals_ms, 0.0);
    if (normals_ms >= 0.0) AppState::push(app.normals_ms, normals);
    const double phases[6] = {ms_between(t0, t1), normals, ms_between(t1n, t1d), ms_between(t1d, t2), ms_between(t2, t3),
                              ms_between(t3, t4)};
    w.stats.add(app, phases, render_ms, interval, t4, normals_ms >= 0.0, drawn);
  }
}

// After the loop: the --screenshot PNG, the statistics, the replay check; then everything closed.
int finish_window(AppState& app, WindowContext& w, const WindowOptions& options, int exit_code) {
  if (!options.screenshot_path.empty() && exit_code == kExitOk) {
    // Direct mode: the last frame is gone with its swap; drawn again.
    if (w.renderer.direct || w.cache_scene) {
      int fb_w = 0, fb_h = 0;
      glfwGetFramebufferSize(w.window, &fb_w, &fb_h);
      clear_window(app, fb_w, fb_h, w.cache_scene);
      if (!w.cache_scene || !w.scene_valid || w.split_pending) {
        app.draw.pieces_begin = 0;
        app.draw.pieces_end = 64;
        draw_surface(app, w);
        draw_trays(app, w);
        renderer_show_drawn(w.renderer);
        w.split_pending = false;
      }
      renderer_present(w.renderer);  // direct mode: nothing to copy
      draw_overlays(app, w);
    }
    std::string message;
    if (take_screenshot(app, options.screenshot_path, message)) {
      std::printf("%s\n", message.c_str());
    } else {
      std::fprintf(stderr, "divvox: error: %s\n", message.c_str());
      exit_code = kExitBadInput;
    }
  }
  w.stats.print(app);
  std::printf("window: layout panel %d px (drawn %.0f px), view %dx%d\n", app.panel_width, app.panel_drawn_width,
              app.viewport.width, app.viewport.height);
  const SimStatus final_status = w.sim.status();
  if (final_status.playing && final_status.hash_mismatched > 0) {
    std::fprintf(stderr, "divvox: error: %s: the window's simulation diverged from the recording (%u of %u hashes differ)\n",
                 final_status.play_path.c_str(), final_status.hash_mismatched, final_status.hash_checked);
    exit_code = kExitInternal;
  }
  std::fflush(stdout);
  w.sim.stop();
  ImGui_ImplOpenGL3_Shutdown();
  ImGui_ImplGlfw_Shutdown();
  ImGui::DestroyContext();
  overlay_destroy(w.overlay);
  overlay_destroy(w.solid_overlay);
  renderer_destroy(w.renderer);
  glfwDestroyWindow(w.window);
  glfwTerminate();
  return exit_code;
}

}  // namespace

int run_window(const WindowOptions& options) {
  Scene scene;
  std::shared_ptr<const Playback> playback;
  if (const int code = load_window_input(options, scene, playback); code >= 0) return code;
  AppState app;
  WindowContext w;
  if (const int code = open_gl_window(options, w); code >= 0) return code;
  if (!init_graphics(app, w)) return kExitInternal;
  app.window_options = options;
  std::snprintf(app.record_path, sizeof app.record_path, "%s",
                options.record_path.empty() ? default_output_path("divvox_recording.jsonl").c_str()
                                            : options.record_path.c_str());
  if (playback) {
    std::snprintf(app.play_path, sizeof app.play_path, "%s", options.play_path.c_str());
    w.sim.play(playback);
  } else {
    w.sim.open(scene, scene.pbd.dt, options.record_path);
  }
  std::snprintf(app.scene_path, sizeof app.scene_path, "%s", options.scene_path.c_str());

  // Frame pacing: at most DIVVOX_MAX_FPS frames a second (default 60; 0: unpaced). Without a vsync
  // (Xvfb) a frame that reuses the scene cache takes a few ms, and every frame shown costs this
  // thread the copy and the panels and the X server a copy of the window: the time a faster frame
  // rate would spend goes to the simulation thread instead.
  const double max_fps = read_env_options().max_fps;
  Clock::time_point frame_start = Clock::now();
  int exit_code = kExitOk;
  while (!glfwWindowShouldClose(w.window)) {
    // Paused with nothing new on the last frame: wait for input (up to 50 ms) instead of redrawing
    // the same image at full speed (on a software rasteriser that is two busy cores for nothing).
    if (w.idle) glfwWaitEventsTimeout(0.05);
    if (max_fps > 0.0) {
      const Clock::time_point next = frame_start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / max_fps));
      if (Clock::now() < next) std::this_thread::sleep_until(next);
    }
    frame_start = Clock::now();
    run_frame(app, w);
    // The initial scene failed to open: nothing to show.
    if (!app.status.ready && !app.status.loading && !app.status.error.empty()) {
      exit_code = kExitBadInput;
      break;
    }
    if (options.exit_after_frames > 0 && w.stats.counted_frames >= uint64_t(options.exit_after_frames)) {
      const bool playing = app.status.playing && !w.sim.play_done();
      if (!playing) break;
    }
  }
  return finish_window(app, w, options, exit_code);
}

}  // namespace dvx
