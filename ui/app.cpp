#include "ui/app.h"

#include "engine/errors.h"
#include "engine/recording.h"
#include "engine/render_snapshot.h"
#include "engine/scene.h"
#include "engine/timing.h"
#include "render/camera.h"
#include "render/renderer.h"
#include "ui/app_state.h"
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

bool take_screenshot(AppState& app, const std::string& path, std::string& message) {
  std::vector<uint8_t> rgba;
  std::string error;
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
  return name;
}

namespace {

// The played recording's poses by step (for drawing the blade and its trail while playing).
void load_play_poses(AppState& app, const std::string& path) {
  app.play_poses.clear();
  try {
    const Recording r = read_recording(path);
    for (const RecordedStep& s : r.steps) {
      if (s.has_blade) app.play_poses.push_back({s.step, s.blade, s.cutting});
    }
  } catch (const std::exception&) {
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
    }
  }
}

void handle_keys(AppState& app, GLFWwindow* window) {
  for (const auto& [key, mods] : g_events.keys) {
    switch (key) {
      case GLFW_KEY_R:
      case GLFW_KEY_HOME: frame_camera(app); break;
      case GLFW_KEY_G: app.tool = Tool::kGrab; break;
      case GLFW_KEY_S:
      case GLFW_KEY_C: app.tool = Tool::kScalpel; break;
      case GLFW_KEY_EQUAL:
      case GLFW_KEY_KP_ADD: camera_zoom(app.camera, 0.9f, app.radius); break;
      case GLFW_KEY_MINUS:
      case GLFW_KEY_KP_SUBTRACT: camera_zoom(app.camera, 1.0f / 0.9f, app.radius); break;
      case GLFW_KEY_SPACE: app.sim->set_paused(!app.status.paused); break;
      case GLFW_KEY_PERIOD: app.sim->step_once(); break;
      case GLFW_KEY_W: app.draw.wireframe = !app.draw.wireframe; break;
      case GLFW_KEY_T: app.show_trail = !app.show_trail; break;
      case GLFW_KEY_D: app.blade_depth = 0.0f; break;  // back to the box entry
      case GLFW_KEY_F1: app.show_help = !app.show_help; break;
      case GLFW_KEY_F12: {
        std::string message;
        take_screenshot(app, default_screenshot_name(), message);
        app.message = message;
        std::printf("%s\n", message.c_str());
        break;
      }
      case GLFW_KEY_ESCAPE:
        if (mods & GLFW_MOD_SHIFT) glfwSetWindowShouldClose(window, GLFW_TRUE);
        break;
      default: break;
    }
  }
  g_events.keys.clear();
}

