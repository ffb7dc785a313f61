#include "markcell/tools/capacity.hpp"

#include <cstdio>
#include <vector>

#include "markcell/control/planner.hpp"
#include "markcell/host/cell.hpp"

namespace markcell::host {

Capacity marking_capacity(const CellConfig& config, const Eigen::Isometry3d& X_Base_CamR, double speed, double spacing,
                          double depth, double length) {
  const control::ArmTimingModel arm = arm_timing_model(config);
  Capacity c;
  c.speed = speed;
  c.spacing = spacing;
  const Eigen::Vector3d dir_CamR = config.marking.line_direction_CamR.normalized();
  const Eigen::Vector3d dir = X_Base_CamR.linear() * dir_CamR;
  // The nozzle in front of a defect on the optical axis's height, at s along the line.
  const auto nozzle = [&](double s) {
    return Eigen::Vector3d(X_Base_CamR * (Eigen::Vector3d(0, 0, depth - config.marking.standoff) + s * dir_CamR));
  };
  // Along the line (s in metres) the nozzles are within reach for [enter, leave].
  double enter = 0, leave = 0;
  if (!control::reach_interval(nozzle(0.0), dir, arm.reach, enter, leave)) return c;  // never: capacity 0
  c.window_s = speed > 0 ? (leave - enter) / speed : 0;
  c.seconds_per_defect = control::move_seconds(arm, spacing) + to_seconds(arm.settle) + to_seconds(arm.pulse);

  c.row = std::min(kCapacityMaxDefects, static_cast<int>(length / spacing + 1e-9) + 1);
  std::vector<control::PlanDefect> row(static_cast<std::size_t>(c.row));
  std::vector<control::PlanEntry> out(static_cast<std::size_t>(c.row));
  for (int k = 0; k < c.row; ++k)
    row[static_cast<std::size_t>(k)] = control::PlanDefect{k, nozzle(enter - k * spacing), true};
  const Eigen::Vector3d home(config.arm.limits.home[0], config.arm.limits.home[1], config.arm.limits.home[2]);
  control::plan_marking(row, home, dir * speed, arm, out);
  c.defects = c.row;
  for (int k = 0; k < c.row; ++k)
    if (out[static_cast<std::size_t>(k)].verdict != control::PlanVerdict::kFeasible) {
      c.defects = k;
      break;
    }
  return c;
}

std::string capacity_table(const CellConfig& config, const Eigen::Isometry3d& X_Base_CamR, const std::vector<double>& speeds,
                           const std::vector<double>& spacings, double depth, double length) {
  std::string t;
  char line[160];
  std::snprintf(line, sizeof line,
                "arm: %.2f m/s, %.2f m/s^2, reach %.2f m; %.0f ms settle + %.0f ms pulse per defect; panel %.2f m from CamR\n",
                config.arm.limits.max_tcp_speed, config.arm.limits.max_tcp_accel, config.arm.limits.reach,
                to_seconds(config.marking.timing.settle) * 1e3, to_seconds(config.spray.pulse) * 1e3, depth);
  t += line;
  std::snprintf(line, sizeof line, "a row of defects along the line on a %.2f m panel\n", length);
  t += line;
  t += "line speed   spacing   s/defect   in reach   marked in one pass\n";
  for (const double v : speeds)
    for (const double d : spacings) {
      const Capacity c = marking_capacity(config, X_Base_CamR, v, d, depth, length);
      std::snprintf(line, sizeof line, "%6.1f cm/s  %5.0f cm   %6.2f s   %6.1f s   ", v * 100, d * 100, c.seconds_per_defect,
                    c.window_s);
      t += line;
      std::snprintf(line, sizeof line, "%d of %d%s\n", c.defects, c.row, c.defects == c.row ? " (all)" : "");
      t += line;
    }
  return t;
}

}  // namespace markcell::host
