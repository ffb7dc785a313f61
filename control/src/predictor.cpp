#include "markcell/control/predictor.hpp"

#include <cmath>

namespace markcell::control {

std::string_view to_string(PredictorKind kind) { return kind == PredictorKind::kTwoFrame ? "two-frame" : "kalman"; }

namespace {
Eigen::Vector3d log_rotation(const Eigen::Matrix3d& R) {
  const Eigen::AngleAxisd aa(R);
  return aa.axis() * aa.angle();
}
Eigen::Matrix3d exp_rotation(const Eigen::Vector3d& r) {
  const double angle = r.norm();
  if (angle < 1e-15) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, r / angle).toRotationMatrix();
}
}  // namespace

void PosePredictor::reset(const Eigen::Vector3d& anchor_P) {
  anchor_P_ = anchor_P;
  count_ = 0;
  last_time_ = 0;
}

bool PosePredictor::ready() const { return params_.kind == PredictorKind::kTwoFrame ? count_ >= 2 : count_ >= 1; }

Eigen::Isometry3d PosePredictor::compose(const Eigen::Vector3d& anchor_CamR, const Eigen::Vector3d& rotvec) const {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = exp_rotation(rotvec) * R_ref_;
  X.translation() = anchor_CamR - X.linear() * anchor_P_;
  return X;
}

Eigen::Matrix<double, 6, 6> PosePredictor::measurement_noise(const Eigen::Isometry3d& X,
                                                             std::span<const Eigen::Vector3d> mfs_P) const {
  const double lat2 = params_.lateral_sigma * params_.lateral_sigma, dep2 = params_.depth_sigma * params_.depth_sigma;
  Eigen::Matrix<double, 6, 6> noise = Eigen::Matrix<double, 6, 6>::Zero();
  if (mfs_P.size() < 3) {
    noise.diagonal() << lat2, lat2, dep2, Eigen::Vector3d::Constant(params_.rotation_sigma * params_.rotation_sigma);
    return noise;
  }
  // The fit moves MF i by d_i = dp + dtheta x c_i, c_i its lever from the anchor in CamR:
  // the information about (dp, dtheta) is the sum of J_i^T W J_i with J_i = [I, -[c_i]x]
  // and W the MF's inverse noise; its inverse is the pose's covariance (Gauss-Markov).
  const Eigen::Vector3d w(1 / lat2, 1 / lat2, 1 / dep2);
  Eigen::Matrix<double, 6, 6> info = Eigen::Matrix<double, 6, 6>::Zero();
  for (const Eigen::Vector3d& a : mfs_P) {
    const Eigen::Vector3d c = X.linear() * (a - anchor_P_);
    Eigen::Matrix<double, 3, 6> J;
    J.leftCols<3>().setIdentity();
    J.rightCols<3>() << 0, c.z(), -c.y(), -c.z(), 0, c.x(), c.y(), -c.x(), 0;  // -[c]x
    info += J.transpose() * w.asDiagonal() * J;
  }
  // A rotation no MF layout pins down (all on one line) is left at a radian's uncertainty.
  info.bottomRightCorner<3, 3>().diagonal().array() += 1.0;
  return info.inverse();
}

void PosePredictor::update(Nanos time, const Eigen::Isometry3d& X, std::span<const Eigen::Vector3d> mfs_P) {
  if (count_ > 0 && time <= last_time_) return;
  const Eigen::Vector3d p = X * anchor_P_;
  if (count_ == 0) {
    R_ref_ = X.linear();
    x_.setZero();
    x_.segment<3>(0) = p;
    P_.setZero();
    const double lat2 = params_.lateral_sigma * params_.lateral_sigma, dep2 = params_.depth_sigma * params_.depth_sigma;
    P_.diagonal().segment<3>(0) << lat2, lat2, dep2;
    P_.diagonal().segment<3>(3).setConstant(0.05 * 0.05);  // up to a few cm/s unknown
    P_.diagonal().segment<3>(6).setConstant(params_.rotation_sigma * params_.rotation_sigma);
    P_.diagonal().segment<3>(9).setConstant(0.02 * 0.02);  // rad/s
  } else {
    const double dt = to_seconds(time - last_time_);
    Mat12 F = Mat12::Identity();
    F.block<3, 3>(0, 3) = Eigen::Matrix3d::Identity() * dt;
    F.block<3, 3>(6, 9) = Eigen::Matrix3d::Identity() * dt;
    Mat12 Q = Mat12::Zero();
    const double a2 = params_.accel_sigma * params_.accel_sigma, w2 = params_.angular_accel_sigma * params_.angular_accel_sigma;
    const double q11 = dt * dt * dt / 3, q12 = dt * dt / 2, q22 = dt;
    for (int i = 0; i < 3; ++i) {
      Q(i, i) = q11 * a2, Q(i, 3 + i) = Q(3 + i, i) = q12 * a2, Q(3 + i, 3 + i) = q22 * a2;
      Q(6 + i, 6 + i) = q11 * w2, Q(6 + i, 9 + i) = Q(9 + i, 6 + i) = q12 * w2, Q(9 + i, 9 + i) = q22 * w2;
    }
    x_ = F * x_;
    P_ = F * P_ * F.transpose() + Q;
    Eigen::Matrix<double, 6, 1> z;
    z.head<3>() = p;
    z.tail<3>() = log_rotation(X.linear() * R_ref_.transpose());
    Eigen::Matrix<double, 6, 12> H = Eigen::Matrix<double, 6, 12>::Zero();
    H.block<3, 3>(0, 0).setIdentity();
    H.block<3, 3>(3, 6).setIdentity();
    const Eigen::Matrix<double, 6, 6> Rm = measurement_noise(X, mfs_P);
    const Eigen::Matrix<double, 6, 6> S = H * P_ * H.transpose() + Rm;
    const Eigen::Matrix<double, 12, 6> K = P_ * H.transpose() * S.inverse();
    x_ += K * (z - H * x_);
    P_ = (Mat12::Identity() - K * H) * P_;
    P_ = 0.5 * (P_ + P_.transpose());
  }
  t1_ = t2_;
  X1_ = X2_;
  t2_ = time;
  X2_ = X;
  last_time_ = time;
  ++count_;
}

Eigen::Isometry3d PosePredictor::predict(Nanos time) const {
  if (count_ == 0) return Eigen::Isometry3d::Identity();
  if (params_.kind == PredictorKind::kTwoFrame) {
    if (count_ < 2 || t2_ == t1_) return X2_;
    const double k = static_cast<double>(time - t2_) / static_cast<double>(t2_ - t1_);
    const Eigen::Vector3d p1 = X1_ * anchor_P_, p2 = X2_ * anchor_P_;
    const Eigen::Vector3d r = log_rotation(X2_.linear() * X1_.linear().transpose());
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() = exp_rotation(k * r) * X2_.linear();
    X.translation() = p2 + k * (p2 - p1) - X.linear() * anchor_P_;
    return X;
  }
  const double dt = to_seconds(time - last_time_);
  return compose(x_.segment<3>(0) + dt * x_.segment<3>(3), x_.segment<3>(6) + dt * x_.segment<3>(9));
}

}  // namespace markcell::control
