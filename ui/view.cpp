#include "ui/view.h"

#include "engine/render_snapshot.h"
#include "render/normals.h"
#include "ui/input.h"

#include <glad/gl.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#include <imgui.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>

namespace dvx {

namespace {

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
  app.history.last_coverage = coverage(rgba, app.view.draw.background);
  char text[512];
  std::snprintf(text, sizeof text, "wrote screenshot %s (%dx%d, object coverage %.1f %%)", path.c_str(),
                app.renderer->width, app.renderer->height, 100.0 * app.history.last_coverage);
  message = text;
  return true;
}

bool take_window_screenshot(int fb_w, int fb_h, const std::string& path, std::string& message) {
  // The window's back buffer as drawn so far (call it after the panels, before the swap).
  std::vector<uint8_t> rgba(size_t(fb_w) * size_t(fb_h) * 4);
  glBindFramebuffer(GL_READ_FRAMEBUFFER, 0);
  glReadBuffer(GL_BACK);
  glPixelStorei(GL_PACK_ALIGNMENT, 1);
  glReadPixels(0, 0, fb_w, fb_h, GL_RGBA, GL_UNSIGNED_BYTE, rgba.data());
  // GL's rows start at the bottom; the PNG's at the top.
  const size_t row = size_t(fb_w) * 4;
  for (int y = 0; y < fb_h / 2; ++y) {
    std::swap_ranges(rgba.begin() + ptrdiff_t(size_t(y) * row), rgba.begin() + ptrdiff_t(size_t(y + 1) * row),
                     rgba.begin() + ptrdiff_t(size_t(fb_h - 1 - y) * row));
  }
  const std::filesystem::path parent = std::filesystem::path(path).parent_path();
  std::error_code ec;
  if (!parent.empty()) std::filesystem::create_directories(parent, ec);
  std::string error;
  if (!write_png(path, fb_w, fb_h, rgba, error)) {
    message = error;
    return false;
  }
  message = "wrote window screenshot " + path + " (" + std::to_string(fb_w) + "x" + std::to_string(fb_h) +
            ", panel included)";
  return true;
}

std::string default_screenshot_name() {
  const std::time_t now = std::time(nullptr);
  char name[64];
  std::strftime(name, sizeof name, "divvox_%Y%m%d_%H%M%S.png", std::localtime(&now));
  return default_output_path(name);
}

// The scene's contact planes as trays: centred under the object, a little wider than it.
void set_trays(AppState& app) {
  app.view.draw.trays.clear();
  for (const ContactPlane& p : app.status.scene.pbd.planes) {
    app.view.draw.trays.push_back(tray_under(app.view.bounds.min.cast<float>(), app.view.bounds.max.cast<float>(),
                                             p.point.cast<float>(), p.normal.cast<float>()));
  }
}

void frame_camera(AppState& app) {
  app.view.camera = frame_box(app.view.bounds, app.view.viewport.aspect());
  app.view.radius = float(0.5 * app.view.bounds.extent().norm());
}

namespace {

void add_line(std::vector<LineVertex>& lines, const Vec3d& a, const Vec3d& b, const Eigen::Vector4f& c) {
  lines.push_back({{float(a.x()), float(a.y()), float(a.z())}, {c.x(), c.y(), c.z(), c.w()}});
  lines.push_back({{float(b.x()), float(b.y()), float(b.z())}, {c.x(), c.y(), c.z(), c.w()}});
}

// The blade to draw: the recording's at the displayed step while playing, else the mouse's.
bool blade_to_draw(AppState& app, BladePose& blade, bool& cutting, std::vector<BladePose>& trail) {
  trail.clear();
  if (app.status.playing && !app.view.play_poses.empty() && app.current) {
    const uint32_t step = app.current->step;
    auto it = std::upper_bound(app.view.play_poses.begin(), app.view.play_poses.end(), step,
                               [](uint32_t s, const PlayPose& p) { return s < p.step; });
    if (it == app.view.play_poses.begin()) return false;
    const auto last = it - 1;
    blade = last->pose;
    cutting = last->cutting;
    for (auto k = last; k >= app.view.play_poses.begin() && int(last - k) < app.view.trail_length; --k) {
      if (!k->cutting) break;
      trail.insert(trail.begin(), k->pose);
      if (k == app.view.play_poses.begin()) break;
    }
    return true;
  }
  if (app.tools.tool != Tool::kScalpel || !app.tools.cursor_in_view) return false;
  blade = app.tools.blade_pose;
  cutting = app.tools.left_down;
  trail.assign(app.tools.trail.begin(), app.tools.trail.end());
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
    if (app.view.show_trail && trail.size() > 1) {
      for (size_t k = 0; k + 1 < trail.size(); ++k) {
        const float alpha = 0.25f + 0.6f * float(k) / float(trail.size());
        add_line(lines, trail[k].b, trail[k + 1].b, Eigen::Vector4f(1.0f, 0.85f, 0.3f, alpha));
      }
    }
    ScalpelStyle style;
    style.blade_width = std::max(0.05f * app.view.radius, 2.0f * app.view.voxel_size);
    style.handle_length = 0.35f * app.view.radius;
    if (cutting) style.edge_color = Vec3f(1.0f, 0.35f, 0.3f);
    // The steel shows a quarter of the depth above the entry (drawn only: the cutting edge is a..b).
    const Vec3f a = blade.a.cast<float>(), b = blade.b.cast<float>();
    scalpel_mesh(a - 0.25f * (b - a), b, app.tools.edge_dir, style, solids);
    // The entry mark: a ring in the view plane where the blade meets the surface.
    if (app.tools.hover_hit && !app.status.playing) {
      const Vec3f c = app.tools.hover.point, r = camera_right(app.view.camera), u = camera_up(app.view.camera);
      const float radius = 0.012f * app.tools.hover.t;
      const Eigen::Vector4f colour =
          cutting ? Eigen::Vector4f(1.0f, 0.35f, 0.3f, 1.0f) : Eigen::Vector4f(0.4f, 0.95f, 1.0f, 1.0f);
      for (int k = 0; k < 16; ++k) {
        const float a0 = float(k) * 0.3926991f, a1 = float(k + 1) * 0.3926991f;
        add_line(lines, (c + radius * (std::cos(a0) * r + std::sin(a0) * u)).cast<double>(),
                 (c + radius * (std::cos(a1) * r + std::sin(a1) * u)).cast<double>(), colour);
      }
    }
  }
  // Anchored tissue: a small steel-blue pin on each anchored particle (they never move), seen through
  // the surface as ghosts where the tissue covers them.
  if (app.view.show_anchors) {
    const float pin = 0.35f * std::max(app.view.voxel_size * 4.0f, 0.004f * app.view.radius);
    for (const Vec3f& p : app.status.anchors) marker_mesh(p, pin, Vec3f(0.35f, 0.55f, 1.0f), solids);
  }
  if (app.tools.grabbing && app.current && app.tools.grab_vertex < app.current->positions.size()) {
    const Vec3f p = app.current->positions[app.tools.grab_vertex];
    if (p.allFinite()) {
      marker_mesh(p, 0.03f * app.view.radius, Vec3f(0.3f, 1.0f, 0.45f), solids);
      add_line(lines, p.cast<double>(), app.tools.grab_target.cast<double>(), Eigen::Vector4f(0.3f, 1.0f, 0.45f, 1.0f));
      marker_mesh(app.tools.grab_target, 0.015f * app.view.radius, Vec3f(1.0f, 1.0f, 1.0f), solids);
    }
  }
}

}  // namespace

