#include "markcell/control/planner.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

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
}  // namespace

bool reach_interval(const Eigen::Vector3d& p0, const Eigen::Vector3d& v, double reach, double& t_in, double& t_out) {
  // |p0 + v t|^2 = reach^2: a t^2 + b t + c = 0.
  const double a = v.squaredNorm(), b = 2.0 * p0.dot(v), c = p0.squaredNorm() - reach * reach;
  if (a < 1e-18) {  // standing still: always or never
    t_in = -std::numeric_limits<double>::infinity();
    t_out = std::numeric_limits<double>::infinity();
    return c <= 0;
  }
  const double disc = b * b - 4.0 * a * c;
  if (disc < 0) return false;
  const double root = std::sqrt(disc);
  t_in = (-b - root) / (2.0 * a);
  t_out = (-b + root) / (2.0 * a);
  return true;
}

Plan plan_marking(std::span<const PlanDefect> defects, const Eigen::Vector3d& arm_Base, const Eigen::Vector3d& velocity,
                  const ArmTimingModel& arm, std::span<PlanEntry> out) {
  Plan plan;
  Eigen::Vector3d at = arm_Base;
  double t = 0;  // when the arm is free
  const double settle = to_seconds(arm.settle), pulse = to_seconds(arm.pulse);
  const double timeout = to_seconds(arm.defect_timeout), horizon = to_seconds(arm.horizon);
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
    // Within reach while the arm is free: [t_in, t_out] (a straight path through a sphere).
    double t_in = 0, t_out = 0;
    if (!reach_interval(d.position_Base, velocity, arm.reach, t_in, t_out) || t_out < t || t_in > t + horizon) {
      e.verdict = PlanVerdict::kNeverInReach;
      ++plan.infeasible;
      continue;
    }
    if (spray < t_in) {  // not yet: the arm waits where the line will bring it
      ready = t_in;
      spray = std::max(t_in, t + move_seconds(arm, (d.position_Base + velocity * t_in - at).norm()) + settle);
    }
    if (spray > t_out) {  // gone before the arm's turn comes
      e.verdict = PlanVerdict::kLeavesReach;
      ++plan.infeasible;
      continue;
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
