#pragma once
// Where the panel will be at a given time, from the tracker's poses (paper IV.A, V).
//
// Both predictors follow one point of the panel, the anchor (the MFs' centroid in P), and
// the panel's rotation, so that a rotation about the vertical axis does not turn into a
// fictitious translation of P's origin three metres away.
//  - kTwoFrame: the paper's. The rigid motion between the last two frames repeats: the
//    prediction k intervals after the last frame applies it k times (the paper: k = 2),
//    fractional k by scaling the rotation angle and the anchor's displacement.
//  - kKalman: the default. A Kalman filter on the anchor's position and velocity and the
//    rotation vector and its rate (constant velocity and turn rate, white acceleration),
//    with the stereo rig's measurement noise (depth worse than lateral); it predicts to
//    any time, which is how the controller compensates camera, vision and arm latency.
// Fixed-size matrices; no allocation.
#include <cstdint>
#include <span>
#include <string_view>

#include <Eigen/Geometry>

#include "markcell/common/time.hpp"

namespace markcell::control {

enum class PredictorKind : std::uint8_t { kTwoFrame, kKalman };
std::string_view to_string(PredictorKind kind);

struct PredictorParams {
  PredictorKind kind = PredictorKind::kKalman;
  double accel_sigma = 0.005;       // m/s^2: the line's speed fluctuation
  double angular_accel_sigma = 0.002;  // rad/s^2: curved sections
  // Measurement noise. With the MFs a pose was fitted to, these are one MF's position
  // noise and the pose's covariance follows from the MFs' layout; without, the pose's own.
  double lateral_sigma = 0.0004;    // m: across the view
  double depth_sigma = 0.002;       // m: along the view (stereo depth)
  double rotation_sigma = 0.003;    // rad: the pose's, without MFs
};

class PosePredictor {
 public:
  explicit PosePredictor(const PredictorParams& params) : params_(params) {}
  // A new panel frame P: forget everything; follow `anchor_P`.
  void reset(const Eigen::Vector3d& anchor_P);
  // A pose measured at `time` (the frame's capture time). Older or equal times are ignored.
  // `mfs_P`: the MFs the pose was fitted to, in P (Kalman): the measurement's covariance is
  // the rigid fit's, from their layout around the anchor. Few MFs, or MFs nearly on one
  // line, leave the rotation about that line to the filter's own prediction instead of
  // levering their depth noise out across the panel. Empty: the parameters' fixed noise.
  void update(Nanos time, const Eigen::Isometry3d& X_CamR_P, std::span<const Eigen::Vector3d> mfs_P = {});
  // At least two measurements (two-frame) or one (Kalman) have arrived.
  bool ready() const;
  Eigen::Isometry3d predict(Nanos time) const;
  Nanos last_update() const { return last_time_; }
  const PredictorParams& params() const { return params_; }

 private:
  using Vec12 = Eigen::Matrix<double, 12, 1>;
  using Mat12 = Eigen::Matrix<double, 12, 12>;
  Eigen::Isometry3d compose(const Eigen::Vector3d& anchor_CamR, const Eigen::Vector3d& rotvec) const;
  Eigen::Matrix<double, 6, 6> measurement_noise(const Eigen::Isometry3d& X_CamR_P, std::span<const Eigen::Vector3d> mfs_P) const;
  PredictorParams params_;
  Eigen::Vector3d anchor_P_ = Eigen::Vector3d::Zero();
  int count_ = 0;
  Nanos last_time_ = 0;
  // Two-frame: the last two poses.
  Nanos t1_ = 0, t2_ = 0;
  Eigen::Isometry3d X1_ = Eigen::Isometry3d::Identity(), X2_ = Eigen::Isometry3d::Identity();
  // Kalman: state [anchor p (CamR), velocity, rotation vector r (R = exp(r) R_ref), rate].
  Eigen::Matrix3d R_ref_ = Eigen::Matrix3d::Identity();
  Vec12 x_ = Vec12::Zero();
  Mat12 P_ = Mat12::Identity();
};

}  // namespace markcell::control
