#pragma once
// `markcell calibrate-base`: drives the arm through the configured poses with the board
// on the gripper, takes a stereo pair at each, finds and triangulates the board's
// corners, and fits X_Base_CamR (control/base_calibration.hpp).
//
// The devices sit behind one small interface: the live cell's (the configured arm link,
// the Aravis stereo pair) and the rig's (the simulated arm as a CAN node on an in-memory
// wire behind the real CAN arm link, the board rendered where the simulated arm holds
// it). The procedure above them is the same code.
#include <iosfwd>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "markcell/control/base_calibration.hpp"
#include "markcell/drivers/arm.hpp"
#include "markcell/host/config.hpp"
#include "markcell/vision/stereo_rig.hpp"

namespace markcell::host {

class BaseCalibrationDevices {
 public:
  virtual ~BaseCalibrationDevices() = default;
  virtual drivers::ArmLink& arm() = 0;
  virtual Nanos now() = 0;
  // Lets `dt` pass (the rig: simulated time, the arm and the link stepped every
  // millisecond), polling the arm link.
  virtual void wait(Nanos dt) = 0;
  // One stereo pair, 8-bit grey. False with the reason when none came.
  virtual bool capture(cv::Mat& left, cv::Mat& right, std::string& why) = 0;
};

struct BaseCalibrationRun {
  std::vector<control::BoardObservation> observations;
  std::vector<std::string> skipped;  // "pose 4: board not found in the right image"
  control::BaseCalibration result;
  std::vector<cv::Mat> left_images, right_images;  // the pairs taken, in pose order (for the record)
};

// The board, its mounting and the poses from the configuration.
control::BoardGeometry board_geometry(const BaseCalibrationConfig& c);
Eigen::Isometry3d X_Tool_Board(const BaseCalibrationConfig& c);
drivers::ToolPose tool_pose(const PoseSix& p);

// The nominal X_Base_CamR (calibration.base) only decides which end of the board is
// which in each image (a chessboard's corners are found up to a half turn); it must be
// right to a fraction of the board. Throws std::runtime_error when the arm link fails.
BaseCalibrationRun run_base_calibration(BaseCalibrationDevices& devices, const vision::StereoRig& rig,
                                        const Eigen::Isometry3d& X_Base_CamR_nominal, const BaseCalibrationConfig& config,
                                        std::ostream* progress);

// The table calibrate-base prints: per pose and overall residuals, outliers, skipped poses.
std::string base_calibration_table(const BaseCalibrationRun& run);
// report.json of the calibration-board scenario; `truth` (the rig's) adds the error of
// the fit against it.
std::string base_calibration_json(const BaseCalibrationRun& run, const std::string& scenario, std::uint64_t seed,
                                  const Eigen::Isometry3d* truth);
// Rotation angle (degrees) and translation (metres) between two poses.
double rotation_error_deg(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b);
double translation_error(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b);

// The rig's devices for the calibration-board scenario: the camera truly at
// X_Base_CamR_true, the board rendered with sensor noise from `seed`.
std::unique_ptr<BaseCalibrationDevices> make_rig_board_devices(const CellConfig& config, const vision::StereoCalibration& stereo,
                                                               const Eigen::Isometry3d& X_Base_CamR_true, std::uint64_t seed);
// The live cell's: the configured arm link (can or serial) and Aravis cameras.
std::unique_ptr<BaseCalibrationDevices> make_live_devices(const CellConfig& config);

}  // namespace markcell::host
