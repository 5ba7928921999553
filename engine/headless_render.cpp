#include "engine/headless_render.h"

#include "engine/render_snapshot.h"
#include "engine/timing.h"
#include "render/camera.h"
#include "render/egl_context.h"
#include "render/renderer.h"

#include <cmath>
#include <cstdio>
#include <filesystem>

namespace dvx {

bool probe_headless_render(std::string& error) {
  EglContext context;
  if (!create_egl_context(context, error)) return false;
  destroy_egl_context(context);
  return true;
}

bool run_headless_render(SnapshotExchange& exchange, const HeadlessRenderOptions& options, std::vector<FrameRow>& rows,
                         std::string& error) {
  EglContext context;
  if (!create_egl_context(context, error)) {
    exchange.close();
    return false;
  }
  Renderer renderer;
  if (!renderer_init(renderer, options.width, options.height, error)) {
    exchange.close();
    destroy_egl_context(context);
    return false;
  }
  const Camera framing = frame_box(options.framing, float(options.width) / float(options.height));
  Camera camera = framing;
  DrawOptions draw;
  draw.wireframe = options.wireframe;
  for (const ContactPlane& p : options.planes) {
    draw.trays.push_back(tray_under(options.framing.min.cast<float>(), options.framing.max.cast<float>(),
                                    p.point.cast<float>(), p.normal.cast<float>()));
  }
  std::vector<Vec3f> normals, casters;
  std::vector<uint8_t> rgba;
  uint64_t last_sequence = 0, frame = 0;
  Clock::time_point last_frame = Clock::now();
  bool ok = true;
  while (ok) {
    const Snapshot* s = exchange.take();
    if (s == nullptr) {
      if (exchange.finished()) break;
      exchange.wait(50);
      continue;
    }
    // Upload: positions and normals in full (they move every step), triangles by dirty range unless
    // snapshots were skipped.
    const Clock::time_point t0 = Clock::now();
    upload_snapshot(renderer, *s, s->sequence != last_sequence + 1, normals);
    last_sequence = s->sequence;
    // The recording's camera when it sets one (clip planes scaled to its distance).
    if (s->has_camera) {
      camera.target = s->camera_target;
      camera.distance = s->camera_distance;
      camera.yaw = s->camera_yaw;
      camera.pitch = s->camera_pitch;
      camera.z_near = 0.01f * s->camera_distance;
      camera.z_far = 100.0f * s->camera_distance;
    } else {
      camera = framing;
    }
    const Clock::time_point t1 = Clock::now();
    if (!draw.trays.empty()) {
      shadow_casters(*s, casters);
      tray_shadow_update(renderer, casters.data(), uint32_t(casters.size()), camera, draw);
    }
    renderer_draw(renderer, camera, draw);
    const Clock::time_point t2 = Clock::now();
    FrameRow row{frame, s->step, ms_between(t0, t1), ms_between(t1, t2), 0.0, ms_between(last_frame, t2), false};
    last_frame = t2;
    // Capture: read back and write the PNG.
    if (s->capture && !options.frames_dir.empty()) {
      if (!renderer_read_pixels(renderer, rgba)) {
        error = "cannot read the rendered frame back";
        ok = false;
      }
      row.readback_ms = ms_between(t2, Clock::now());
      char name[64];
      std::snprintf(name, sizeof name, "frame_%05u.png", s->step);
      if (ok && !write_png((std::filesystem::path(options.frames_dir) / name).string(), options.width, options.height,
                           rgba, error)) {
        ok = false;
      }
      row.written = ok;
    } else {
      renderer_read_pixels(renderer, rgba);  // finish the frame (llvmpipe renders lazily)
      row.readback_ms = ms_between(t2, Clock::now());
    }
    rows.push_back(row);
    ++frame;
  }
  exchange.close();
  renderer_destroy(renderer);
  destroy_egl_context(context);
  return ok;
}

}  // namespace dvx
