// Camera to robot base: the fit on exact and corrupted correspondences, and the whole
// calibrate-base procedure on the rig's calibration-board scenario, against the rig's
// truth and against OpenCV's own hand-eye calibration on the same images.
#include <catch2/catch.hpp>

#include <random>

#include <Eigen/Core>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>
#include <opencv2/imgproc.hpp>

#include "draw.hpp"
#include "markcell/control/base_calibration.hpp"
#include "markcell/control/tool_pose.hpp"
#include "markcell/tools/base_calibration_run.hpp"
#include "markcell/tools/capacity.hpp"
#include "markcell/host/cell.hpp"
#include "markcell/rig/scenario.hpp"
#include "markcell/vision/calibration_io.hpp"
#include "test_files.hpp"

using namespace markcell;
using markcell::test::source_path;

namespace {

Eigen::Isometry3d pose(double x, double y, double z, const Eigen::Vector3d& axis, double angle) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
  X.translation() = Eigen::Vector3d(x, y, z);
  return X;
}

// Observations made exactly from a known X_Base_CamR, with Gaussian noise on the corners.
std::vector<control::BoardObservation> synthetic(const Eigen::Isometry3d& X_Base_CamR, const control::BoardGeometry& board,
                                                 const Eigen::Isometry3d& X_Tool_Board, int poses, double noise) {
  std::mt19937_64 rng(5);
  std::normal_distribution<double> n(0.0, noise);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<control::BoardObservation> obs;
  for (int k = 0; k < poses; ++k) {
    control::BoardObservation o;
    o.name = "pose " + std::to_string(k + 1);
    const Eigen::Matrix<double, 7, 1> d = test::draw(rng, u, u, u, u, u, u, u);
    o.X_Base_Tool = pose(0.2 + 0.2 * d(0), 0.4 + 0.2 * d(1), 1.0 + 0.2 * d(2), Eigen::Vector3d(d(3), d(4), d(5)), 0.3 * d(6)) *
                    pose(0, 0, 0, Eigen::Vector3d::UnitY(), -M_PI / 2);
    for (const auto& c : control::board_corners(board)) {
      const Eigen::Vector3d p = X_Base_CamR.inverse() * o.X_Base_Tool * X_Tool_Board * c;
      o.corners_CamR.push_back(p + test::draw(rng, n, n, n));
    }
    obs.push_back(std::move(o));
  }
  return obs;
}

}  // namespace

TEST_CASE("base calibration: exact correspondences give the pose back, noise stays within its size") {
  const control::BoardGeometry board{9, 6, 0.05};
  const Eigen::Isometry3d X_Tool_Board = pose(-0.2, -0.125, 0.02, Eigen::Vector3d::UnitZ(), 0.1);
  const Eigen::Isometry3d truth = pose(-2.4, 0.22, 1.0, Eigen::Vector3d(1, -1, 1), 2.1);
  control::BaseCalibrationLimits limits;

  auto exact = control::calibrate_base(synthetic(truth, board, X_Tool_Board, 15, 0.0), board, X_Tool_Board, limits);
  REQUIRE(exact.ok());
  CHECK(exact.kept == 15);
  CHECK((exact.X_Base_CamR.matrix() - truth.matrix()).cwiseAbs().maxCoeff() < 1e-9);
  CHECK(exact.rms.maxCoeff() < 1e-9);

  auto noisy = control::calibrate_base(synthetic(truth, board, X_Tool_Board, 15, 0.0005), board, X_Tool_Board, limits);
  REQUIRE(noisy.ok());
  // 810 corners with 0.5 mm noise: the residual RMS is the noise, the pose far better.
  CHECK(noisy.rms.maxCoeff() == Approx(0.0005).epsilon(0.15));
  CHECK((noisy.X_Base_CamR.translation() - truth.translation()).norm() < 0.0005);
  for (const auto& p : noisy.poses) CHECK_FALSE(p.outlier);
}

TEST_CASE("base calibration: a pose whose reported tool pose is off is flagged and left out") {
  const control::BoardGeometry board{9, 6, 0.05};
  const Eigen::Isometry3d X_Tool_Board = pose(-0.2, -0.125, 0.02, Eigen::Vector3d::UnitX(), 0.0);
  const Eigen::Isometry3d truth = pose(-2.4, 0.22, 1.0, Eigen::Vector3d(1, -1, 1), 2.1);
  auto obs = synthetic(truth, board, X_Tool_Board, 15, 0.0003);
  obs[6].X_Base_Tool.translation() += Eigen::Vector3d(0.0, 0.03, -0.02);  // the arm's report is 3.6 cm off
  const auto r = control::calibrate_base(obs, board, X_Tool_Board, {});
  REQUIRE(r.ok());
  CHECK(r.kept == 14);
  CHECK(r.poses[6].outlier);
  for (std::size_t k = 0; k < r.poses.size(); ++k)
    if (k != 6) CHECK_FALSE(r.poses[k].outlier);
  CHECK((r.X_Base_CamR.translation() - truth.translation()).norm() < 0.0005);
}

