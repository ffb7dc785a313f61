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
// Both tools add where the calibration came from (CalibrationProvenance), under the key
// `provenance`; a file without it (made by hand or by another tool) loads as before.
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

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

// Where a calibration came from, kept in its file so the file says it wherever it is
// copied: when, by which program, for which cameras, and how well it fitted.
//   provenance:
//     calibrated_utc: "2026-12-07T03:40:12Z"
//     tool: "markcell 0.1.0 (commit 5661ec5, calibrate-stereo)"
//     left_camera: "...", right_camera: "..."   the cameras' ids or serials ("" not given)
//     rms: 0.213, rms_unit: px                  stereo: reprojection px; base: 3-D residual mm
//     views: [{name: view01, rms: 0.2}, ...]    per view (stereo) or per arm pose (base)
struct CalibrationProvenance {
  std::string calibrated_utc;
  std::string tool;
  std::string left_camera, right_camera;
  double rms = 0;
  std::string rms_unit;  // px or mm
  struct View {
    std::string name;
    double rms = 0;
  };
  std::vector<View> views;
};
inline constexpr std::size_t kMaxProvenanceViews = 1000;

// Throw CalibrationError naming the file and the key that is missing or malformed.
StereoCalibration load_stereo_calibration(const std::string& path);
void save_stereo_calibration(const std::string& path, const StereoCalibration& calibration,
                             const CalibrationProvenance* provenance = nullptr);

Eigen::Isometry3d load_pose(const std::string& path, const std::string& key);
void save_pose(const std::string& path, const std::string& key, const Eigen::Isometry3d& pose,
               const CalibrationProvenance* provenance = nullptr);

// The file's provenance; nullopt when it has none. Throws CalibrationError naming the
// file and key of a malformed one (a wrong type, a non-finite or negative RMS, more than
// kMaxProvenanceViews views).
std::optional<CalibrationProvenance> load_provenance(const std::string& path);

}  // namespace markcell::vision
