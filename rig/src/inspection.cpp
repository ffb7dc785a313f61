#include "markcell/rig/inspection.hpp"

#include <cmath>

#include "markcell/common/geometry.hpp"
#include "markcell/common/splitmix.hpp"

namespace markcell::rig {

InspectionRecord simulate_inspection(const std::string& panel_id, const rig::Panel& panel,
                                     const std::vector<DefectSpec>& defects, const vision::StereoCalibration& scanner,
                                     const Eigen::Isometry3d& X_SL_Panel, const InspectionNoise& noise, std::uint64_t seed) {
  // The project's own generator and transforms, each draw in a statement of its own: the
  // same seed gives the same record on every compiler and architecture (docs/determinism.md).
  SplitMix rng{seed};
  const auto pixel_noise = [&rng, &noise] {
    const double du = rng.normal(0.0, noise.pixel_sigma);
    const double dv = rng.normal(0.0, noise.pixel_sigma);
    return Eigen::Vector2d(du, dv);
  };
  InspectionRecord r;
  r.panel_id = panel_id;
  r.panel_type = panel.name;
  // CamL_SL is the scanner's frame: its left camera is the origin, the right one sits
  // at X_CamR_CamL of the scanner's calibration.
  const Eigen::Isometry3d X_CamR_SL = scanner.X_CamR_CamL;
  geometry::ProjectionMatrix P_left = geometry::ProjectionMatrix::Zero(), P_right;
  P_left.leftCols<3>() = scanner.left.K;
  P_right = scanner.right.K * X_CamR_SL.matrix().topRows<3>();
  for (const auto& mf : panel.macro_features) {
    const Eigen::Vector3d p_SL = X_SL_Panel * mf;
    const Eigen::Vector2d xl = rig::project_point(scanner.left, p_SL) + pixel_noise();
    const Eigen::Vector2d xr = rig::project_point(scanner.right, X_CamR_SL * p_SL) + pixel_noise();
    r.macro_features_SL.push_back(geometry::triangulate(P_left, P_right, xl, xr));
  }
  for (const auto& d : defects) {
    InspectionDefect out;
    out.id = d.id;
    for (int i = 0; i < noise.points_per_defect; ++i) {
      // Uniform over the disc around the centre, on the surface, pressed in by the ding.
      const double rho = d.radius * std::sqrt(rng.unit());
      const double phi = 2 * M_PI * rng.unit();
      const double x = d.x + rho * std::cos(phi), y = d.y + rho * std::sin(phi);
      const double dent = noise.ding_depth * std::exp(-0.5 * (rho * rho) / (0.4 * d.radius * 0.4 * d.radius));
      const double pressed = dent + rng.normal(0.0, noise.depth_sigma);
      const MeshHit front = panel.surface->from_front(x, y);
      if (!front.hit()) continue;  // over a hole or past an edge: the scanner sees no surface there
      out.points_SL.push_back(X_SL_Panel * (front.p - front.normal * pressed));
    }
    r.defects.push_back(out);
  }
  return r;
}

}  // namespace markcell::rig
