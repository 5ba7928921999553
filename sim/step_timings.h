// What one simulation step's phases took, in milliseconds: measured by the caller's clock (sim/ reads
// none; see StepClock below), zero when the caller lends no clock.
#pragma once

namespace dvx {

// The cut (map, divide, fine and coarse update), the surface update, the deformation (PBD +
// embedding) and the whole step; map_ms is the part of cut_ms that mapped the blade to rest space,
// model_ms the part of cut_ms that updated the PBD model (pbd_apply_cut), contact_ms the part of
// deform_ms that gathered the contacts (their index, contact points and pairs; the rest of deform_ms
// is the solver and the embedding).
struct StepTimings {
  double cut_ms = 0, surface_ms = 0, deform_ms = 0, total_ms = 0;
  double map_ms = 0;
  double model_ms = 0, contact_ms = 0;
};

// A clock the caller lends the step for its report (sim/ reads none): milliseconds since any origin.
struct StepClock {
  void* context = nullptr;
  double (*now_ms)(void* context) = nullptr;
  double now() const { return now_ms ? now_ms(context) : 0.0; }
};

}  // namespace dvx
