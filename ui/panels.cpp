// The window's ImGui panels: scene, simulation, tools, view, performance, recording, help.
#include "engine/errors.h"
#include "ui/app_state.h"

#include <imgui.h>

#include <algorithm>
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
    app.sim->open(scene, scene.solver.dt);
    app.edit_error.clear();
    app.message = "opening " + path;
  } catch (const InputError& e) {
    app.edit_error = e.what();
  }
}

float mean_of(const std::vector<float>& v) {
  return v.empty() ? 0.0f : std::accumulate(v.begin(), v.end(), 0.0f) / float(v.size());
}

void plot(const char* label, const std::vector<float>& values, const char* unit) {
  char overlay[64];
  std::snprintf(overlay, sizeof overlay, "%.2f %s (mean %.2f)", values.empty() ? 0.0f : values.back(), unit,
                mean_of(values));
  ImGui::PlotLines(label, values.data(), int(values.size()), 0, overlay, 0.0f, FLT_MAX, ImVec2(0, 50));
}

void scene_panel(AppState& app) {
  if (!ImGui::CollapsingHeader("Scene", ImGuiTreeNodeFlags_DefaultOpen)) return;
  ImGui::TextWrapped("%s", app.status.scene.file.empty() ? "(scene built in code)" : app.status.scene.file.c_str());
  ImGui::InputText("scene file", app.scene_path, sizeof app.scene_path);
  ImGui::SameLine();
  if (ImGui::Button("Open")) open_scene_file(app, app.scene_path);
  for (const std::string& f : scene_files()) {
    if (ImGui::Selectable(f.c_str(), f == app.status.scene.file)) {
      std::snprintf(app.scene_path, sizeof app.scene_path, "%s", f.c_str());
      open_scene_file(app, f);
    }
  }
  ImGui::Separator();
  SceneEdit& e = app.edit;
  ImGui::InputText("mesh", e.mesh, sizeof e.mesh);
  ImGui::InputInt("resolution", &e.resolution);
  ImGui::InputInt("sim resolution", &e.sim_resolution);
  ImGui::InputDouble("density", &e.density, 0, 0, "%.6g");
  ImGui::InputDouble("stretch compliance", &e.stretch_compliance, 0, 0, "%.3g");
  ImGui::InputDouble("shape stiffness", &e.shape_stiffness, 0, 0, "%.3g");
  ImGui::InputDouble("dt", &e.dt, 0, 0, "%.6g");
  ImGui::InputInt("substeps", &e.substeps);
  ImGui::InputInt("iterations", &e.iterations);
  ImGui::InputDouble("damping", &e.damping, 0, 0, "%.3g");
  ImGui::InputScalarN("gravity", ImGuiDataType_Double, e.gravity, 3);
  ImGui::InputDouble("scalpel length", &e.scalpel_length, 0, 0, "%.4g");
  if (ImGui::Button("Apply (rebuild)")) {
    Scene scene;
    std::string error;
    if (apply_scene_edit(app.status.scene, e, scene, error)) {
      app.sim->open(scene, scene.solver.dt);
      app.edit_error.clear();
    } else {
      app.edit_error = error;
    }
  }
  ImGui::SameLine();
  if (ImGui::Button("Revert")) {
    e = scene_edit_of(app.status.scene);
    app.edit_error.clear();
  }
  if (!app.edit_error.empty()) ImGui::TextColored(ImVec4(1, 0.4f, 0.4f, 1), "%s", app.edit_error.c_str());
}

void simulation_panel(AppState& app) {
  if (!ImGui::CollapsingHeader("Simulation", ImGuiTreeNodeFlags_DefaultOpen)) return;
  const SimStatus& s = app.status;
  ImGui::Text("step %u  (%.1f s simulated)%s", s.step, s.step * s.dt, s.loading ? "  loading..." : "");
  if (ImGui::Button(s.paused ? "Play" : "Pause")) app.sim->set_paused(!s.paused);
  ImGui::SameLine();
  if (ImGui::Button("Step")) app.sim->step_once();
  ImGui::SameLine();
  if (ImGui::Button("Reset")) app.sim->open(s.scene, s.dt);
  const bool locked = s.recording || s.playing;
  if (locked) ImGui::TextDisabled("(solver edits are off while recording or playing)");
  ImGui::BeginDisabled(locked);
  ImGui::InputFloat("dt##sim", &app.ui_dt, 0, 0, "%.5f");
  ImGui::InputInt("iterations##sim", &app.ui_iterations);
  ImGui::InputFloat3("gravity##sim", app.ui_gravity);
  if (ImGui::Button("Set")) {
    if (app.ui_dt >= 1e-6f && app.ui_dt <= 1.0f && app.ui_iterations >= 1 && app.ui_iterations <= 10000) {
      app.sim->set_solver(app.ui_dt, app.ui_iterations, Vec3d(app.ui_gravity[0], app.ui_gravity[1], app.ui_gravity[2]));
    } else {
      app.message = "dt must be in [1e-6, 1], iterations in [1, 10000]";
    }
  }
  ImGui::SameLine();
  if (ImGui::Button("From scene")) {
    app.ui_dt = float(s.dt);
    app.ui_iterations = s.scene.solver.iterations;
    for (int k = 0; k < 3; ++k) app.ui_gravity[k] = float(s.scene.gravity[k]);
  }
  ImGui::EndDisabled();
  if (!s.error.empty()) ImGui::TextColored(ImVec4(1, 0.4f, 0.4f, 1), "%s", s.error.c_str());
}

