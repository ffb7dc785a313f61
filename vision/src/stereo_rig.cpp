#include "markcell/vision/stereo_rig.hpp"

#include <cmath>

#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>

#include "markcell/common/check.hpp"

namespace markcell::vision {

namespace {
std::array<double, 5> five_coefficients(const CameraModel& m, const char* which) {
  std::array<double, 5> d{};
  if (m.distortion.empty()) return d;
  const auto n = static_cast<int>(m.distortion.total());
  // Rational and thin-prism models (8+ coefficients) need more than this tracker inverts.
  MARKCELL_THROW_UNLESS(n == 4 || n == 5 || std::abs(cv::norm(m.distortion.colRange(std::min(n, 5), n))) == 0.0,
                        which << " camera: only k1 k2 p1 p2 k3 are supported, the calibration has " << n
                              << " non-zero coefficients");
  for (int i = 0; i < std::min(n, 5); ++i) d[static_cast<std::size_t>(i)] = m.distortion.at<double>(i);
  return d;
}

Eigen::Matrix3d skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d S;
  S << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return S;
}

// Normalised image point -> distorted normalised point (Brown-Conrady, OpenCV's order).
Eigen::Vector2d distort(const std::array<double, 5>& d, const Eigen::Vector2d& n) {
  const double x = n.x(), y = n.y(), r2 = x * x + y * y;
  const double radial = 1 + d[0] * r2 + d[1] * r2 * r2 + d[4] * r2 * r2 * r2;
  return {x * radial + 2 * d[2] * x * y + d[3] * (r2 + 2 * x * x), y * radial + d[2] * (r2 + 2 * y * y) + 2 * d[3] * x * y};
}
}  // namespace

StereoRig::StereoRig(const StereoCalibration& calibration) : calibration_(calibration) {
  MARKCELL_THROW_UNLESS(calibration.left.width > 0 && calibration.left.width == calibration.right.width &&
                            calibration.left.height == calibration.right.height,
                        "left " << calibration.left.width << "x" << calibration.left.height << ", right "
                                << calibration.right.width << "x" << calibration.right.height);
  dist_L_ = five_coefficients(calibration.left, "left");
  dist_R_ = five_coefficients(calibration.right, "right");
  X_CamL_CamR_ = calibration.X_CamR_CamL.inverse();
  P_R_.setZero();
  P_R_.leftCols<3>() = calibration.right.K;
  P_L_.leftCols<3>() = calibration.left.K * X_CamL_CamR_.linear();
  P_L_.col(3) = calibration.left.K * X_CamL_CamR_.translation();
  // x_R^T K_R^-T [t]x R K_L^-1 x_L = 0 with p_R = R p_L + t.
  const Eigen::Matrix3d E = skew(calibration.X_CamR_CamL.translation()) * calibration.X_CamR_CamL.linear();
  F_ = calibration.right.K.inverse().transpose() * E * calibration.left.K.inverse();
  // OpenCV's convention: camera 1 = left, R and T map camera-1 points into camera 2.
  cv::Mat K1, K2, R, T, R1, R2, P1, P2, Q;
  cv::eigen2cv(calibration.left.K, K1);
  cv::eigen2cv(calibration.right.K, K2);
  cv::eigen2cv(Eigen::Matrix3d(calibration.X_CamR_CamL.linear()), R);
  cv::eigen2cv(Eigen::Vector3d(calibration.X_CamR_CamL.translation()), T);
  const cv::Mat D1 = calibration.left.distortion.empty() ? cv::Mat::zeros(1, 5, CV_64F) : calibration.left.distortion;
  const cv::Mat D2 = calibration.right.distortion.empty() ? cv::Mat::zeros(1, 5, CV_64F) : calibration.right.distortion;
  cv::stereoRectify(K1, D1, K2, D2, cv::Size(width(), height()), R, T, R1, R2, P1, P2, Q, cv::CALIB_ZERO_DISPARITY, 0);
  cv::cv2eigen(R1, R1_);
  cv::cv2eigen(R2, R2_);
  cv::cv2eigen(P1, P1_);
  cv::cv2eigen(P2, P2_);
}

Eigen::Vector2d StereoRig::rectify(Camera c, const Eigen::Vector2d& px) const {
  const Eigen::Matrix3d& K = model(c).K;
  const Eigen::Vector2d u = undistort(c, px);
  const Eigen::Vector3d ray = R_rect(c) * Eigen::Vector3d((u.x() - K(0, 2)) / K(0, 0), (u.y() - K(1, 2)) / K(1, 1), 1.0);
  return (P_rect(c).leftCols<3>() * ray).hnormalized();
}

Eigen::Vector2d StereoRig::undistort(Camera c, const Eigen::Vector2d& px) const {
  const auto& d = c == Camera::kLeft ? dist_L_ : dist_R_;
  const Eigen::Matrix3d& K = model(c).K;
  const Eigen::Vector2d observed((px.x() - K(0, 2)) / K(0, 0), (px.y() - K(1, 2)) / K(1, 1));
  Eigen::Vector2d n = observed;
  for (int round = 0; round < 20; ++round) {  // fixed-point iteration, as cv::undistortPoints
    const Eigen::Vector2d err = distort(d, n) - observed;
    n -= err;
    if (err.squaredNorm() < 1e-24) break;
  }
  return {n.x() * K(0, 0) + K(0, 2), n.y() * K(1, 1) + K(1, 2)};
}

Eigen::Vector2d StereoRig::project(Camera c, const Eigen::Vector3d& p_CamR) const {
  const Eigen::Vector3d p = c == Camera::kLeft ? Eigen::Vector3d(X_CamL_CamR_ * p_CamR) : p_CamR;
  const Eigen::Vector2d n = distort(c == Camera::kLeft ? dist_L_ : dist_R_, p.head<2>() / p.z());
  const Eigen::Matrix3d& K = model(c).K;
  return {K(0, 0) * n.x() + K(0, 1) * n.y() + K(0, 2), K(1, 1) * n.y() + K(1, 2)};
}

double StereoRig::epipolar_distance(const Eigen::Vector2d& xL, const Eigen::Vector2d& xR) const {
  const Eigen::Vector3d l = F_ * xL.homogeneous();             // line in the right image
  const Eigen::Vector3d m = F_.transpose() * xR.homogeneous();  // line in the left image
  const double e = xR.homogeneous().dot(l);
  return 0.5 * (std::abs(e) / l.head<2>().norm() + std::abs(e) / m.head<2>().norm());
}

Eigen::Vector3d StereoRig::triangulate_observed(const Eigen::Vector2d& xL, const Eigen::Vector2d& xR) const {
  return geometry::triangulate(P_L_, P_R_, undistort(Camera::kLeft, xL), undistort(Camera::kRight, xR));
}

}  // namespace markcell::vision
