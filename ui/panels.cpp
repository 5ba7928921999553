// The window's ImGui panel, docked on the left at a fixed width (it cannot be dragged, resized or
// seen through; the 3D view starts right of it): a status line, then tools, simulation, view,
// performance, scene, recording and help sections, the rarely used ones collapsed. Every label
// fits at 1280x720 (items take half the width, long text wraps).
#include "engine/errors.h"
#include "ui/app_state.h"
#include "ui/tools.h"

#include <imgui.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <numeric>

namespace dvx {
namespace {

// assets/scenes/*.json next to the working directory, else in the source tree.
std::vector<std::string> scene_files() {
  std::vector<std::string> files;
  for (const std::filesystem::path& dir :
       {std::filesystem::path("assets/scenes"), std::filesystem::path(DIVVOX_SOURCE_DIR_DEFAULT) / "assets/scenes"}) {
    std::error_code ec;
    if (!std::filesystem::is_directory(dir, ec)) continue;
    for (const auto& entry : std::filesystem::directory_iterator(dir, ec)) {
      if (entry.path().extension() == ".json") files.push_back(entry.path().string());
    }
    if (!files.empty()) break;
  }
  std::sort(files.begin(), files.end());
  return files;
}

void open_scene_file(AppState& app, const std::string& path) {
  try {
    const Scene scene = load_scene(path);
    app.sim->open(scene, scene.pbd.dt);
    app.panel.edit_error.clear();
    show_message(app, "opening " + path, 4.0);
  } catch (const InputError& e) {
    app.panel.edit_error = e.what();
  }
}

float mean_of(const std::vector<float>& v) {
  return v.empty() ? 0.0f : std::accumulate(v.begin(), v.end(), 0.0f) / float(v.size());
}

// `last_nonzero`: the overlay shows the latest non-zero value (cut and surface times are zero on the
// steps that do not cut, so the latest value would read 0.00 between the steps of a cut).
void plot(const char* label, const std::vector<float>& values, const char* unit, bool last_nonzero = false) {
  float shown = values.empty() ? 0.0f : values.back();
  if (last_nonzero) {
    for (auto it = values.rbegin(); it != values.rend(); ++it) {
      if (*it > 0.0f) {
        shown = *it;
        break;
      }
    }
  }
  char overlay[64];
  std::snprintf(overlay, sizeof overlay, "%s%.2f %s (mean %.2f)", last_nonzero ? "last " : "", shown, unit,
                mean_of(values));
  ImGui::PlotLines(label, values.data(), int(values.size()), 0, overlay, 0.0f, FLT_MAX, ImVec2(0, 40));
}

void scene_panel(AppState& app) {
  if (!ImGui::CollapsingHeader("Scene")) return;
  ImGui::TextWrapped("%s", app.status.scene.file.empty() ? "(scene built in code)" : app.status.scene.file.c_str());
  ImGui::InputText("scene file", app.panel.scene_path, sizeof app.panel.scene_path);
  if (ImGui::Button("Open")) open_scene_file(app, app.panel.scene_path);
  for (const std::string& f : scene_files()) {
    const std::string name = std::filesystem::path(f).filename().string();
    if (ImGui::Selectable(name.c_str(), std::filesystem::path(f) == std::filesystem::path(app.status.scene.file))) {
      std::snprintf(app.panel.scene_path, sizeof app.panel.scene_path, "%s", f.c_str());
      open_scene_file(app, f);
    }
  }
  ImGui::Separator();
  SceneEdit& e = app.panel.edit;
  ImGui::InputText("mesh", e.mesh, sizeof e.mesh);
  ImGui::InputInt("resolution", &e.resolution);
  ImGui::InputInt("sim resolution", &e.sim_resolution);
  // The material: a physical one (SI units) or the paper's solver knobs, each with its own keys.
  int model = e.physical ? 0 : 1;
  ImGui::RadioButton("material (E, nu)", &model, 0);
  ImGui::SameLine();
  ImGui::RadioButton("paper's model", &model, 1);
  e.physical = model == 0;
  ImGui::InputDouble("density (kg/m^3)", &e.density, 0, 0, "%.6g");
  if (e.physical) {
    ImGui::InputDouble("Young's modulus (Pa)", &e.youngs_modulus, 0, 0, "%.6g");
    ImGui::InputDouble("Poisson's ratio", &e.poisson_ratio, 0, 0, "%.4g");
    ImGui::InputDouble("damping (s, Rayleigh)", &e.stiffness_damping, 0, 0, "%.3g");
    // A whole-body linear solve each substep: stiff materials (MPa) at a budget of 1 x 1.
    ImGui::Checkbox("global step (stiff materials)", &e.global_step);
  } else {
    ImGui::InputDouble("stretch compliance", &e.stretch_compliance, 0, 0, "%.3g");
    ImGui::InputDouble("shape stiffness", &e.shape_stiffness, 0, 0, "%.3g");
  }
  ImGui::InputDouble("dt", &e.dt, 0, 0, "%.6g");
  ImGui::InputInt("substeps", &e.substeps);
  ImGui::InputInt("iterations", &e.iterations);
  // The paper's velocity damping (the material model damps through its constraints instead).
  if (!e.physical) ImGui::InputDouble("damping", &e.damping, 0, 0, "%.3g");
  ImGui::InputScalarN("gravity", ImGuiDataType_Double, e.gravity, 3);
  ImGui::InputDouble("cut depth", &e.scalpel_length, 0, 0, "%.4g");
  if (ImGui::Button("Apply (rebuild)")) {
    Scene scene;
    std::string error;
    if (apply_scene_edit(app.status.scene, e, scene, error)) {
      app.sim->open(scene, scene.pbd.dt);
      app.panel.edit_error.clear();
    } else {
      app.panel.edit_error = error;
    }
  }
  ImGui::SameLine();
  if (ImGui::Button("Revert")) {
    e = scene_edit_of(app.status.scene);
    app.panel.edit_error.clear();
  }
  if (!app.panel.edit_error.empty()) {
    ImGui::PushStyleColor(ImGuiCol_Text, ImVec4(1, 0.4f, 0.4f, 1));
    ImGui::TextWrapped("%s", app.panel.edit_error.c_str());
    ImGui::PopStyleColor();
  }
}

void simulation_panel(AppState& app) {
  if (!ImGui::CollapsingHeader("Simulation", ImGuiTreeNodeFlags_DefaultOpen)) return;
  const SimStatus& s = app.status;
  ImGui::Text("step %u  (%.1f s)%s%s", s.step, s.step * s.dt, s.paused ? "  paused" : "",
              s.loading ? "  loading..." : "");
  if (ImGui::Button(s.paused ? "Play" : "Pause")) app.sim->set_paused(!s.paused);
  ImGui::SameLine();
  if (ImGui::Button("Step")) app.sim->step_once();
  ImGui::SameLine();
  if (ImGui::Button("Reset")) app.sim->open(s.scene, s.dt);
  if (!ImGui::TreeNode("solver")) return;
  const bool locked = s.recording || s.playing;
  if (locked) ImGui::TextWrapped("(solver edits are off while recording or playing)");
  ImGui::BeginDisabled(locked);
  ImGui::InputFloat("dt##sim", &app.panel.ui_dt, 0, 0, "%.5f");
  ImGui::InputInt("iterations##sim", &app.panel.ui_iterations);
  ImGui::InputFloat3("gravity##sim", app.panel.ui_gravity);
  if (ImGui::Button("Set")) {
    if (app.panel.ui_dt >= 1e-6f && app.panel.ui_dt <= 1.0f && app.panel.ui_iterations >= 1 &&
        app.panel.ui_iterations <= 10000) {
      app.sim->set_solver(app.panel.ui_dt, app.panel.ui_iterations,
                          Vec3d(app.panel.ui_gravity[0], app.panel.ui_gravity[1], app.panel.ui_gravity[2]));
    } else {
      show_message(app, "dt must be in [1e-6, 1], iterations in [1, 10000]");
    }
  }
  ImGui::SameLine();
  if (ImGui::Button("From scene")) {
    app.panel.ui_dt = float(s.dt);
    app.panel.ui_iterations = s.scene.pbd.iterations;
    for (int k = 0; k < 3; ++k) app.panel.ui_gravity[k] = float(s.scene.pbd.gravity[k]);
  }
  ImGui::EndDisabled();
  ImGui::TreePop();
  if (!s.error.empty()) {
    ImGui::PushStyleColor(ImGuiCol_Text, ImVec4(1, 0.4f, 0.4f, 1));
    ImGui::TextWrapped("%s", s.error.c_str());
    ImGui::PopStyleColor();
  }
}

void tools_panel(AppState& app) {
  if (!ImGui::CollapsingHeader("Tools", ImGuiTreeNodeFlags_DefaultOpen)) return;
  int tool = app.tools.tool == Tool::kScalpel ? 0 : 1;
  ImGui::RadioButton("scalpel (S)", &tool, 0);
  ImGui::SameLine();
  ImGui::RadioButton("grab (G)", &tool, 1);
  select_tool(app, tool == 0 ? Tool::kScalpel : Tool::kGrab);
  float depth = app.tools.cut_depth;
  if (ImGui::SliderFloat("cut depth", &depth, 0.5f * app.view.voxel_size, 2.0f * app.view.radius, "%.2f",
                         ImGuiSliderFlags_Logarithmic)) {
    app.tools.cut_depth = depth;
  }
  ImGui::TextDisabled("ctrl+wheel or [ ] also set it");
  ImGui::SliderFloat("grab stiffness", &app.tools.grab_stiffness, 10.0f, 1e5f, "%.0f N/m", ImGuiSliderFlags_Logarithmic);
  ImGui::SliderFloat("force limit", &app.tools.grab_force_limit, 0.0f, 200.0f, app.tools.grab_force_limit > 0.0f ? "%.0f N" : "none");
  const SimStatus& s = app.status;
  ImGui::BeginDisabled(s.undo_levels == 0 || s.recording || s.playing);
  if (ImGui::Button("Undo (ctrl+z)")) request_undo(app, false);
  ImGui::EndDisabled();
  ImGui::SameLine();
  ImGui::BeginDisabled(s.redo_levels == 0 || s.recording || s.playing);
  if (ImGui::Button("Redo (ctrl+shift+z)")) request_undo(app, true);
  ImGui::EndDisabled();
  ImGui::TextDisabled("%u undo, %u redo kept%s", s.undo_levels, s.redo_levels,
                      s.recording || s.playing ? " (off while recording)" : "");
}

void view_panel(AppState& app) {
  if (!ImGui::CollapsingHeader("View")) return;
  ImGui::Checkbox("wireframe (W)", &app.view.draw.wireframe);
  ImGui::Checkbox("blade trail (T)", &app.view.show_trail);
  ImGui::SliderInt("trail length", &app.view.trail_length, 2, 200);
  ImGui::Checkbox("shadow on the tray", &app.view.draw.shadows);
  ImGui::Checkbox("Show anchors", &app.view.show_anchors);
  ImGui::ColorEdit3("cut colour", app.view.draw.cut_color.data());
  ImGui::ColorEdit3("surface colour", app.view.draw.surface_color.data());
  if (ImGui::Button("Reset view (R)")) {
    app.view.camera = frame_box(app.view.bounds, app.view.viewport.aspect());
  }
  ImGui::InputText("screenshot", app.panel.screenshot_path, sizeof app.panel.screenshot_path);
  ImGui::SameLine();
  if (ImGui::Button("Save (F12)")) {
    app.panel.screenshot_request =
        app.panel.screenshot_path[0] ? std::string(app.panel.screenshot_path) : default_screenshot_name();
  }
}

void performance_panel(AppState& app) {
  if (!ImGui::CollapsingHeader("Performance")) return;
  std::vector<float> cut, surface, deform, total;
  for (const StepTimings& t : app.status.timings) {
    cut.push_back(float(t.cut_ms));
    surface.push_back(float(t.surface_ms));
    deform.push_back(float(t.deform_ms));
    total.push_back(float(t.total_ms));
  }
  plot("cut ms", cut, "ms", true);
  plot("surface ms", surface, "ms", true);
  plot("deform ms", deform, "ms");
  plot("step ms", total, "ms");
  plot("grab force N", app.status.grab_force_n, "N");
  plot("upload ms", app.history.upload_ms, "ms");
  plot("normals ms", app.history.normals_ms, "ms");
  plot("render ms", app.history.render_ms, "ms");
  plot("FPS", app.history.fps, "fps");
  const SimStatus& s = app.status;
  ImGui::TextWrapped("voxels %u, divided %u, sim voxels divided %u", s.occupied_voxels, s.divided_voxels,
                     s.sim_voxels_divided);
  ImGui::TextWrapped("particles %u, triangles %llu", s.particles,
                     static_cast<unsigned long long>(app.history.triangles));
  if (!app.history.latency_frames.empty()) {
    double mean = 0;
    for (double l : app.history.latency_frames) mean += l;
    ImGui::Text("input to cut latency %.1f frames", mean / double(app.history.latency_frames.size()));
  }
  ImGui::PushStyleColor(ImGuiCol_Text, ImGui::GetStyleColorVec4(ImGuiCol_TextDisabled));
  ImGui::TextWrapped("%s", app.gl_renderer.c_str());
  ImGui::PopStyleColor();
}

void recording_panel(AppState& app) {
  if (!ImGui::CollapsingHeader("Recording")) return;
  const SimStatus& s = app.status;
  ImGui::InputText("record to", app.panel.record_path, sizeof app.panel.record_path);
  if (!s.recording) {
    if (ImGui::Button("Record (restarts the scene)")) {
      const std::filesystem::path parent = std::filesystem::path(app.panel.record_path).parent_path();
      std::error_code ec;
      if (!parent.empty()) std::filesystem::create_directories(parent, ec);
      app.sim->start_recording(app.panel.record_path);
      show_message(app, std::string("recording to ") + app.panel.record_path, 4.0);
    }
  } else {
    ImGui::PushStyleColor(ImGuiCol_Text, ImVec4(1, 0.3f, 0.3f, 1));
    ImGui::TextWrapped("recording %s", s.recording_path.c_str());
    ImGui::PopStyleColor();
    if (ImGui::Button("Stop recording")) app.sim->stop_recording();
  }
  ImGui::Separator();
  ImGui::InputText("play file", app.panel.play_path, sizeof app.panel.play_path);
  if (ImGui::Button("Play")) {
    try {
      app.sim->play(app.panel.play_path);
      show_message(app, std::string("playing ") + app.panel.play_path, 4.0);
    } catch (const InputError& e) {
      show_message(app, e.what(), 10.0);
    }
  }
  if (s.playing) {
    ImGui::TextWrapped("%s: step %u / %u, hashes %u checked, %u differ", s.play_path.c_str(),
                       std::min(s.step, s.play_last), s.play_last, s.hash_checked, s.hash_mismatched);
    if (s.play_done) ImGui::TextWrapped("final hash %s", s.final_hash.c_str());
  }
}

void help_panel(AppState& app) {
  ImGui::SetNextItemOpen(app.panel.show_help, ImGuiCond_Always);
  app.panel.show_help = ImGui::CollapsingHeader("Help (F1)");
  if (!app.panel.show_help) return;
  static const char* const kKeys[][2] = {{"left drag", "scalpel: cut, 'cut depth' deep / grab: pull the surface"},
                                         {"ctrl+wheel, [ ]", "cut depth"},
                                         {"ctrl+z, ctrl+shift+z", "undo, redo a cut or a grab"},
                                         {"right drag", "orbit"},
                                         {"middle drag", "pan (also shift + right drag)"},
                                         {"wheel, + -", "zoom"},
                                         {"S or C, G", "scalpel, grab tool"},
                                         {"R or Home", "reset the view"},
                                         {"space, .", "pause / play, one step"},
                                         {"W, T", "wireframe, blade trail"},
                                         {"F12, shift+F12", "screenshot: view, window (out/window/)"},
                                         {"F1", "this help"},
                                         {"shift+Esc", "quit"}};
  if (ImGui::BeginTable("keys", 2, ImGuiTableFlags_SizingStretchProp)) {
    ImGui::TableSetupColumn("key", ImGuiTableColumnFlags_WidthFixed, 0.36f * float(app.view.panel_width));
    ImGui::TableSetupColumn("action", ImGuiTableColumnFlags_WidthStretch);
    for (const auto& row : kKeys) {
      ImGui::TableNextRow();
      ImGui::TableSetColumnIndex(0);
      ImGui::TextWrapped("%s", row[0]);
      ImGui::TableSetColumnIndex(1);
      ImGui::TextWrapped("%s", row[1]);
    }
    ImGui::EndTable();
  }
}

}  // namespace

int panel_width_for(int framebuffer_width) {
  return std::clamp(int(0.3f * float(framebuffer_width)), std::min(300, framebuffer_width / 2), 400);
}

void draw_panels(AppState& app) {
  // Docked: the left strip of the window, full height; fixed, opaque, no title bar.
  ImGui::SetNextWindowPos(ImVec2(0, 0), ImGuiCond_Always);
  ImGui::SetNextWindowSize(ImVec2(float(app.view.panel_width), float(app.view.viewport.height)), ImGuiCond_Always);
  ImGui::SetNextWindowBgAlpha(app.view.panel_cleared ? 0.0f : 1.0f);
  const ImGuiWindowFlags flags = ImGuiWindowFlags_NoResize | ImGuiWindowFlags_NoMove | ImGuiWindowFlags_NoCollapse |
                                 ImGuiWindowFlags_NoTitleBar | ImGuiWindowFlags_NoSavedSettings |
                                 ImGuiWindowFlags_NoBringToFrontOnFocus;
  ImGui::Begin("divvox", nullptr, flags | ImGuiWindowFlags_NoScrollbar | ImGuiWindowFlags_NoScrollWithMouse);
  // Status line: the last message, else what the window is doing.
  const SimStatus& s = app.status;
  const float fps = app.history.fps.empty() ? 0.0f : mean_of(app.history.fps);
  // The simulation's pace, as printed at exit (SimPace: since the last reset or undo, paused time
  // left out), once half a second of running is counted; with the last full second's pace.
  char pace[64] = "";
  const SimPace& p = app.history.pace;
  if (s.ready && !s.paused && !s.loading && p.run_seconds >= 0.5) {
    if (p.per_second.empty()) {
      std::snprintf(pace, sizeof pace, "sim x%.2f real time", p.rate());
    } else {
      std::snprintf(pace, sizeof pace, "sim x%.2f real time (last s x%.2f)", p.rate(), double(p.per_second.back()));
    }
  }
  ImGui::Text("divvox  %.0f fps  %s", fps, s.loading ? "loading..." : s.paused ? "paused" : pace);
  if (!app.panel.message.empty()) {
    ImGui::PushStyleColor(ImGuiCol_Text, ImVec4(1.0f, 0.85f, 0.45f, 1.0f));
    ImGui::TextWrapped("%s", app.panel.message.c_str());
    ImGui::PopStyleColor();
  } else if (s.grab_on && app.tools.grabbing) {
    // The grab's reading: its force, or why it moves nothing.
    if (s.grab_held == 0 && s.grab_anchored > 0) {
      ImGui::TextColored(ImVec4(1.0f, 0.6f, 0.4f, 1.0f), "grab: held by an anchor (nothing moves)");
    } else {
      ImGui::Text("grab: %.1f N on %u particles%s", s.grab_force_n.empty() ? 0.0f : s.grab_force_n.back(), s.grab_held,
                  s.grab_anchored > 0 ? ", partly held by an anchor" : "");
    }
  } else if (s.playing && !s.play_done) {
    ImGui::TextWrapped("playing step %u / %u", std::min(s.step, s.play_last), s.play_last);
  } else {
    ImGui::TextDisabled(
        "%s", app.tools.tool == Tool::kScalpel ? "left drag cuts, right drag orbits" : "left drag pulls the tissue");
  }
  ImGui::Separator();
  // The sections scroll under the status line (which stays in view) when they outgrow the window.
  ImGui::BeginChild("sections", ImVec2(0.0f, 0.0f), false);
  ImGui::PushItemWidth(0.5f * float(app.view.panel_width));
  tools_panel(app);
  simulation_panel(app);
  view_panel(app);
  performance_panel(app);
  scene_panel(app);
  recording_panel(app);
  help_panel(app);
  ImGui::PopItemWidth();
  app.view.panel_sections_height = ImGui::GetCursorPosY() - ImGui::GetStyle().ItemSpacing.y;
  app.view.panel_sections_room = ImGui::GetWindowHeight();
  ImGui::EndChild();
  app.view.panel_drawn_width = ImGui::GetWindowSize().x;
  ImGui::End();
}

}  // namespace dvx
