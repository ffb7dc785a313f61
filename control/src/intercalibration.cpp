#include "markcell/control/intercalibration.hpp"

#include <algorithm>
#include <cmath>

#include <Eigen/Eigenvalues>

#include "markcell/common/geometry.hpp"

namespace markcell::control {

namespace {
// How a point at lever c from the centroid moves with the fit's (dp, dtheta): [I, -[c]x].
Eigen::Matrix<double, 3, 6> placement_jacobian(const Eigen::Vector3d& c) {
  Eigen::Matrix<double, 3, 6> J;
  J.leftCols<3>().setIdentity();
  J.rightCols<3>() << 0, c.z(), -c.y(), -c.z(), 0, c.x(), c.y(), -c.x(), 0;
  return J;
}
}  // namespace

double Intercalibration::placement_sigma(const Eigen::Vector3d& p_P) const {
  const Eigen::Matrix<double, 3, 6> J = placement_jacobian(p_P - centroid_P);
  const Eigen::Matrix3d cov = J * covariance * J.transpose();
  return std::sqrt(std::max(0.0, Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(cov, Eigen::EigenvaluesOnly).eigenvalues().maxCoeff()));
}

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
  geometry::RobustFitOptions options;
  options.inlier_threshold = limits.inlier_threshold;
  const geometry::RigidFit fit =
      geometry::fit_rigid_robust(std::span(a.data(), n), std::span(b.data(), n), options, std::span(inlier.data(), n));
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
  // Covariance: one MF's noise from the residuals (3 per MF, 6 taken by the fit), never
  // below the stations' own; a fitted point moves by dp + dtheta x (b - centroid), and the
  // information is the sum of J^T J / sigma^2 over the inliers. A rotation no layout pins
  // down (collinear MFs) keeps a radian's uncertainty instead of an infinite one.
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < n; ++i)
    if (inlier[i]) centroid += b[i];
  centroid /= r.inliers;
  const int dof = 3 * r.inliers - 6;
  const double sigma2 = std::max(limits.point_sigma * limits.point_sigma, dof > 0 ? sq.sum() / dof : 0.0);
  Eigen::Matrix<double, 6, 6> info = Eigen::Matrix<double, 6, 6>::Zero();
  for (std::size_t i = 0; i < n; ++i) {
    if (!inlier[i]) continue;
    const Eigen::Matrix<double, 3, 6> J = placement_jacobian(b[i] - centroid);
    info += J.transpose() * J / sigma2;
  }
  info.bottomRightCorner<3, 3>().diagonal().array() += 1.0;
  r.centroid_P = centroid;
  r.covariance = info.inverse();
  r.status = r.paired - r.inliers > limits.max_outliers ? IntercalibrationStatus::kOutliers
             : r.max_abs.maxCoeff() > limits.max_abs_error ? IntercalibrationStatus::kAboveLimit
                                                           : IntercalibrationStatus::kOk;
  return r;
}

}  // namespace markcell::control
