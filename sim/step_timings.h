// What one simulation step's phases took, in milliseconds: measured by the caller's clock (sim/ reads
// none; see StepClock in sim/world.h), zero when the caller lends no clock.
#pragma once

namespace dvx {

// The cut (map, divide, fine and coarse update), the surface update, the deformation (PBD +
// embedding) and the whole step; map_ms is the part of cut_ms that mapped the blade to rest space.
struct StepTimings {
  double cut_ms = 0, surface_ms = 0, deform_ms = 0, total_ms = 0;
  double map_ms = 0;
};

}  // namespace dvx
