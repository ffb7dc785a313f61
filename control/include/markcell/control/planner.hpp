#pragma once
// Planning a panel's marking (paper section IV): given where each defect's spraying pose
// is now and how the line moves it, the order of the defects and, for each, whether the
// arm can be there, settled, and spray before the panel carries it out of reach.
//
// The model: the arm moves rest to rest at its TCP speed and acceleration limits
// (trapezoid, or triangle for short moves) to intercept the moving target, then needs
// `settle` on it before the pulse; the line moves every defect at the same constant
// velocity; the arm reaches a sphere of `reach` about the base origin. The marking
// sequence plans with it once the panel's motion is known, and `markcell capacity`
// answers the paper's trade-off with the same code: how many defects at spacing d fit
// on one pass.
//
// Bounded: every loop has a fixed upper bound; no allocation (the caller owns the storage).
#include <cstdint>
#include <span>
#include <string_view>

#include <Eigen/Core>

#include "markcell/common/time.hpp"
#include "markcell/drivers/sim_arm.hpp"

namespace markcell::control {

// The arm's limits default to the arm model's (drivers::SimArmLimits: declared there once);
// the cell sets them from `devices.arm.limits`.
struct ArmTimingModel {
  double max_speed = drivers::SimArmLimits{}.max_speed;  // m/s, TCP
  double max_accel = drivers::SimArmLimits{}.max_accel;  // m/s^2
  double reach = drivers::SimArmLimits{}.reach;          // m, from the base origin
  Nanos settle = millis(150);  // on target before the pulse: command lead, pursuit, settle time
  Nanos pulse = millis(80);
  Nanos defect_timeout = seconds(6);  // the sequence gives up on a defect after this
  Nanos horizon = seconds(120);       // a defect not in reach within this is never in reach
};

// Rest-to-rest time over `distance` at the model's limits.
double move_seconds(const ArmTimingModel& arm, double distance);

// When a point starting at p0 and moving at v is within `reach` of the origin: the times
// [t_in, t_out] (the whole line for one standing inside). False: never.
bool reach_interval(const Eigen::Vector3d& p0, const Eigen::Vector3d& v, double reach, double& t_in, double& t_out);

struct PlanDefect {
  int index = 0;                                        // the caller's (the job's defect index)
  Eigen::Vector3d position_Base = Eigen::Vector3d::Zero();  // spraying pose of the nozzle at t = 0
  bool usable = true;                                   // false: skipped before planning (tool pose)
};

enum class PlanVerdict : std::uint8_t {
  kFeasible,
  kLeavesReach,   // in reach, but gone before the arm's turn comes
  kNeverInReach,  // the line never brings it within reach (within the horizon)
  kTooLong,       // not sprayed within the sequence's per-defect timeout of its turn (or of entering reach)
  kNotPlanned,    // not usable (skipped before planning)
};
std::string_view to_string(PlanVerdict v);

struct PlanEntry {
  int index = 0;
  PlanVerdict verdict = PlanVerdict::kNotPlanned;
  double spray_time = 0;  // s from t = 0 (feasible only)
};

struct Plan {
  int feasible = 0;
  int infeasible = 0;
  double finish_time = 0;  // s: the last feasible pulse ends
};

// Plans the defects in the order given (downstream first is the caller's choice: the
// line takes those out of reach first). `arm_Base` is where the tool is at t = 0;
// `line_velocity_Base` moves every defect. Infeasible defects are passed over and cost
// no time. out[i] answers defects[i]; out.size() >= defects.size().
Plan plan_marking(std::span<const PlanDefect> defects, const Eigen::Vector3d& arm_Base,
                  const Eigen::Vector3d& line_velocity_Base, const ArmTimingModel& arm, std::span<PlanEntry> out);

}  // namespace markcell::control
