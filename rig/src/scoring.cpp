#include "markcell/rig/scoring.hpp"

#include <cmath>
#include <limits>

namespace markcell::rig {

namespace {
// `panel` null: scored on the aim.
Score score(const rig::Panel* panel, const std::function<Eigen::Isometry3d(Nanos)>& X_CamR_Panel_at,
            const std::vector<TrueDefect>& defects, const std::vector<Spray>& sprays, const std::vector<SkippedDefect>& skipped,
            double radius) {
  Score score;
  score.scored_on = panel != nullptr ? ScoredOn::kSurface : ScoredOn::kAim;
  for (const auto& d : defects) {
    DefectResult r;
    r.id = d.id;
    for (const auto& s : skipped)
      if (s.id == d.id) r.skipped_reason = s.reason;
    score.defects.push_back(r);
  }
  for (const auto& spray : sprays) {
    SprayResult r;
    r.time = spray.time;
    r.open_for = spray.open_for;
    const Eigen::Isometry3d X_CamR_Panel = X_CamR_Panel_at(spray.time);
    const Eigen::Isometry3d X_Panel_Nozzle = X_CamR_Panel.inverse() * spray.X_CamR_Nozzle;
    const Eigen::Vector3d o = X_Panel_Nozzle.translation();
    const Eigen::Vector3d d = -X_Panel_Nozzle.linear().col(2);  // unit: a rotation's column
    const double t = panel != nullptr ? rig::intersect_panel(*panel, o, d) : 1.0;
    if (t > 0) {
      r.on_panel = panel != nullptr;
      if (r.on_panel) r.standoff = t;  // d is a unit vector
      const Eigen::Vector3d p_Panel = o + t * d;
      r.p_CamR = X_CamR_Panel * p_Panel;
      double best = std::numeric_limits<double>::infinity();
      for (std::size_t i = 0; i < defects.size(); ++i) {
        // On the surface: landing point to centre. On the aim: the centre's distance from
        // the axis, for a centre in front of the nozzle (behind it: never hit).
        const Eigen::Vector3d c = defects[i].p_Panel - o;
        const double along = c.dot(d);
        const double dist = panel != nullptr ? (defects[i].p_Panel - p_Panel).norm()
                            : along > 0      ? (c - along * d).norm()
                                             : std::numeric_limits<double>::infinity();
        if (panel == nullptr && dist < best) r.p_CamR = X_CamR_Panel * (o + along * d);  // the axis's nearest point
        if (dist < best) {
          best = dist;
          r.nearest_defect = defects[i].id;
        }
        DefectResult& dr = score.defects[i];
        if (dist <= radius) {
          if (!dr.sprayed_at || dist < dr.error) dr.error = dist;
          dr.sprayed_at = true;
          dr.marked = true;
        }
      }
      r.distance = best;
      r.hit = best <= radius;
    }
    if (!r.hit) ++score.false_sprays;
    score.sprays.push_back(r);
  }
  double sum_sq = 0;
  for (const auto& d : score.defects) {
    if (!d.skipped_reason.empty()) ++score.skipped;
    else ++score.planned;
    if (d.marked) {
      ++score.marked;
      score.error_max = std::max(score.error_max, d.error);
      sum_sq += d.error * d.error;
    }
  }
  score.error_rms = score.marked > 0 ? std::sqrt(sum_sq / score.marked) : 0.0;
  return score;
}
}  // namespace

Score score_sprays(const rig::Panel& panel, const std::function<Eigen::Isometry3d(Nanos)>& X_CamR_Panel_at,
                   const std::vector<TrueDefect>& defects, const std::vector<Spray>& sprays,
                   const std::vector<SkippedDefect>& skipped, double radius) {
  return score(&panel, X_CamR_Panel_at, defects, sprays, skipped, radius);
}

Score score_sprays_by_aim(const std::function<Eigen::Isometry3d(Nanos)>& X_CamR_Panel_at, const std::vector<TrueDefect>& defects,
                          const std::vector<Spray>& sprays, const std::vector<SkippedDefect>& skipped, double radius) {
  return score(nullptr, X_CamR_Panel_at, defects, sprays, skipped, radius);
}

}  // namespace markcell::rig
