#pragma once
// Camera to robot base (paper section III): the checkerboard on the gripper, seen by the
// stereo pair at N arm poses. Each pose gives the board's inner corners triangulated in
// CamR and, through the arm's reported tool pose and the board's mounting on the tool,
// the same corners in the base frame; Arun's fit of all of them is X_Base_CamR.
//
// A commissioning step, not a real-time one: it allocates freely. What it must do is
// refuse a bad result: residuals per pose and overall, poses whose residual stands out
// flagged and left out of the final fit, and no result when the fit exceeds the limits.
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Geometry>

#include "markcell/common/param.hpp"

namespace markcell::control {

struct BoardGeometry {
  int cols = 9;          // inner corners along the board's x
  int rows = 6;          // ... and along its y
  double square = 0.06;  // m

  template <class V>
  void Visit(V& v) {
    v(Param{"cols", Unit::kNone, 3, 40, "inner corners along the board's x", true}, cols);
    v(Param{"rows", Unit::kNone, 3, 40, "inner corners along the board's y", true}, rows);
    v(Param{"square_m", Unit::kMetre, 0.002, 0.5, "the printed squares' side", true}, square);
  }
};

// The inner corners in the board frame (z = 0), in the order findChessboardCorners
// reports them for an upright board: row by row, x fastest.
std::vector<Eigen::Vector3d> board_corners(const BoardGeometry& board);

struct BaseCalibrationLimits {
  double max_rms = 0.002;      // m, per axis, over the poses kept
  double max_abs = 0.006;      // m, per axis, any corner of a kept pose
  double outlier_factor = 4.0;  // a pose whose RMS exceeds this times the median pose RMS ...
  double outlier_floor = 0.001;  // ... and this (m) is an outlier
  int min_poses = 6;
};

struct BoardObservation {
  std::string name;                      // "pose 3", for the reports
  Eigen::Isometry3d X_Base_Tool = Eigen::Isometry3d::Identity();  // as the arm reported it
  std::vector<Eigen::Vector3d> corners_CamR;  // triangulated, board_corners() order
};

struct PoseResidual {
  std::string name;
  Eigen::Vector3d max_abs = Eigen::Vector3d::Zero();  // per base axis, m
  Eigen::Vector3d rms = Eigen::Vector3d::Zero();
  double rms_norm = 0;                                // 3D RMS, m
  bool outlier = false;
};

enum class BaseCalibrationStatus : std::uint8_t { kOk, kTooFewPoses, kDegenerate, kAboveLimit };
std::string_view to_string(BaseCalibrationStatus s);

struct BaseCalibration {
  BaseCalibrationStatus status = BaseCalibrationStatus::kTooFewPoses;
  Eigen::Isometry3d X_Base_CamR = Eigen::Isometry3d::Identity();
  std::vector<PoseResidual> poses;                    // every pose given, outliers flagged
  Eigen::Vector3d max_abs = Eigen::Vector3d::Zero();  // over the kept poses, per base axis, m
  Eigen::Vector3d rms = Eigen::Vector3d::Zero();
  int kept = 0;
  std::string reason;  // why the status is not kOk
  bool ok() const { return status == BaseCalibrationStatus::kOk; }
};

// Fits X_Base_CamR: corners_CamR ~ X_Base_CamR^-1 * X_Base_Tool * X_Tool_Board * corner.
// Every observation must carry board_corners(board).size() corners.
BaseCalibration calibrate_base(const std::vector<BoardObservation>& observations, const BoardGeometry& board,
                               const Eigen::Isometry3d& X_Tool_Board, const BaseCalibrationLimits& limits);

}  // namespace markcell::control