void handle_mouse(AppState& app, GLFWwindow* window) {
  double mx = 0, my = 0;
  glfwGetCursorPos(window, &mx, &my);
  int ww = 1, wh = 1;
  glfwGetWindowSize(window, &ww, &wh);
  // Window coordinates -> framebuffer pixels (HiDPI).
  const Eigen::Vector2f pixel(float(mx) * float(app.viewport.width) / float(std::max(ww, 1)),
                              float(my) * float(app.viewport.height) / float(std::max(wh, 1)));
  const Eigen::Vector2f delta = app.have_cursor ? Eigen::Vector2f(pixel - app.cursor) : Eigen::Vector2f::Zero();
  app.cursor = pixel;
  app.have_cursor = true;
  const ImGuiIO& io = ImGui::GetIO();
  const bool free_mouse = !io.WantCaptureMouse;
  const bool shift = glfwGetKey(window, GLFW_KEY_LEFT_SHIFT) == GLFW_PRESS || glfwGetKey(window, GLFW_KEY_RIGHT_SHIFT) == GLFW_PRESS;
  const bool ctrl = glfwGetKey(window, GLFW_KEY_LEFT_CONTROL) == GLFW_PRESS ||
                    glfwGetKey(window, GLFW_KEY_RIGHT_CONTROL) == GLFW_PRESS;
  const bool left = glfwGetMouseButton(window, GLFW_MOUSE_BUTTON_LEFT) == GLFW_PRESS;
  const bool right = glfwGetMouseButton(window, GLFW_MOUSE_BUTTON_RIGHT) == GLFW_PRESS;
  const bool middle = glfwGetMouseButton(window, GLFW_MOUSE_BUTTON_MIDDLE) == GLFW_PRESS;

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
    if (ctrl && app.tool == Tool::kScalpel) {
      if (app.blade_depth <= 0.0f) app.blade_depth = app.cursor_blade.depth;
      app.blade_depth = std::max(app.camera.z_near, app.blade_depth - float(g_events.scroll) * 0.03f * app.radius);
    } else {
      camera_zoom(app.camera, std::pow(0.9f, float(g_events.scroll)), app.radius);
    }
    g_events.scroll = 0.0;
  }

  app.cursor_blade = blade_from_cursor(app.camera, app.viewport, pixel, app.bounds, app.status.scene.scalpel.length,
                                       app.blade_depth);
  if (app.status.playing && !app.status.play_done) return;  // the recording drives the tools
  if (!app.status.ready) return;

  // Scalpel: left held cuts along the cursor ray.
  if (app.tool == Tool::kScalpel) {
    if (left && !app.left_down && free_mouse) {
      app.left_down = true;
      app.trail.clear();
      send_blade(app, app.cursor_blade.pose, false);  // the cut starts here
    } else if (left && app.left_down) {
      const BladePose& p = app.cursor_blade.pose;
      if (p.a != app.last_sent_pose.a || p.b != app.last_sent_pose.b) send_blade(app, p, true);
    } else if (!left && app.left_down) {
      app.left_down = false;
      send_blade(app, app.cursor_blade.pose, false);
    }
  }
  // Grab: left drag pulls the surface point under the cursor in the camera plane.
  if (app.tool == Tool::kGrab) {
    if (left && !app.left_down && free_mouse) {
      app.left_down = true;
      Vec3f picked;
      if (app.current && pick_point(app.camera, app.viewport, pixel, app.current->positions, 6.0f, picked)) {
        app.grabbing = true;
        app.grab_anchor = picked;
        StepCommands c;
        c.grab.kind = GrabCommand::kTarget;
        c.grab.target = picked.cast<double>();
        app.sim->push_now(c);
        app.grab_target = picked;
      }
    } else if (left && app.left_down && app.grabbing) {
      const Vec3f target = drag_target(app.camera, app.viewport, pixel, app.grab_anchor);
      if (target != app.grab_target) {
        StepCommands c;
        c.grab.kind = GrabCommand::kTarget;
        c.grab.target = target.cast<double>();
        app.sim->push_now(c);
        app.grab_target = target;
      }
    } else if (!left && app.left_down) {
      app.left_down = false;
      if (app.grabbing) {
        StepCommands c;
        c.grab.kind = GrabCommand::kRelease;
        app.sim->push_now(c);
        app.grabbing = false;
      }
    }
  }
}

