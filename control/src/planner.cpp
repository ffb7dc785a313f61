#include "markcell/control/planner.hpp"

#include <algorithm>
#include <cmath>

namespace markcell::control {

std::string_view to_string(PlanVerdict v) {
  switch (v) {
    case PlanVerdict::kFeasible: return "feasible";
    case PlanVerdict::kLeavesReach: return "leaves the arm's reach before its turn";
    case PlanVerdict::kNeverInReach: return "never within the arm's reach";
    case PlanVerdict::kTooLong: return "not within the per-defect timeout";
    case PlanVerdict::kNotPlanned: return "not planned";
  }
  return "?";
}

double move_seconds(const ArmTimingModel& arm, double d) {
  const double v = arm.max_speed, a = arm.max_accel;
  if (d <= 0) return 0;
  if (d >= v * v / a) return d / v + v / a;  // accelerate, cruise, brake
  return 2.0 * std::sqrt(d / a);             // accelerate, brake
}

namespace {
constexpr int kInterceptRounds = 30;
constexpr double kReachStep = 0.02;  // s, search for the time a defect enters reach
}  // namespace

Plan plan_marking(std::span<const PlanDefect> defects, const Eigen::Vector3d& arm_Base, const Eigen::Vector3d& velocity,
                  const ArmTimingModel& arm, std::span<PlanEntry> out) {
  Plan plan;
  Eigen::Vector3d at = arm_Base;
  double t = 0;  // when the arm is free
  const double settle = to_seconds(arm.settle), pulse = to_seconds(arm.pulse);
  const double timeout = to_seconds(arm.defect_timeout), horizon = to_seconds(arm.horizon);
  const auto in_reach = [&](const Eigen::Vector3d& p0, double time) { return (p0 + velocity * time).norm() <= arm.reach; };
  const std::size_t n = std::min(defects.size(), out.size());
  for (std::size_t k = 0; k < n; ++k) {
    const PlanDefect& d = defects[k];
    PlanEntry& e = out[k];
    e.index = d.index;
    e.spray_time = 0;
    if (!d.usable) {
      e.verdict = PlanVerdict::kNotPlanned;
      continue;
    }
    // Intercept: the smallest travel time T with move(|target(t + T) - at|) <= T, by
    // fixed-point rounds from T = 0 (monotone while the line is slower than the arm).
    double T = 0;
    for (int round = 0; round < kInterceptRounds; ++round) {
      const double need = move_seconds(arm, (d.position_Base + velocity * (t + T) - at).norm());
      if (std::abs(need - T) < 1e-4) break;
      T = need;
    }
    double spray = t + T + settle;
    double ready = t;  // from when the defect is the arm's and within reach
    // Not in reach then: the line may bring it later (the arm waits where it will enter),
    // or it was in reach and left while the arm was busy, or it never comes.
    if (!in_reach(d.position_Base, spray)) {
      const int steps = static_cast<int>(horizon / kReachStep);  // bounded search
      int enter = -1;
      bool earlier = false;
      for (int i = 0; i <= steps; ++i) {
        const double s = t + i * kReachStep;
        const bool inside = in_reach(d.position_Base, s);
        if (inside && s >= spray) {
          enter = i;
          break;
        }
        earlier = earlier || inside;
      }
      if (enter < 0 || earlier) {
        e.verdict = earlier ? PlanVerdict::kLeavesReach : PlanVerdict::kNeverInReach;
        ++plan.infeasible;
        continue;
      }
      const double s = t + enter * kReachStep;
      ready = s;
      spray = std::max(s, t + move_seconds(arm, (d.position_Base + velocity * s - at).norm()) + settle);
      if (!in_reach(d.position_Base, spray)) {  // entered and left again while the arm came
        e.verdict = PlanVerdict::kLeavesReach;
        ++plan.infeasible;
        continue;
      }
    }
    if (spray - ready > timeout) {
      e.verdict = PlanVerdict::kTooLong;
      ++plan.infeasible;
      continue;
    }
    e.verdict = PlanVerdict::kFeasible;
    e.spray_time = spray;
    ++plan.feasible;
    at = d.position_Base + velocity * spray;
    t = spray + pulse;
    plan.finish_time = t;
  }
  return plan;
}

}  // namespace markcell::control