// The depth next to the cursor while aiming (ImGui's foreground layer, so it is never hidden).
void cursor_label(AppState& app) {
  char text[96];
  // The grab: its force in newtons beside the cursor while it pulls (or that an anchor holds it).
  if (app.tools.tool == Tool::kGrab && app.tools.grabbing && app.status.grab_on && !app.status.playing) {
    const SimStatus& s = app.status;
    if (s.grab_held == 0 && s.grab_anchored > 0) {
      std::snprintf(text, sizeof text, "held by an anchor");
    } else {
      std::snprintf(text, sizeof text, "%.1f N", s.grab_force_n.empty() ? 0.0 : double(s.grab_force_n.back()));
    }
    const ImVec2 at(float(app.view.view_x) + app.tools.cursor.x() + 18.0f, app.tools.cursor.y() + 12.0f);
    ImGui::GetForegroundDrawList()->AddText(at, IM_COL32(200, 255, 210, 240), text);
    return;
  }
  if (app.tools.tool != Tool::kScalpel || !app.tools.cursor_in_view || app.status.playing) return;
  if (app.tools.hover_hit || app.tools.left_down) {
    if (app.tools.reach_depth > app.tools.cut_depth) {
      std::snprintf(text, sizeof text, "depth %.2f (through %.2f)", app.tools.cut_depth, app.tools.reach_depth);
    } else {
      std::snprintf(text, sizeof text, "depth %.2f", app.tools.cut_depth);
    }
  } else {
    std::snprintf(text, sizeof text, "no tissue here");
  }
  const ImVec2 at(float(app.view.view_x) + app.tools.cursor.x() + 18.0f, app.tools.cursor.y() + 12.0f);
  ImGui::GetForegroundDrawList()->AddText(at, IM_COL32(230, 240, 255, 230), text);
}