TEST_CASE("base calibration: refused above the limits, with too few poses, and on a wrong corner count") {
  const control::BoardGeometry board{9, 6, 0.05};
  const Eigen::Isometry3d X_Tool_Board = Eigen::Isometry3d::Identity();
  const Eigen::Isometry3d truth = pose(-2.4, 0.22, 1.0, Eigen::Vector3d(0, 0, 1), 0.4);

  auto noisy = control::calibrate_base(synthetic(truth, board, X_Tool_Board, 15, 0.004), board, X_Tool_Board, {});
  CHECK(noisy.status == control::BaseCalibrationStatus::kAboveLimit);
  CHECK_THAT(noisy.reason, Catch::Contains("the limits are 2.00 mm RMS and 6.00 mm max"));

  auto few = control::calibrate_base(synthetic(truth, board, X_Tool_Board, 5, 0.0), board, X_Tool_Board, {});
  CHECK(few.status == control::BaseCalibrationStatus::kTooFewPoses);
  CHECK(few.reason == "5 usable poses, at least 6 are needed");

  auto obs = synthetic(truth, board, X_Tool_Board, 8, 0.0);
  obs[2].corners_CamR.pop_back();
  CHECK_THROWS_WITH(control::calibrate_base(obs, board, X_Tool_Board, {}), "pose 3: 53 corners, the 9x6 board has 54");
}

TEST_CASE("calibrate-base on the rig's calibration-board scenario: the truth recovered, OpenCV's hand-eye agrees") {
  const auto config = host::load_config(source_path("config/cell.example.yaml"), host::task_catalog());
  REQUIRE(config.base_calibration.poses.size() == 15);
  const auto stereo = vision::load_stereo_calibration(config.calibration.stereo);
  const vision::StereoRig rig(stereo);
  const Eigen::Isometry3d nominal = vision::load_pose(config.calibration.base, "X_Base_CamR");
  const auto scenario = rig::find_scenario("calibration-board", markcell::test::source_path("config/scenarios"), 3);
  const Eigen::Isometry3d truth = nominal * scenario.X_CamRnominal_CamR;
  // The scenario moves the camera far enough that keeping the nominal would be wrong.
  REQUIRE(host::translation_error(nominal, truth) > 0.005);

  auto devices = host::make_rig_board_devices(config, stereo, truth, 3);
  const host::BaseCalibrationRun run = host::run_base_calibration(*devices, rig, nominal, config.base_calibration, nullptr);
  INFO(host::base_calibration_table(run));
  REQUIRE(run.result.ok());
  CHECK(run.skipped.empty());
  CHECK(run.result.kept == 15);
  CHECK(host::translation_error(run.result.X_Base_CamR, truth) < 0.002);
  CHECK(host::rotation_error_deg(run.result.X_Base_CamR, truth) < 0.05);

  // OpenCV's eye-to-hand calibration on the same pictures and the same reported arm
  // poses: the board's pose in CamR by solvePnP on the right image's corners (found by
  // OpenCV, ordered as the board's by their nearest triangulated corner), the arm's
  // base-to-gripper transforms, cv::calibrateHandEye -> X_Base_CamR.
  const control::BoardGeometry board = host::board_geometry(config.base_calibration);
  const auto corners = control::board_corners(board);
  std::vector<cv::Point3f> object;
  for (const auto& c : corners) object.emplace_back(static_cast<float>(c.x()), static_cast<float>(c.y()), 0.0f);
  cv::Mat K, D;
  cv::eigen2cv(stereo.right.K, K);
  D = stereo.right.distortion.empty() ? cv::Mat::zeros(1, 5, CV_64F) : stereo.right.distortion;
  std::vector<cv::Mat> R_base2gripper, t_base2gripper, R_target2cam, t_target2cam;
  REQUIRE(run.right_images.size() == run.observations.size());
  for (std::size_t k = 0; k < run.observations.size(); ++k) {
    std::vector<cv::Point2f> found;
    REQUIRE(cv::findChessboardCorners(run.right_images[k], cv::Size(board.cols, board.rows), found));
    cv::cornerSubPix(run.right_images[k], found, cv::Size(5, 5), cv::Size(-1, -1),
                     cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 50, 1e-4));
    std::vector<cv::Point2f> ordered(corners.size());
    for (std::size_t i = 0; i < corners.size(); ++i) {
      const Eigen::Vector2d expect = rig.project(vision::Camera::kRight, run.observations[k].corners_CamR[i]);
      double best = 1e9;
      for (const auto& f : found) {
        const double d = (Eigen::Vector2d(f.x, f.y) - expect).norm();
        if (d < best) {
          best = d;
          ordered[i] = f;
        }
      }
      REQUIRE(best < 2.0);
    }
    cv::Mat rvec, tvec, R;
    REQUIRE(cv::solvePnP(object, ordered, K, D, rvec, tvec));
    cv::Rodrigues(rvec, R);
    R_target2cam.push_back(R);
    t_target2cam.push_back(tvec);
    const Eigen::Isometry3d X_Tool_Base = (run.observations[k].X_Base_Tool * host::X_Tool_Board(config.base_calibration)).inverse();
    cv::Mat Rb, tb;
    cv::eigen2cv(Eigen::Matrix3d(X_Tool_Base.linear()), Rb);
    cv::eigen2cv(Eigen::Vector3d(X_Tool_Base.translation()), tb);
    R_base2gripper.push_back(Rb);
    t_base2gripper.push_back(tb);
  }
  cv::Mat R_cam2base, t_cam2base;
  cv::calibrateHandEye(R_base2gripper, t_base2gripper, R_target2cam, t_target2cam, R_cam2base, t_cam2base,
                       cv::CALIB_HAND_EYE_PARK);
  Eigen::Matrix3d R;
  Eigen::Vector3d t;
  cv::cv2eigen(R_cam2base, R);
  cv::cv2eigen(t_cam2base, t);
  Eigen::Isometry3d opencv = Eigen::Isometry3d::Identity();
  opencv.linear() = R;
  opencv.translation() = t;
  INFO("OpenCV vs truth: " << host::translation_error(opencv, truth) * 1e3 << " mm, " << host::rotation_error_deg(opencv, truth)
                           << " deg; ours vs truth: " << host::translation_error(run.result.X_Base_CamR, truth) * 1e3 << " mm");
  CHECK(host::translation_error(opencv, run.result.X_Base_CamR) < 0.01);
  CHECK(host::rotation_error_deg(opencv, run.result.X_Base_CamR) < 0.2);
}

