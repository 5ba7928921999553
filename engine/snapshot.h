// What the simulation thread hands the render thread: an immutable copy of the surface after a step
// (deformed positions, triangles, cut flags, dirty ranges, timings), through a triple buffer. The
// exchange holds its lock only to swap slot indices: a step never waits for a frame and a frame
// never waits for a step (except when frames are captured at given steps: then the simulation
// waits until that snapshot has been taken, so every requested frame is written).
#pragma once

#include "engine/timing.h"
#include "sim/cut.h"
#include "sim/mesh.h"

#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <vector>

namespace dvx {

struct Snapshot {
  uint64_t sequence = 0;            // 1, 2, 3, ... in publish order
  uint32_t step = 0;
  std::vector<Vec3f> positions;     // (vertex slots) deformed positions; free slots hold NaN
  std::vector<Tri> triangles;       // (triangle slots) kDeadIndex for free slots
  std::vector<uint8_t> triangle_flags;  // (triangle slots) bit 0: cut face
  uint32_t dirty_triangle_begin = 0, dirty_triangle_end = 0;  // triangle slots changed since the previous snapshot
  bool capture = false;             // a frame must be captured of this snapshot
  StepTimings timings;
  // Split vertex normals (render/normals.h: outer surface, cut faces), filled by the window's
  // simulation thread when asked (ui/sim_runner.h); empty elsewhere (the headless renderer computes
  // its own). normals_ms: the time that took.
  std::vector<Vec3f> normals, cut_normals;
  double normals_ms = 0.0;
  // A camera set by the recording ("camera" in step lines), else the default framing is used.
  bool has_camera = false;
  Vec3f camera_target = Vec3f::Zero();
  float camera_distance = 1.0f, camera_yaw = 0.0f, camera_pitch = 0.0f;
};

// Timings of one frame of the render thread.
struct FrameRow {
  uint64_t frame;
  uint32_t step;
  double upload_ms, draw_ms, readback_ms, interval_ms;
  bool written;  // a PNG was written for this frame
};

class SnapshotExchange {
 public:
  // Simulation side: fills the back slot through `fill`, publishes it. With `capture`, waits until
  // the render side has taken it (or the exchange is closed).
  template <typename Fill>
  void publish(Fill&& fill, bool capture) {
    Snapshot& slot = slots_[back_];
    fill(slot, slot_sequence_[back_]);
    slot.capture = capture;
    std::unique_lock<std::mutex> lock(mutex_);
    slot.sequence = ++published_;
    slot_sequence_[back_] = slot.sequence;
    std::swap(back_, middle_);
    fresh_ = true;
    taken_.notify_all();
    if (capture) {
      const uint64_t sequence = published_;
      taken_.wait(lock, [&] { return consumed_ >= sequence || closed_; });
    }
  }

  // Render side: the newest snapshot not seen yet, or nullptr. Valid until the next take().
  const Snapshot* take() {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!fresh_) return nullptr;
    std::swap(front_, middle_);
    fresh_ = false;
    consumed_ = slots_[front_].sequence;
    taken_.notify_all();
    return &slots_[front_];
  }

  // Render side: waits (up to `ms`) for a fresh snapshot or the end.
  void wait(int ms) {
    std::unique_lock<std::mutex> lock(mutex_);
    taken_.wait_for(lock, std::chrono::milliseconds(ms), [&] { return fresh_ || finished_; });
  }

  // The simulation finished (no more snapshots) / the consumer went away (never wait again).
  void finish() {
    std::lock_guard<std::mutex> lock(mutex_);
    finished_ = true;
    taken_.notify_all();
  }
  void close() {
    std::lock_guard<std::mutex> lock(mutex_);
    closed_ = true;
    taken_.notify_all();
  }
  bool finished() {
    std::lock_guard<std::mutex> lock(mutex_);
    return finished_ && !fresh_;
  }

 private:
  Snapshot slots_[3];
  uint64_t slot_sequence_[3] = {0, 0, 0};  // sequence each slot last held (for incremental filling)
  int back_ = 0, middle_ = 1, front_ = 2;
  bool fresh_ = false, finished_ = false, closed_ = false;
  uint64_t published_ = 0, consumed_ = 0;
  std::mutex mutex_;
  std::condition_variable taken_;
};

// Copies the surface into a snapshot slot: positions in full (they all move under physics), the
// triangle slots changed since the slot's last fill (`history` holds the dirty ranges of the recent
// publishes, newest last; an older slot is copied in full).
struct DirtyHistory {
  // Publishes remembered: a slot that missed more is copied in full (with three slots a slot rarely
  // misses more than a few publishes).
  static constexpr size_t kKept = 8;
  std::vector<std::pair<uint32_t, uint32_t>> ranges;  // per publish, sequence = first_sequence + index
  uint64_t first_sequence = 1;
};
void fill_snapshot(Snapshot& slot, uint64_t slot_sequence, const CutSurface& surface, const std::vector<Vec3f>* deformed,
                   DirtyHistory& history, uint32_t step, const StepTimings& timings);

// The vertices that cast the tray's shadow: the snapshot's positions where a live triangle uses the
// slot, NaN elsewhere (a vertex slot no triangle uses may keep a stale position; the shadow grid
// skips NaN). Used by the window and the headless renderer alike.
void shadow_casters(const Snapshot& snapshot, std::vector<Vec3f>& out);

}  // namespace dvx