namespace {

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
  return a.sequence == b.sequence && a.width == b.width && a.height == b.height && a.x == b.x && p.target == q.target &&
         p.distance == q.distance && p.yaw == q.yaw && p.pitch == q.pitch && p.fov_y == q.fov_y &&
         p.z_near == q.z_near && p.z_far == q.z_far && o.wireframe == u.wireframe && o.shadows == u.shadows &&
         o.cull_back_faces == u.cull_back_faces && o.vertex_lighting == u.vertex_lighting && o.surface_color == u.surface_color && o.cut_color == u.cut_color &&
         o.wire_color == u.wire_color && o.background == u.background && o.tray_color == u.tray_color &&
         o.shadow_alpha == u.shadow_alpha && same_trays(o.trays, u.trays);
}

}  // namespace

// The 3D view right of the docked panel, for a framebuffer size.
void layout_view(AppState& app, int fb_w, int fb_h) {
  app.view.panel_width = panel_width_for(fb_w);
  app.view.view_x = app.view.panel_width;
  app.view.viewport = {std::max(fb_w - app.view.view_x, 16), fb_h};
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
  app.history.triangles = 0;
  for (const Tri& t : s->triangles) app.history.triangles += t[0] != kDeadIndex ? 1 : 0;
  // The probed cut is in this snapshot: counted once it shows (record_latency).
  if (app.history.latency_probe_stamp != 0 && s->step + 1 >= app.history.latency_probe_stamp) {
    w.latency_hit = true;
    w.latency_hit_frame = app.history.latency_probe_frame;  // a new probe may start before it shows
    w.latency_hit_time = app.history.latency_probe_time;
    app.history.latency_probe_stamp = 0;
  }
  return s->normals_ms;
}

