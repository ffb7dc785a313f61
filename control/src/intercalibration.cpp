#include "markcell/control/intercalibration.hpp"

#include <algorithm>
#include <cmath>

#include "markcell/vision/geometry.hpp"

namespace markcell::control {

std::string_view to_string(IntercalibrationStatus s) {
  switch (s) {
    case IntercalibrationStatus::kOk: return "ok";
    case IntercalibrationStatus::kTooFewPoints: return "too few macro-features on both sides";
    case IntercalibrationStatus::kDegenerate: return "macro-features (nearly) collinear";
    case IntercalibrationStatus::kAboveLimit: return "inter-calibration error above the limit";
    case IntercalibrationStatus::kOutliers: return "macro-features of the record and of the panel disagree";
  }
  return "?";
}

Intercalibration intercalibrate(std::span<const Eigen::Vector3d> mfs_SL, std::span<const Eigen::Vector3d> mfs_P,
                                std::span<const bool> known_P, const IntercalibrationLimits& limits) {
  Intercalibration r;
  std::array<Eigen::Vector3d, kMaxIntercalibrationPoints> a{}, b{};
  std::array<bool, kMaxIntercalibrationPoints> inlier{};
  const std::size_t n_in = std::min({mfs_SL.size(), mfs_P.size(), known_P.size(), a.size()});
  std::size_t n = 0;
  for (std::size_t i = 0; i < n_in; ++i) {
    if (!known_P[i] || !mfs_SL[i].allFinite() || !mfs_P[i].allFinite()) continue;
    a[n] = mfs_SL[i];
    b[n++] = mfs_P[i];
  }
  r.paired = static_cast<int>(n);
  if (r.paired < limits.min_points) return r;
  vision::RobustFitOptions options;
  options.inlier_threshold = limits.inlier_threshold;
  const vision::RigidFit fit =
      vision::fit_rigid_robust(std::span(a.data(), n), std::span(b.data(), n), options, std::span(inlier.data(), n));
  if (!fit.valid) {
    r.status = IntercalibrationStatus::kDegenerate;
    return r;
  }
  r.X_P_SL = fit.X_B_A;
  r.inliers = fit.used;
  if (r.inliers < limits.min_points) {
    r.status = IntercalibrationStatus::kTooFewPoints;
    return r;
  }
  Eigen::Vector3d sq = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < n; ++i) {
    if (!inlier[i]) continue;
    const Eigen::Vector3d e = fit.X_B_A * a[i] - b[i];
    r.max_abs = r.max_abs.cwiseMax(e.cwiseAbs());
    sq += e.cwiseAbs2();
  }
  r.rms = (sq / r.inliers).cwiseSqrt();
  r.status = r.paired - r.inliers > limits.max_outliers ? IntercalibrationStatus::kOutliers
             : r.max_abs.maxCoeff() > limits.max_abs_error ? IntercalibrationStatus::kAboveLimit
                                                           : IntercalibrationStatus::kOk;
  return r;
}

}  // namespace markcell::control