void tools_panel(AppState& app) {
  if (!ImGui::CollapsingHeader("Tools", ImGuiTreeNodeFlags_DefaultOpen)) return;
  int tool = app.tool == Tool::kScalpel ? 0 : 1;
  ImGui::RadioButton("scalpel (S)", &tool, 0);
  ImGui::SameLine();
  ImGui::RadioButton("grab (G)", &tool, 1);
  app.tool = tool == 0 ? Tool::kScalpel : Tool::kGrab;
  if (app.blade_depth > 0.0f) {
    ImGui::Text("blade depth %.3g (ctrl+wheel; D: back to the box entry)", app.blade_depth);
  } else {
    ImGui::Text("blade starts at the bounding box (ctrl+wheel sets a depth)");
  }
  ImGui::Text("scalpel length %.3g", app.status.scene.scalpel.length);
}

void view_panel(AppState& app) {
  if (!ImGui::CollapsingHeader("View")) return;
  ImGui::Checkbox("wireframe (W)", &app.draw.wireframe);
  ImGui::Checkbox("blade trail (T)", &app.show_trail);
  ImGui::SliderInt("trail length", &app.trail_length, 2, 200);
  ImGui::ColorEdit3("cut colour", app.draw.cut_color.data());
  ImGui::ColorEdit3("surface colour", app.draw.surface_color.data());
  if (ImGui::Button("Reset view (R)")) {
    app.camera = frame_box(app.bounds, app.viewport.aspect());
  }
  ImGui::InputText("screenshot", app.screenshot_path, sizeof app.screenshot_path);
  ImGui::SameLine();
  if (ImGui::Button("Save (F12)")) {
    std::string message;
    take_screenshot(app, app.screenshot_path[0] ? std::string(app.screenshot_path) : default_screenshot_name(), message);
    app.message = message;
  }
}

void performance_panel(AppState& app) {
  if (!ImGui::CollapsingHeader("Performance", ImGuiTreeNodeFlags_DefaultOpen)) return;
  std::vector<float> cut, surface, deform, total;
  for (const StepTimings& t : app.status.timings) {
    cut.push_back(float(t.cut_ms));
    surface.push_back(float(t.surface_ms));
    deform.push_back(float(t.deform_ms));
    total.push_back(float(t.total_ms));
  }
  plot("cut ms", cut, "ms");
  plot("surface ms", surface, "ms");
  plot("deform ms", deform, "ms");
  plot("step ms", total, "ms");
  plot("render ms", app.render_ms, "ms");
  plot("FPS", app.fps, "fps");
  const SimStatus& s = app.status;
  ImGui::Text("voxels %u, divided voxels %u, sim voxels divided %u", s.occupied_voxels, s.divided_voxels,
              s.sim_voxels_divided);
  ImGui::Text("particles %u, triangles %llu", s.particles, static_cast<unsigned long long>(app.triangles));
  if (!app.latency_frames.empty()) {
    double mean = 0;
    for (double l : app.latency_frames) mean += l;
    ImGui::Text("input to cut latency %.1f frames", mean / double(app.latency_frames.size()));
  }
  ImGui::TextDisabled("%s", app.gl_renderer.c_str());
}

void recording_panel(AppState& app) {
  if (!ImGui::CollapsingHeader("Recording", ImGuiTreeNodeFlags_DefaultOpen)) return;
  const SimStatus& s = app.status;
  ImGui::InputText("record to", app.record_path, sizeof app.record_path);
  if (!s.recording) {
    if (ImGui::Button("Record (restarts the scene)")) app.sim->start_recording(app.record_path);
  } else {
    ImGui::TextColored(ImVec4(1, 0.3f, 0.3f, 1), "recording %s", s.recording_path.c_str());
    if (ImGui::Button("Stop recording")) app.sim->stop_recording();
  }
  ImGui::Separator();
  ImGui::InputText("recording", app.play_path, sizeof app.play_path);
  ImGui::SameLine();
  if (ImGui::Button("Play")) {
    try {
      app.sim->play(app.play_path);
      app.message = std::string("playing ") + app.play_path;
    } catch (const InputError& e) {
      app.message = e.what();
    }
  }
  if (s.playing) {
    ImGui::Text("%s: step %u / %u, hashes %u checked, %u differ", s.play_path.c_str(), std::min(s.step, s.play_last),
                s.play_last, s.hash_checked, s.hash_mismatched);
    if (s.play_done) ImGui::Text("final hash %s", s.final_hash.c_str());
  }
}

void help_panel(AppState& app) {
  if (!ImGui::CollapsingHeader("Help (F1)", app.show_help ? ImGuiTreeNodeFlags_DefaultOpen : 0)) return;
  ImGui::TextUnformatted(
      "left drag        scalpel: cut along the cursor ray / grab: pull the surface\n"
      "right drag       orbit\n"
      "middle drag      pan (also shift + right drag)\n"
      "wheel, + / -     zoom\n"
      "ctrl + wheel     scalpel depth along the ray (D: back to the box entry)\n"
      "S or C / G       scalpel / grab tool\n"
      "R or Home        reset the view (frame the object)\n"
      "space / .        pause-play / one step\n"
      "W / T            wireframe / blade trail\n"
      "F12              screenshot (PNG in the working directory)\n"
      "F1               this help\n"
      "shift + Esc      quit");
}

}  // namespace

void draw_panels(AppState& app) {
  ImGui::SetNextWindowPos(ImVec2(8, 8), ImGuiCond_FirstUseEver);
  ImGui::SetNextWindowSize(ImVec2(380, float(std::max(200, app.viewport.height - 16))), ImGuiCond_FirstUseEver);
  ImGui::Begin("divvox");
  if (!app.message.empty()) ImGui::TextWrapped("%s", app.message.c_str());
  scene_panel(app);
  simulation_panel(app);
  tools_panel(app);
  view_panel(app);
  performance_panel(app);
  recording_panel(app);
  help_panel(app);
  ImGui::End();
}

}  // namespace dvx
