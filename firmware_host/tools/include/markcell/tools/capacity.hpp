#pragma once
// `markcell capacity`: the paper's trade-off (section IV), how many defects at spacing d
// along the line one pass can mark at a line speed, answered by the same planner the
// marking sequence uses (control/planner.hpp).
//
// The set-up: a row of defects `spacing` apart along the line's travel, as many as a panel
// `length` long carries, `depth` in front of CamR at the height of its optical axis; the
// nozzle `standoff` in front of each; at t = 0 the most downstream defect enters the
// arm's reach and the arm is at home. The arm marks them downstream first, waiting for
// those the line has yet to bring within reach.
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "markcell/host/config.hpp"

namespace markcell::host {

inline constexpr int kCapacityMaxDefects = 200;  // the longest row it plans

struct Capacity {
  double speed = 0;              // m/s
  double spacing = 0;            // m
  int row = 0;                   // defects on the row (the panel's length / spacing + 1)
  int defects = 0;               // marked in one pass before the first that cannot be
  double seconds_per_defect = 0; // in the steady state: move over the spacing, settle, pulse
  double window_s = 0;           // how long each defect stays within reach
};

Capacity marking_capacity(const CellConfig& config, const Eigen::Isometry3d& X_Base_CamR, double speed, double spacing,
                          double depth, double length);

// The table `markcell capacity` prints.
std::string capacity_table(const CellConfig& config, const Eigen::Isometry3d& X_Base_CamR, const std::vector<double>& speeds,
                           const std::vector<double>& spacings, double depth, double length);

}  // namespace markcell::host
