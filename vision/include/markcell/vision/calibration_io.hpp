#pragma once
// Calibration files, stored as OpenCV FileStorage YAML so OpenCV's own tools read them.
//
// Stereo pair (what `markcell calibrate-stereo` writes; OpenCV's stereoCalibrate names):
//   image_width, image_height   ints
//   K1, D1, K2, D2              left/right camera matrix (3x3) and distortion (1xN, N in 4,5,8,12,14)
//   R, T                        X_CamR_CamL: a point in the left camera's frame maps to the
//                               right camera's frame as p_R = R p_L + T (metres)
// Camera to robot base (what `markcell calibrate-base` writes):
//   X_Base_CamR                 4x4 homogeneous rigid transform (metres)
#include <stdexcept>
#include <string>
#include <string_view>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

namespace markcell::vision {

class CalibrationError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct CameraModel {
  Eigen::Matrix3d K = Eigen::Matrix3d::Identity();
  cv::Mat distortion;  // 1xN, CV_64F (empty: none)
  int width = 0;
  int height = 0;
};

struct StereoCalibration {
  CameraModel left;
  CameraModel right;
  Eigen::Isometry3d X_CamR_CamL = Eigen::Isometry3d::Identity();
  double baseline() const { return X_CamR_CamL.translation().norm(); }
};

// An OpenCV FileStorage YAML file from outside (a calibration, a panel type): only a
// regular file of at most `max_bytes`, starting %YAML, not nested deeper than 16 levels
// (50,000 overflowed FileStorage's stack), parsed from the very bytes checked. Throws
// CalibrationError naming the file and what is wrong.
cv::FileStorage open_yaml_storage(const std::string& path, std::size_t max_bytes, std::string_view what);

// Throw CalibrationError naming the file and the key that is missing or malformed.
StereoCalibration load_stereo_calibration(const std::string& path);
void save_stereo_calibration(const std::string& path, const StereoCalibration& calibration);

Eigen::Isometry3d load_pose(const std::string& path, const std::string& key);
void save_pose(const std::string& path, const std::string& key, const Eigen::Isometry3d& pose);

}  // namespace markcell::vision
