#pragma once
// How a panel moves down the line in the rig: a speed profile along a path that may
// turn about the vertical axis (a curved line section, the paper's sled rotated about
// Y0). Deterministic from its seed; integrated once on a 1 ms grid, so every query of
// the same motion gives the same pose, bit for bit.
#include <cstdint>
#include <vector>

#include <Eigen/Geometry>

#include "markcell/common/time.hpp"

namespace markcell::rig {

enum class SpeedKind : std::uint8_t { kConstant, kFluctuating, kStopAndGo };

struct SpeedProfile {
  SpeedKind kind = SpeedKind::kConstant;
  double min_speed = 0.014;   // m/s; constant: the speed is min_speed
  double max_speed = 0.014;   // m/s; fluctuating: stays within [min, max]
  double stop_and_go_run_s = 4.0;   // stop-and-go: seconds moving at max_speed ...
  double stop_and_go_stop_s = 2.0;  // ... then seconds stopped
  double accel = 0.05;        // m/s^2, stop-and-go ramps
  std::uint64_t seed = 1;     // fluctuation pattern
};

struct LinePath {
  // The line's frame L in the right camera's frame: x along the travel, y up, z towards
  // the cameras, origin where the panel's centre starts.
  Eigen::Isometry3d X_CamR_Line = Eigen::Isometry3d::Identity();
  double curve_start_m = 1e9;  // distance travelled before the line starts to turn
  double curvature = 0.0;      // 1/m about the vertical axis (y); > 0 turns towards the cameras
};

class LineMotion {
 public:
  LineMotion(const SpeedProfile& speed, const LinePath& path, Nanos duration);
  Nanos duration() const { return duration_; }
  double distance(Nanos t) const;  // metres travelled at t (t clamped to [0, duration])
  double speed(Nanos t) const;     // m/s at t
  Eigen::Isometry3d X_Line_Panel(Nanos t) const;
  Eigen::Isometry3d X_CamR_Panel(Nanos t) const { return path_.X_CamR_Line * X_Line_Panel(t); }
  double heading(Nanos t) const;   // rad about the vertical axis

 private:
  LinePath path_;
  Nanos duration_;
  std::vector<double> distance_;  // at every millisecond
  std::vector<double> speed_;
};

}  // namespace markcell::rig