TEST_CASE("calibrate-base: an unreachable pose and a pose where the board leaves the view are skipped with the reason") {
  auto config = host::load_config(source_path("config/cell.example.yaml"), host::task_catalog());
  config.base_calibration.poses.resize(6);
  config.base_calibration.poses.push_back({1.4, 0.8, 1.0, 0, -90, 0});   // 1.9 m from the base: beyond its 1.6 m reach
  config.base_calibration.poses.push_back({0.2, -0.9, 1.0, 0, -90, 0});  // reachable, but outside both cameras' view
  const auto stereo = vision::load_stereo_calibration(config.calibration.stereo);
  const Eigen::Isometry3d nominal = vision::load_pose(config.calibration.base, "X_Base_CamR");
  auto devices = host::make_rig_board_devices(config, stereo, nominal, 4);
  const auto run = host::run_base_calibration(*devices, vision::StereoRig(stereo), nominal, config.base_calibration, nullptr);
  REQUIRE(run.skipped.size() == 2);
  CHECK(run.skipped[0] == "pose 7: the arm refused the pose (out of reach?)");
  CHECK(run.skipped[1] == "pose 8: board not found in the left image");
  CHECK(run.result.ok());
  CHECK(run.result.kept == 6);
}

// (markcell capacity lives with calibrate-base among the commissioning tools.)
TEST_CASE("capacity: the reach window is the chord of the reach sphere, a slow line marks the whole row, a fast one not") {
  const auto config = host::load_config(source_path("config/cell.example.yaml"), host::task_catalog());
  const Eigen::Isometry3d X_Base_CamR = vision::load_pose(config.calibration.base, "X_Base_CamR");
  const double depth = 3.1;
  // The nozzles' path in the base frame: a line; its distance h from the base origin
  // gives the chord 2 sqrt(R^2 - h^2) the line travels within reach.
  const Eigen::Vector3d o = X_Base_CamR * Eigen::Vector3d(0, 0, depth - config.marking.standoff);
  const Eigen::Vector3d dir =
      (X_Base_CamR.linear() *
       config.marking.line_direction_CamR)
          .normalized();
  const double h = (o - o.dot(dir) * dir).norm();
  const double chord = 2 * std::sqrt(config.arm.limits.reach * config.arm.limits.reach - h * h);

  const auto slow = host::marking_capacity(config, X_Base_CamR, 0.014, 0.05, depth, 1.0);
  CHECK(slow.window_s == Approx(chord / 0.014).margin(0.004 / 0.014));
  CHECK(slow.row == 21);
  CHECK(slow.defects == 21);
  const auto fast = host::marking_capacity(config, X_Base_CamR, 0.6, 0.05, depth, 4.0);
  CHECK(fast.row == 81);
  CHECK(fast.defects > 0);
  CHECK(fast.defects < 10);  // 0.7 s a defect against 0.08 s of line between them, a 4 s window
}