// The blade and its trail as line segments.
void overlay_lines(AppState& app, std::vector<LineVertex>& lines) {
  lines.clear();
  const auto add = [&](const Vec3d& a, const Vec3d& b, float r, float g, float bl, float alpha) {
    lines.push_back({{float(a.x()), float(a.y()), float(a.z())}, {r, g, bl, alpha}});
    lines.push_back({{float(b.x()), float(b.y()), float(b.z())}, {r, g, bl, alpha}});
  };
  std::vector<BladePose> trail;
  BladePose blade;
  bool blade_cutting = false, have_blade = false;
  if (app.status.playing && !app.play_poses.empty() && app.current) {
    // The recorded blade at the displayed step, and its recent cutting poses.
    const uint32_t step = app.current->step;
    auto it = std::upper_bound(app.play_poses.begin(), app.play_poses.end(), step,
                               [](uint32_t s, const PlayPose& p) { return s < p.step; });
    if (it != app.play_poses.begin()) {
      const auto last = it - 1;
      blade = last->pose;
      blade_cutting = last->cutting;
      have_blade = true;
      for (auto k = last; k >= app.play_poses.begin() && int(last - k) < app.trail_length; --k) {
        if (!k->cutting) break;
        trail.insert(trail.begin(), k->pose);
        if (k == app.play_poses.begin()) break;
      }
    }
  } else if (app.tool == Tool::kScalpel && app.have_cursor) {
    blade = app.cursor_blade.pose;
    blade_cutting = app.left_down;
    have_blade = true;
    trail.assign(app.trail.begin(), app.trail.end());
  }
  if (app.show_trail && trail.size() > 1) {
    for (size_t k = 0; k + 1 < trail.size(); ++k) {
      const float alpha = 0.25f + 0.6f * float(k) / float(trail.size());
      add(trail[k].a, trail[k + 1].a, 1.0f, 0.85f, 0.3f, alpha);
      add(trail[k].b, trail[k + 1].b, 1.0f, 0.85f, 0.3f, alpha);
      if (k % 4 == 0) add(trail[k].a, trail[k].b, 1.0f, 0.85f, 0.3f, 0.35f * alpha);
    }
  }
  if (have_blade) {
    if (blade_cutting) {
      add(blade.a, blade.b, 1.0f, 0.3f, 0.25f, 1.0f);
    } else {
      add(blade.a, blade.b, 0.85f, 0.9f, 1.0f, 0.9f);
    }
  }
  if (app.grabbing) {
    const Vec3d a = app.grab_anchor.cast<double>(), b = app.grab_target.cast<double>();
    add(a, b, 0.3f, 1.0f, 0.4f, 1.0f);
  }
}

}  // namespace

