#pragma once
// How well a run marked its panel, judged against the rig's ground truth.
//
// For every spray: the point where the nozzle's axis meets the panel's surface at the
// moment of spraying, against each true defect centre at that moment. A defect is
// marked when a spray lands within the radius of it; a spray that lands within the
// radius of no defect (or misses the panel) is a false spray. Defects the controller
// skipped are listed with its reasons.
//
// Without the recorded panel's surface (a recording of a panel the rig has no shape of),
// a spray is scored on its aim alone: the distance of the nozzle's axis from each true
// defect centre, never on another panel's surface.
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "markcell/common/time.hpp"
#include "markcell/rig/render.hpp"

namespace markcell::rig {

struct Spray {
  Nanos time = 0;
  // The nozzle's pose; it sprays along its -z axis (the tool frame O_V has z out of
  // the surface, towards the cameras, so the nozzle looks back along it).
  Eigen::Isometry3d X_CamR_Nozzle = Eigen::Isometry3d::Identity();
  Nanos open_for = -1;  // the valve's opening as the simulated world saw it; -1: unknown
};

struct TrueDefect {
  int id = 0;
  Eigen::Vector3d p_Panel = Eigen::Vector3d::Zero();
};

struct SkippedDefect {
  int id = 0;
  std::string reason;
};

enum class ScoredOn { kSurface, kAim };

struct SprayResult {
  Nanos time = 0;
  bool on_panel = false;            // the axis met panel material (always false scored on the aim)
  Eigen::Vector3d p_CamR = Eigen::Vector3d::Zero();  // where, when on_panel
  int nearest_defect = -1;          // id, -1 when there is no defect
  double distance = 0;              // to that defect's centre (from the axis, scored on the aim), m
  bool hit = false;                 // within the radius
  double standoff = 0;              // nozzle to the true surface along its axis, m (when on_panel)
  Nanos open_for = -1;              // the spray's Spray::open_for
};

struct DefectResult {
  int id = 0;
  bool marked = false;
  double error = 0;                 // distance of the best spray, m (when sprayed at)
  bool sprayed_at = false;
  std::string skipped_reason;       // when the controller skipped it
};

struct Score {
  ScoredOn scored_on = ScoredOn::kSurface;
  std::vector<SprayResult> sprays;
  std::vector<DefectResult> defects;
  int planned = 0;                  // defects the controller did not skip
  int marked = 0;
  int skipped = 0;
  int false_sprays = 0;
  double error_max = 0;             // over marked defects, m
  double error_rms = 0;
};

Score score_sprays(const rig::Panel& panel, const std::function<Eigen::Isometry3d(Nanos)>& X_CamR_Panel_at,
                   const std::vector<TrueDefect>& defects, const std::vector<Spray>& sprays,
                   const std::vector<SkippedDefect>& skipped, double radius);
// The same on the aim alone (ScoredOn::kAim): no surface.
Score score_sprays_by_aim(const std::function<Eigen::Isometry3d(Nanos)>& X_CamR_Panel_at, const std::vector<TrueDefect>& defects,
                          const std::vector<Spray>& sprays, const std::vector<SkippedDefect>& skipped, double radius);

}  // namespace markcell::rig
