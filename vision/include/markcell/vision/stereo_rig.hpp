#pragma once
// The marking station's stereo rig as the tracker uses it, derived once at start-up from
// the calibration file: projection matrices in the tracking frame CamR, the fundamental
// matrix, and allocation-free (un)distortion of single points.
//
// Frames: CamR is the right camera (the tracking frame); CamL the left one.
// P_L and P_R map a point in CamR to undistorted pixels of each camera.
#include <Eigen/Core>
#include <Eigen/Geometry>

#include "markcell/common/geometry.hpp"
#include "markcell/vision/calibration_io.hpp"

namespace markcell::vision {

enum class Camera : int { kLeft = 0, kRight = 1 };

class StereoRig {
 public:
  explicit StereoRig(const StereoCalibration& calibration);

  const StereoCalibration& calibration() const { return calibration_; }
  const geometry::ProjectionMatrix& P(Camera c) const { return c == Camera::kLeft ? P_L_ : P_R_; }
  // x_R^T F x_L = 0 for undistorted pixels of the same point.
  const Eigen::Matrix3d& F() const { return F_; }
  int width() const { return calibration_.left.width; }
  int height() const { return calibration_.left.height; }

  // Rectification (cv::stereoRectify, derived at start-up): rotations that make both
  // image planes coplanar with horizontal epipolar lines, and the new projections. A
  // point's rectified pixel in either view has the same row.
  const Eigen::Matrix3d& R_rect(Camera c) const { return c == Camera::kLeft ? R1_ : R2_; }
  const geometry::ProjectionMatrix& P_rect(Camera c) const { return c == Camera::kLeft ? P1_ : P2_; }
  Eigen::Vector2d rectify(Camera c, const Eigen::Vector2d& observed_px) const;
  // Undistorted pixel of a distorted (observed) one: the iterative inversion OpenCV's
  // undistortPoints uses, with a fixed number of rounds.
  Eigen::Vector2d undistort(Camera c, const Eigen::Vector2d& px) const;
  // Observed pixel of a point in CamR (distortion applied).
  Eigen::Vector2d project(Camera c, const Eigen::Vector3d& p_CamR) const;
  // Distance in pixels of the right view's undistorted point from the epipolar line of
  // the left one (symmetric: the mean of both images' distances).
  double epipolar_distance(const Eigen::Vector2d& xL_undistorted, const Eigen::Vector2d& xR_undistorted) const;
  // The 3D point (CamR) of an observed (distorted) left and right pixel pair.
  Eigen::Vector3d triangulate_observed(const Eigen::Vector2d& xL, const Eigen::Vector2d& xR) const;

 private:
  const CameraModel& model(Camera c) const { return c == Camera::kLeft ? calibration_.left : calibration_.right; }
  StereoCalibration calibration_;
  std::array<double, 5> dist_L_{}, dist_R_{};  // k1 k2 p1 p2 k3
  geometry::ProjectionMatrix P_L_, P_R_;
  Eigen::Matrix3d F_;
  Eigen::Matrix3d R1_, R2_;
  geometry::ProjectionMatrix P1_, P2_;
  Eigen::Isometry3d X_CamL_CamR_;
};

}  // namespace markcell::vision