int run_window(const WindowOptions& options) {
  AppState app;
  // Bad input first (exit 2 before any window opens).
  Scene scene;
  try {
    if (options.play_path.empty()) {
      scene = load_scene(options.scene_path);
    } else {
      (void)read_recording(options.play_path);  // validates it
    }
  } catch (const InputError& e) {
    std::fprintf(stderr, "divvox: error: %s\n", e.what());
    return kExitBadInput;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "divvox: internal error: %s\n", e.what());
    return kExitInternal;
  }

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
  GLFWwindow* window = glfwCreateWindow(options.width, options.height, "divvox", nullptr, nullptr);
  if (window == nullptr) {
    if (g_glfw_error_code == GLFW_VERSION_UNAVAILABLE || g_glfw_error_code == GLFW_API_UNAVAILABLE) {
      std::fprintf(stderr, "divvox: error: the display offers no OpenGL 4.5 core context (%s); use 'divvox replay REC --headless'\n",
                   g_glfw_error.c_str());
    } else {
      no_display_error();
    }
    glfwTerminate();
    return kExitBadInput;
  }
  glfwMakeContextCurrent(window);
  glfwSwapInterval(1);
  if (gladLoadGL(reinterpret_cast<GLADloadfunc>(glfwGetProcAddress)) == 0) {
    std::fprintf(stderr, "divvox: error: cannot load OpenGL 4.5 entry points\n");
    glfwDestroyWindow(window);
    glfwTerminate();
    return kExitInternal;
  }
  const std::string gl_renderer = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
  int fb_w = 0, fb_h = 0;
  glfwGetFramebufferSize(window, &fb_w, &fb_h);
  fb_w = std::max(fb_w, 16);
  fb_h = std::max(fb_h, 16);
  // MSAA on a GPU; none on a software rasteriser (llvmpipe), where it costs a lot.
  const int samples = gl_renderer.find("llvmpipe") != std::string::npos || gl_renderer.find("softpipe") != std::string::npos ? 0 : 4;
  Renderer renderer;
  std::string error;
  if (!renderer_init(renderer, fb_w, fb_h, error, samples)) {
    std::fprintf(stderr, "divvox: error: renderer: %s\n", error.c_str());
    glfwDestroyWindow(window);
    glfwTerminate();
    return kExitInternal;
  }
  LineOverlay overlay;
  if (!overlay_init(overlay, error)) std::fprintf(stderr, "divvox: warning: %s (no blade overlay)\n", error.c_str());

  glfwSetScrollCallback(window, on_scroll);
  glfwSetKeyCallback(window, on_key);
  IMGUI_CHECKVERSION();
  ImGui::CreateContext();
  ImGui::GetIO().IniFilename = nullptr;
  ImGui::StyleColorsDark();
  ImGui_ImplGlfw_InitForOpenGL(window, true);  // chains the callbacks above
  ImGui_ImplOpenGL3_Init("#version 330 core");

  SimRunner sim;
  app.sim = &sim;
  app.renderer = &renderer;
  app.gl_renderer = gl_renderer;
  app.viewport = {fb_w, fb_h};
  app.window_options = options;
  std::snprintf(app.record_path, sizeof app.record_path, "%s",
                options.record_path.empty() ? "divvox_recording.jsonl" : options.record_path.c_str());
  if (!options.play_path.empty()) {
    std::snprintf(app.play_path, sizeof app.play_path, "%s", options.play_path.c_str());
    load_play_poses(app, options.play_path);
    try {
      sim.play(options.play_path);
    } catch (const InputError& e) {
      std::fprintf(stderr, "divvox: error: %s\n", e.what());
      return kExitBadInput;
    }
  } else {
    sim.open(scene, scene.solver.dt, options.record_path);
  }
  std::snprintf(app.scene_path, sizeof app.scene_path, "%s", options.scene_path.c_str());

  int exit_code = kExitOk;
  uint64_t generation = 0, last_sequence = 0;
  uint64_t counted_frames = 0;
  std::vector<Vec3f> normals;
  std::vector<LineVertex> lines;
  Clock::time_point last_frame = Clock::now(), first_counted;
  std::vector<double> render_ms_all, interval_ms_all;
  while (!glfwWindowShouldClose(window)) {
    glfwPollEvents();
    app.status = sim.status();
    // Initial scene failed to open: nothing to show.
    if (!app.status.ready && !app.status.loading && !app.status.error.empty()) {
      exit_code = kExitBadInput;
      break;
    }
    if (app.status.generation != generation && app.status.ready) {
      generation = app.status.generation;
      app.bounds = app.status.bounds;
      app.edit = scene_edit_of(app.status.scene);
      frame_camera(app);
      app.trail.clear();
      app.blade_sent = false;
      app.last_blade_stamp = 0;
      app.left_down = app.grabbing = false;
      app.latency_probe_stamp = 0;
      if (app.status.playing) load_play_poses(app, app.status.play_path);
    }
    // Window resize: a new offscreen target.
    glfwGetFramebufferSize(window, &fb_w, &fb_h);
    if (fb_w >= 16 && fb_h >= 16 && (fb_w != renderer.width || fb_h != renderer.height)) {
      if (renderer_resize(renderer, fb_w, fb_h, error)) app.viewport = {fb_w, fb_h};
    }

    ImGui_ImplOpenGL3_NewFrame();
    ImGui_ImplGlfw_NewFrame();
    ImGui::NewFrame();
    handle_keys(app, window);
    handle_mouse(app, window);

    // The newest snapshot: upload what changed.
    const Clock::time_point t0 = Clock::now();
    if (const Snapshot* s = sim.exchange().take()) {
      app.current = s;
      upload_snapshot(renderer, *s, s->sequence != last_sequence + 1 || s->sequence == sim.generation_first_sequence(),
                      normals);
      last_sequence = s->sequence;
      app.triangles = 0;
      for (const Tri& t : s->triangles) app.triangles += t[0] != kDeadIndex ? 1 : 0;
      if (app.latency_probe_stamp != 0 && s->step + 1 >= app.latency_probe_stamp) {
        app.latency_frames.push_back(double(app.frame - app.latency_probe_frame));
        if (app.latency_frames.size() > 120) app.latency_frames.erase(app.latency_frames.begin());
        app.latency_probe_stamp = 0;
      }
    }
    const Clock::time_point t1 = Clock::now();
    renderer_draw(renderer, app.camera, app.draw);
    overlay_lines(app, lines);
    overlay_draw(overlay, renderer.resolve_framebuffer, renderer.width, renderer.height, app.camera, lines);
    renderer_blit(renderer, 0, fb_w, fb_h);
    const Clock::time_point t2 = Clock::now();

    draw_panels(app);
    ImGui::Render();
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    glViewport(0, 0, fb_w, fb_h);
    ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());
    const Clock::time_point t3 = Clock::now();
    glfwSwapBuffers(window);
    const Clock::time_point t4 = Clock::now();

    // Frame statistics.
    const double render_ms = ms_between(t0, t3), interval = ms_between(last_frame, t4);
    last_frame = t4;
    app.push_frame(ms_between(t0, t1), ms_between(t1, t2), render_ms, interval);
    ++app.frame;
    if (app.status.ready && app.current != nullptr) {
      if (counted_frames == 0) first_counted = t4;
      ++counted_frames;
      render_ms_all.push_back(render_ms);
      if (counted_frames > 1) interval_ms_all.push_back(interval);
    }
    if (options.exit_after_frames > 0 && counted_frames >= uint64_t(options.exit_after_frames)) {
      const bool playing = app.status.playing && !sim.play_done();
      if (!playing) break;
    }
  }

  // The last frame as a PNG.
  if (!options.screenshot_path.empty() && exit_code == kExitOk) {
    std::string message;
    if (take_screenshot(app, options.screenshot_path, message)) {
      std::printf("%s\n", message.c_str());
    } else {
      std::fprintf(stderr, "divvox: error: %s\n", message.c_str());
      exit_code = kExitBadInput;
    }
  }
  if (counted_frames > 1) {
    std::sort(render_ms_all.begin(), render_ms_all.end());
    const double seconds = std::chrono::duration<double>(last_frame - first_counted).count();
    double latency = 0.0;
    for (double l : app.latency_frames) latency += l;
    std::printf("window: %llu frames in %.2f s (%.1f fps), render ms p50 %.2f p99 %.2f, %u steps, %s\n",
                static_cast<unsigned long long>(counted_frames), seconds,
                seconds > 0 ? double(counted_frames - 1) / seconds : 0.0,
                render_ms_all[render_ms_all.size() / 2], render_ms_all[std::min(render_ms_all.size() - 1, size_t(0.99 * render_ms_all.size()))],
                app.status.step, gl_renderer.c_str());
    if (!app.latency_frames.empty()) {
      std::printf("input to cut latency: %.2f frames mean over %zu cuts\n", latency / double(app.latency_frames.size()),
                  app.latency_frames.size());
    }
  }
  const SimStatus final_status = sim.status();
  if (final_status.playing && final_status.hash_mismatched > 0) {
    std::fprintf(stderr, "divvox: error: %s: the window's simulation diverged from the recording (%u of %u hashes differ)\n",
                 final_status.play_path.c_str(), final_status.hash_mismatched, final_status.hash_checked);
    exit_code = kExitInternal;
  }
  std::fflush(stdout);

  sim.stop();
  ImGui_ImplOpenGL3_Shutdown();
  ImGui_ImplGlfw_Shutdown();
  ImGui::DestroyContext();
  overlay_destroy(overlay);
  renderer_destroy(renderer);
  glfwDestroyWindow(window);
  glfwTerminate();
  return exit_code;
}

}  // namespace dvx
