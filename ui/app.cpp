// The window: GLFW, the GL context, ImGui, the frame loop and its end (the view: ui/view.cpp; the
// tools: ui/tools.cpp; the panels: ui/panels.cpp; the frame statistics: ui/frame_stats.cpp).
#include "ui/app.h"

#include "engine/errors.h"
#include "engine/options.h"
#include "engine/playback.h"
#include "engine/scene.h"
#include "engine/timing.h"
#include "ui/app_state.h"
#include "ui/frame_stats.h"
#include "ui/tools.h"
#include "ui/view.h"

#include <glad/gl.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#include <backends/imgui_impl_glfw.h>
#include <backends/imgui_impl_opengl3.h>
#include <imgui.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <thread>

namespace dvx {
namespace {

std::string g_glfw_error;
int g_glfw_error_code = 0;
void on_glfw_error(int code, const char* message) {
  g_glfw_error_code = code;
  g_glfw_error = message ? message : "";
}

// Input events gathered by the GLFW callbacks (ImGui chains its own after these).
InputEvents g_events;

void on_scroll(GLFWwindow*, double, double dy) {
  if (ImGui::GetCurrentContext() && ImGui::GetIO().WantCaptureMouse) return;
  g_events.scroll += dy;
}
void on_key(GLFWwindow*, int key, int, int action, int mods) {
  if (action != GLFW_PRESS && action != GLFW_REPEAT) return;
  if (ImGui::GetCurrentContext() && ImGui::GetIO().WantCaptureKeyboard) return;
  g_events.keys.emplace_back(key, mods);
}

// SIGTERM and SIGINT end the window as a close does (statistics printed, exit 0): the handler only
// sets this flag (lock-free, so safe in a handler); the frame loop polls it.
std::atomic<int> g_quit_signal{0};
void on_quit_signal(int signal_number) { g_quit_signal.store(signal_number); }

void install_quit_handlers() {
  struct sigaction action = {};
  action.sa_handler = on_quit_signal;
  sigemptyset(&action.sa_mask);
  action.sa_flags = SA_RESTART;
  sigaction(SIGTERM, &action, nullptr);
  sigaction(SIGINT, &action, nullptr);
}

void no_display_error() {
  std::fprintf(stderr,
               "divvox: error: no display (DISPLAY is not set or the X server refused); use 'divvox replay REC "
               "--headless'\n");
}

// The played recording's poses by step (for drawing the blade and its trail while playing), from the
// playback the simulation thread runs (read once).
void load_play_poses(AppState& app, const Playback& playback) {
  app.view.play_poses.clear();
  for (const PlaybackStep& s : playback.steps) {
    if (s.commands.has_blade) app.view.play_poses.push_back({s.step, s.commands.blade, s.commands.cutting});
  }
}

// Follows the simulation's status each frame: a new session reframes the camera and resets the
// tools; undo / redo and their notes; messages expire; a finished drag reports what it cut.
void follow_simulation(AppState& app, uint64_t& generation) {
  if (app.status.generation != generation && app.status.ready) {
    generation = app.status.generation;
    app.view.bounds = app.status.bounds;
    app.panel.edit = scene_edit_of(app.status.scene);
    frame_camera(app);
    set_trays(app);
    app.view.voxel_size = float(app.view.bounds.extent().maxCoeff() / std::max(app.status.scene.pbd.resolution, 1));
    app.tools.cut_depth = float(app.status.scene.scalpel.length);
    app.tools.grab_stiffness = float(app.status.scene.grab.stiffness);
    app.tools.grab_force_limit = float(app.status.scene.grab.force_limit);
    app.tools.grab_radius = float(app.status.scene.grab.radius);
    set_cut_depth(app, app.tools.cut_depth);
    app.tools.cut_pending = false;
    app.restores_seen = app.status.restores;
    std::printf("window: ready (%s, panel %d px, view %dx%d)\n", app.status.scene.file.c_str(), app.view.panel_width,
                app.view.viewport.width, app.view.viewport.height);
    std::fflush(stdout);
    app.undo_notes_seen = app.status.undo_notes;
    reset_mouse_commands(app);
    app.tools.left_down = false;
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
  // A grab that started on anchored tissue says why nothing moves (once per grab; also on stdout).
  if (app.tools.grabbing && app.status.grab_on && app.status.grab_held == 0 && app.status.grab_anchored > 0 &&
      !app.tools.grab_anchor_said) {
    app.tools.grab_anchor_said = true;
    show_message(app, "grab: held by an anchor (the scene's fixed tissue): nothing moves here", 6.0);
    std::printf("grab: held by an anchor (%u anchored particles under the cursor)\n", app.status.grab_anchored);
    std::fflush(stdout);
  }
  if (app.panel.message_until > 0.0 && glfwGetTime() > app.panel.message_until) {
    app.panel.message.clear();
    app.panel.message_until = 0.0;
  }
  report_cut(app);
}

}  // namespace

void show_message(AppState& app, const std::string& text, double seconds) {
  app.panel.message = text;
  app.panel.message_until = seconds > 0 ? glfwGetTime() + seconds : 0.0;
}

namespace {

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
      std::fprintf(
          stderr,
          "divvox: error: the display offers no OpenGL 4.5 core context (%s); use 'divvox replay REC --headless'\n",
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
  w.software =
      w.gl_renderer.find("llvmpipe") != std::string::npos || w.gl_renderer.find("softpipe") != std::string::npos;
  return -1;
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
  if (!renderer_init(w.renderer, app.view.viewport.width, app.view.viewport.height, error, samples,
                     samples == 0 && !w.cache_scene)) {
    std::fprintf(stderr, "divvox: error: renderer: %s\n", error.c_str());
    glfwDestroyWindow(w.window);
    glfwTerminate();
    return false;
  }
  renderer_place(w.renderer, app.view.view_x, 0);
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
  if (!solid_overlay_init(w.solid_overlay, error))
    std::fprintf(stderr, "divvox: warning: %s (no scalpel)\n", error.c_str());
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
  app.view.draw.cull_back_faces = true;
  app.view.draw.vertex_lighting = w.software;  // DrawOptions::vertex_lighting (a GPU lights per pixel for free)
  app.view.draw.surface_pieces = w.software ? 4 : 1;  // DrawOptions::surface_pieces
  // DIVVOX_SHADOWS=0: start with the tray's shadow off (View panel: "shadow on the tray").
  if (env.shadows >= 0) app.view.draw.shadows = env.shadows == 1;
  return true;
}

// The panel's font atlas sampled nearest instead of linear (ImGui's backend creates it on its first
// frame): the default font is a bitmap font drawn at its size on whole pixels, so each pixel samples
// a texel's centre and both give the same image, but llvmpipe's linear filter fetches and blends four
// texels for each of the panel's pixels, every frame.
void nearest_font_texture(WindowContext& w) {
  if (w.font_nearest) return;
  const GLuint texture = GLuint(reinterpret_cast<intptr_t>(ImGui::GetIO().Fonts->TexID));
  if (texture == 0) return;
  glTextureParameteri(texture, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
  glTextureParameteri(texture, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
  w.font_nearest = true;
}

// One frame: input, the snapshot, the scene (only when something it shows changed), overlays,
// panels, swap; its phase times into the statistics.
void run_frame(AppState& app, WindowContext& w) {
  glfwPollEvents();
  app.status = w.sim.status();
  follow_simulation(app, w.generation);
  const Clock::time_point now = Clock::now();  // after the status: never before its step_done
  sim_pace_sample(app.history.pace, std::chrono::duration<double>(now.time_since_epoch()).count(), app.status.step,
                  app.status.dt, std::chrono::duration<double>(now - app.status.step_done).count(),
                  app.status.ready && !app.status.paused && !app.status.loading, app.status.generation,
                  app.status.restores);
  // Window resize: a new panel width and offscreen target.
  int fb_w = 0, fb_h = 0;
  glfwGetFramebufferSize(w.window, &fb_w, &fb_h);
  if (fb_w >= 16 && fb_h >= 16) {
    const Viewport before = app.view.viewport;
    layout_view(app, fb_w, fb_h);
    renderer_place(w.renderer, app.view.view_x, 0);
    std::string error;
    if ((app.view.viewport.width != w.renderer.width || app.view.viewport.height != w.renderer.height) &&
        !renderer_resize(w.renderer, app.view.viewport.width, app.view.viewport.height, error)) {
      app.view.viewport = before;
    }
  }
  ImGui_ImplOpenGL3_NewFrame();
  nearest_font_texture(w);
  ImGui_ImplGlfw_NewFrame();
  ImGui::NewFrame();
  handle_keys(app, g_events, w.window);
  const MouseFrame mouse = handle_mouse(app, g_events, w.window);

  const Clock::time_point t0 = Clock::now();
  const Eigen::Vector2f cursor_before = w.last_cursor;
  w.last_cursor = app.tools.cursor;
  // Half of a snapshot's image drawn: the same snapshot until the rest is.
  const double normals_ms = w.split_pending ? -1.0 : take_snapshot(app, w);
  w.idle = normals_ms < 0.0 && !w.split_pending && app.status.ready && app.status.paused && !app.tools.left_down &&
           !app.tools.camera_drag && cursor_before == app.tools.cursor && app.panel.message.empty();
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
  if (!w.cache_scene) renderer_blit(w.renderer, 0, w.renderer.width, w.renderer.height, app.view.view_x, 0);
  if (!app.panel.screenshot_request.empty()) {
    std::string message;
    take_screenshot(app, app.panel.screenshot_request, message);
    show_message(app, message);
    std::printf("%s\n", message.c_str());
    app.panel.screenshot_request.clear();
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
  if (!app.panel.window_screenshot_request.empty()) {
    std::string message;
    take_window_screenshot(fb_w, fb_h, app.panel.window_screenshot_request, message);
    show_message(app, message);
    std::printf("%s\n", message.c_str());
    app.panel.window_screenshot_request.clear();
  }
  if (w.profile) glFinish();
  const Clock::time_point t3 = Clock::now();
  glfwSwapBuffers(w.window);
  const Clock::time_point t4 = Clock::now();

  // Frame statistics (normals: the simulation thread's time for the snapshot shown, or the GPU passes).
  const double render_ms = ms_between(t0, t3), interval = ms_between(w.last_frame, t4);
  w.last_frame = t4;
  app.history.push_frame(ms_between(t0, t1), ms_between(t1, t2), render_ms, interval);
  ++app.history.frame;
  if (app.status.ready && app.current != nullptr) {
    const double normals = w.gpu_normals ? ms_between(t1, t1n) : std::max(normals_ms, 0.0);
    if (normals_ms >= 0.0) FrameHistory::push(app.history.normals_ms, normals);
    const double phases[6] = {ms_between(t0, t1), normals,           ms_between(t1n, t1d), ms_between(t1d, t2),
                              ms_between(t2, t3), ms_between(t3, t4)};
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
        app.view.draw.pieces_begin = 0;
        app.view.draw.pieces_end = 64;
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
  std::printf("window: layout panel %d px (drawn %.0f px), view %dx%d, panel sections %.0f px in %.0f px (%s)\n",
              app.view.panel_width, app.view.panel_drawn_width, app.view.viewport.width, app.view.viewport.height,
              app.view.panel_sections_height, app.view.panel_sections_room,
              app.view.panel_sections_height <= app.view.panel_sections_room ? "fit" : "scroll");
  const SimStatus final_status = w.sim.status();
  if (final_status.playing && final_status.hash_mismatched > 0) {
    std::fprintf(stderr,
                 "divvox: error: %s: the window's simulation diverged from the recording (%u of %u hashes differ)\n",
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
  std::snprintf(app.panel.record_path, sizeof app.panel.record_path, "%s",
                options.record_path.empty() ? default_output_path("divvox_recording.jsonl").c_str()
                                            : options.record_path.c_str());
  if (playback) {
    std::snprintf(app.panel.play_path, sizeof app.panel.play_path, "%s", options.play_path.c_str());
    w.sim.play(playback);
  } else {
    w.sim.open(scene, scene.pbd.dt, options.record_path);
  }
  std::snprintf(app.panel.scene_path, sizeof app.panel.scene_path, "%s", options.scene_path.c_str());

  // Frame pacing: at most DIVVOX_MAX_FPS frames a second (default 60; 0: unpaced). Without a vsync
  // (Xvfb) a frame that reuses the scene cache takes a few ms, and every frame shown costs this
  // thread the copy and the panels and the X server a copy of the window: the time a faster frame
  // rate would spend goes to the simulation thread instead.
  const double max_fps = read_env_options().max_fps;
  Clock::time_point frame_start = Clock::now();
  int exit_code = kExitOk;
  install_quit_handlers();
  while (!glfwWindowShouldClose(w.window)) {
    if (const int signal_number = g_quit_signal.load(); signal_number != 0) {
      std::printf("window: closing on %s\n", signal_number == SIGTERM ? "SIGTERM" : "SIGINT");
      break;
    }
    // Paused with nothing new on the last frame: wait for input (up to 50 ms) instead of redrawing
    // the same image at full speed (on a software rasteriser that is two busy cores for nothing).
    if (w.idle) glfwWaitEventsTimeout(0.05);
    if (max_fps > 0.0) {
      const Clock::time_point next =
          frame_start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / max_fps));
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