// The window's back buffer, in direct and scene-cache modes: all of it cleared at once (colour and
// depth: on a software rasteriser a clear of a part draws a quad), then the panel's strip in the
// panel's colour (so ImGui draws no background of its own: a blended quad as large as the panel).
// With the scene cache (`view_covered`: its copy covers the view) all of it in the panel's colour at
// once, and no depth: nothing drawn over the cache uses the window's depth buffer (the scene's depth
// is a texture, the solids drawn over it go far to near: solid_overlay_draw), and on llvmpipe its
// clear cost the rasteriser's threads 2.5 ms a frame (the colour's next to nothing).
void clear_window(AppState& app, int fb_w, int fb_h, bool view_covered) {
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
  glViewport(0, 0, fb_w, fb_h);
  glDisable(GL_SCISSOR_TEST);
  glDepthMask(GL_TRUE);
  glColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
  const ImVec4 panel = ImGui::GetStyleColorVec4(ImGuiCol_WindowBg);
  const Vec3f& background = app.view.draw.background;
  if (view_covered) {
    glClearColor(panel.x, panel.y, panel.z, 1.0f);
  } else {
    glClearColor(background.x(), background.y(), background.z(), 1.0f);
  }
  glClearDepth(1.0);
  glClear(view_covered ? GL_COLOR_BUFFER_BIT : GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
  if (view_covered) return;
  glEnable(GL_SCISSOR_TEST);
  glScissor(0, 0, std::min(app.view.view_x, fb_w), fb_h);
  glClearColor(panel.x, panel.y, panel.z, 1.0f);
  glClear(GL_COLOR_BUFFER_BIT);
  glDisable(GL_SCISSOR_TEST);
}

// The view's surface (into the back buffer in direct mode, else into the offscreen target, which
// the renderer clears), handed to the rasteriser at once (glFlush), so that on a software
// rasteriser it rasterises while this thread picks, builds the tray's shadow and the panels.
void draw_surface(AppState& app, WindowContext& w) {
  app.view.draw.clear = !w.renderer.direct;
  renderer_draw_surface(w.renderer, app.view.camera, app.view.draw);
  glFlush();
}

namespace {

// What the scene cache's image shows: the snapshot, the camera, the view's size and every drawing
// option (the tray's shadow follows the snapshot and the camera).
SceneKey scene_key_of(const AppState& app, const WindowContext& w) {
  SceneKey k;
  k.sequence = app.current ? app.current->sequence : 0;
  k.camera = app.view.camera;
  k.width = w.renderer.width;
  k.height = w.renderer.height;
  k.x = app.view.view_x;
  k.options = app.view.draw;
  return k;
}

}  // namespace

// The trays, with the surface's shadow: rebuilt only when the snapshot, the camera's orientation
// (the light follows it) or the shadow switch changed (while cutting, most frames show the
// snapshot of the frame before).
void draw_trays(AppState& app, WindowContext& w) {
  if (app.current != nullptr && app.view.draw.shadows &&
      (w.shadow_sequence != app.current->sequence || w.shadow_yaw != app.view.camera.yaw ||
       w.shadow_pitch != app.view.camera.pitch || !w.renderer.shadow_valid)) {
    shadow_casters(*app.current, w.shadow_positions);  // only vertices of live triangles
    tray_shadow_update(w.renderer, w.shadow_positions.data(), uint32_t(w.shadow_positions.size()), app.view.camera,
                       app.view.draw);
    w.shadow_sequence = app.current->sequence;
    w.shadow_yaw = app.view.camera.yaw;
    w.shadow_pitch = app.view.camera.pitch;
  }
  if (w.renderer.triangle_count > 0) tray_draw(w.renderer, app.view.camera, app.view.draw);
}

// The scalpel, its entry mark and trail, the grabbed point, over the scene.
void draw_overlays(AppState& app, WindowContext& w) {
  overlay_geometry(app, w.lines, w.solids);
  const ViewTarget target = renderer_target(w.renderer);
  solid_overlay_draw(w.solid_overlay, target, app.view.camera, w.solids);
  overlay_draw(w.overlay, target, app.view.camera, w.lines);
}

// The input-to-cut latency of a probed cut whose snapshot this frame showed (with split frames, the
// frame that finished its image).
void record_latency(AppState& app, WindowContext& w) {
  if (!w.latency_hit || w.split_pending) return;
  w.latency_hit = false;
  app.history.latency_frames.push_back(double(app.history.frame - w.latency_hit_frame));
  app.history.latency_ms.push_back(1e3 * (glfwGetTime() - w.latency_hit_time));
  if (app.history.latency_frames.size() > 120) app.history.latency_frames.erase(app.history.latency_frames.begin());
  if (app.history.latency_ms.size() > 120) app.history.latency_ms.erase(app.history.latency_ms.begin());
}

namespace {

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

}  // namespace

// The 3D view: the back buffer cleared (direct and scene-cache modes), the scene (or part of it:
// scene_draw_for) drawn, the tools aimed while it rasterises, the cached image copied into the back
// buffer. Returns what it drew.
SceneDraw draw_view(AppState& app, WindowContext& w, int fb_w, int fb_h, const MouseFrame& mouse) {
  const bool window = w.renderer.direct || w.cache_scene;
  app.view.panel_cleared = window;
  if (window) clear_window(app, fb_w, fb_h, w.cache_scene);
  const SceneKey key = scene_key_of(app, w);
  const SceneDraw d = scene_draw_for(w, key);
  const int half = (app.view.draw.surface_pieces + 1) / 2;
  app.view.draw.pieces_begin = d == SceneDraw::kSecondHalf ? half : 0;
  app.view.draw.pieces_end = d == SceneDraw::kFirstHalf ? half : 64;
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

}  // namespace dvx
