#include "markcell/tools/base_calibration_run.hpp"

#include <time.h>

#include <cmath>
#include <cstdio>
#include <ostream>
#include <stdexcept>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "markcell/common/geometry.hpp"
#include "markcell/control/tool_pose.hpp"
#include "markcell/drivers/camera.hpp"
#include "markcell/drivers/can_arm_link.hpp"
#include "markcell/host/cell.hpp"
#include "markcell/host/json.hpp"
#include "markcell/tools/record.hpp"
#include "markcell/rig/render.hpp"

namespace markcell::host {

namespace {
constexpr double kDeg = 3.14159265358979323846 / 180.0;
constexpr Nanos kStep = millis(1);
constexpr Nanos kLinkUpTimeout = seconds(3);

// The corners of one image in board_corners() order. findChessboardCorners reports rows
// of `cols` corners, but which corner comes first depends on how the board lies in the
// image (a half turn, and a mirror when the board is seen from its back): of the four
// orders the grid allows, the one closest to where the nominal calibration expects the
// corners is taken.
bool find_board(const cv::Mat& image, const control::BoardGeometry& board, const std::vector<Eigen::Vector2d>& expected,
                std::vector<Eigen::Vector2d>& out) {
  std::vector<cv::Point2f> found;
  const int flags = cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE;
  if (!cv::findChessboardCorners(image, cv::Size(board.cols, board.rows), found, flags)) return false;
  const cv::TermCriteria criteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 50, 1e-4);
  cv::cornerSubPix(image, found, cv::Size(5, 5), cv::Size(-1, -1), criteria);
  const auto index = [&](int order, int i, int j) {
    const int fi = (order & 1) != 0 ? board.cols - 1 - i : i;
    const int fj = (order & 2) != 0 ? board.rows - 1 - j : j;
    return static_cast<std::size_t>(fj * board.cols + fi);
  };
  int best = 0;
  double best_cost = 0;
  for (int order = 0; order < 4; ++order) {
    double cost = 0;
    for (int j = 0; j < board.rows; ++j)
      for (int i = 0; i < board.cols; ++i) {
        const cv::Point2f& p = found[index(order, i, j)];
        cost += (Eigen::Vector2d(p.x, p.y) - expected[static_cast<std::size_t>(j * board.cols + i)]).squaredNorm();
      }
    if (order == 0 || cost < best_cost) {
      best = order;
      best_cost = cost;
    }
  }
  out.resize(found.size());
  for (int j = 0; j < board.rows; ++j)
    for (int i = 0; i < board.cols; ++i) {
      const cv::Point2f& p = found[index(best, i, j)];
      out[static_cast<std::size_t>(j * board.cols + i)] = Eigen::Vector2d(p.x, p.y);
    }
  return true;
}

std::string status_text(drivers::ArmLinkStatus s) { return std::string(drivers::to_string(s)); }

}  // namespace

control::BoardGeometry board_geometry(const BaseCalibrationConfig& c) {
  return c.board;
}

drivers::ToolPose tool_pose(const PoseSix& p) {
  drivers::ToolPose t;
  for (std::size_t i = 0; i < 3; ++i) {
    t.position[i] = p[i];
    t.rotation[i] = p[i + 3] * kDeg;
  }
  return t;
}

Eigen::Isometry3d X_Tool_Board(const BaseCalibrationConfig& c) { return control::to_isometry(tool_pose(c.X_Tool_Board)); }

BaseCalibrationRun run_base_calibration(BaseCalibrationDevices& devices, const vision::StereoRig& rig,
                                        const Eigen::Isometry3d& X_Base_CamR_nominal, const BaseCalibrationConfig& config,
                                        std::ostream* progress) {
  const control::BoardGeometry board = board_geometry(config);
  const std::vector<Eigen::Vector3d> corners = control::board_corners(board);
  const Eigen::Isometry3d X_Tool_Board_ = X_Tool_Board(config);
  drivers::ArmLink& arm = devices.arm();
  BaseCalibrationRun run;

  arm.activate(devices.now());
  for (Nanos waited = 0; arm.status() != drivers::ArmLinkStatus::kOk; waited += kStep) {
    if (waited > kLinkUpTimeout || drivers::is_fault(arm.status())) {
      const std::string why = status_text(arm.status());
      arm.deactivate();
      throw std::runtime_error("arm link: no state from the arm within 3 s (" + why + ")");
    }
    devices.wait(kStep);
  }
  const auto fail = [&](const std::string& what) {
    drivers::ArmCommand hold;
    hold.mode = drivers::ArmMode::kHold;
    hold.time = devices.now();
    arm.send(hold, devices.now());
    devices.wait(millis(20));
    arm.deactivate();
    throw std::runtime_error(what);
  };

  for (std::size_t k = 0; k < config.poses.size(); ++k) {
    const std::string name = "pose " + std::to_string(k + 1);
    drivers::ArmCommand move;
    move.mode = drivers::ArmMode::kMove;
    move.time = devices.now();
    move.target = tool_pose(config.poses[k]);
    const std::uint64_t refusals = arm.counters().refusals;
    const std::uint8_t seq = arm.send(move, devices.now());
    // Refused by the link (not encodable) or by the arm (its state answers this command).
    const auto refused = [&] {
      return arm.counters().refusals != refusals ||
             (arm.status() == drivers::ArmLinkStatus::kRefused && arm.state().applied_seq == seq);
    };
    // In position on this command's target, and staying there for the settle time.
    Nanos waited = 0, settled = -1;
    for (; waited <= config.move_timeout; waited += kStep) {
      devices.wait(kStep);
      if (drivers::is_fault(arm.status())) fail(name + ": arm link " + status_text(arm.status()));
      if (refused()) break;
      const drivers::ArmState& s = arm.state();
      const bool there = s.applied_seq == seq && s.in_position() && !s.fault();
      settled = there ? (settled < 0 ? 0 : settled + kStep) : -1;
      if (settled >= config.settle) break;
    }
    if (refused()) {
      run.skipped.push_back(name + ": the arm refused the pose (out of reach?)");
      if (progress) *progress << "  " << run.skipped.back() << "\n";
      continue;
    }
    if (settled < config.settle) {
      char buf[128];
      std::snprintf(buf, sizeof buf, ": not in position within %.1f s", to_seconds(config.move_timeout));
      run.skipped.push_back(name + buf);
      if (progress) *progress << "  " << run.skipped.back() << "\n";
      continue;
    }
    const Eigen::Isometry3d X_Base_Tool = control::to_isometry(arm.state().tool);
    cv::Mat left, right;
    std::string why;
    if (!devices.capture(left, right, why)) {
      run.skipped.push_back(name + ": no stereo pair (" + why + ")");
      if (progress) *progress << "  " << run.skipped.back() << "\n";
      continue;
    }
    run.left_images.push_back(left);
    run.right_images.push_back(right);

    const Eigen::Isometry3d X_CamR_Board_nominal = X_Base_CamR_nominal.inverse() * X_Base_Tool * X_Tool_Board_;
    std::vector<Eigen::Vector2d> expect_l, expect_r, found_l, found_r;
    for (const auto& c : corners) {
      expect_l.push_back(rig.project(vision::Camera::kLeft, X_CamR_Board_nominal * c));
      expect_r.push_back(rig.project(vision::Camera::kRight, X_CamR_Board_nominal * c));
    }
    const bool ok_l = find_board(left, board, expect_l, found_l);
    const bool ok_r = ok_l && find_board(right, board, expect_r, found_r);
    if (!ok_l || !ok_r) {
      run.skipped.push_back(name + ": board not found in the " + (ok_l ? "right" : "left") + " image");
      if (progress) *progress << "  " << run.skipped.back() << "\n";
      continue;
    }
    control::BoardObservation o;
    o.name = name;
    o.X_Base_Tool = X_Base_Tool;
    for (std::size_t i = 0; i < corners.size(); ++i) o.corners_CamR.push_back(rig.triangulate_observed(found_l[i], found_r[i]));
    run.observations.push_back(std::move(o));
    if (progress) *progress << "  " << name << ": board found, " << corners.size() << " corners triangulated\n";
  }

  // Home, then let go of the arm.
  drivers::ArmCommand home;
  home.mode = drivers::ArmMode::kHome;
  home.time = devices.now();
  const std::uint8_t seq = arm.send(home, devices.now());
  for (Nanos waited = 0; waited <= config.move_timeout; waited += kStep) {
    devices.wait(kStep);
    if (drivers::is_fault(arm.status())) fail("going home: arm link " + status_text(arm.status()));
    if (arm.state().applied_seq == seq && arm.state().in_position()) break;
  }
  arm.deactivate();

  control::BaseCalibrationLimits limits;
  limits.max_rms = config.max_rms_mm / 1000.0;
  limits.max_abs = config.max_abs_mm / 1000.0;
  run.result = control::calibrate_base(run.observations, board, X_Tool_Board_, limits);
  return run;
}

double rotation_error_deg(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle() / kDeg;
}

double translation_error(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return (a.translation() - b.translation()).norm();
}

std::string base_calibration_table(const BaseCalibrationRun& run) {
  std::string out;
  char line[256];
  const control::BaseCalibration& r = run.result;
  out += "pose        RMS x/y/z (mm)         max |x|/|y|/|z| (mm)\n";
  for (const auto& p : r.poses) {
    std::snprintf(line, sizeof line, "%-10s %5.2f %5.2f %5.2f      %5.2f %5.2f %5.2f%s\n", p.name.c_str(), p.rms.x() * 1e3,
                  p.rms.y() * 1e3, p.rms.z() * 1e3, p.max_abs.x() * 1e3, p.max_abs.y() * 1e3, p.max_abs.z() * 1e3,
                  p.outlier ? "   OUTLIER (left out of the fit)" : "");
    out += line;
  }
  for (const auto& s : run.skipped) out += "skipped: " + s + "\n";
  std::snprintf(line, sizeof line, "overall (%d poses kept): RMS %.2f %.2f %.2f mm, max %.2f %.2f %.2f mm\n", r.kept,
                r.rms.x() * 1e3, r.rms.y() * 1e3, r.rms.z() * 1e3, r.max_abs.x() * 1e3, r.max_abs.y() * 1e3,
                r.max_abs.z() * 1e3);
  out += line;
  return out;
}

std::string base_calibration_json(const BaseCalibrationRun& run, const std::string& scenario, std::uint64_t seed,
                                  const Eigen::Isometry3d* truth) {
  const control::BaseCalibration& r = run.result;
  // Appended piece by piece: `"[" + std::string` trips GCC 12's -Wrestrict false positive at
  // -O3 (GCC bug 105329), which a plain CMAKE_BUILD_TYPE=Release build turns into an error.
  const auto vec_mm = [](const Eigen::Vector3d& v) {
    std::string s = "[";
    s += json_number(v.x() * 1e3, 3);
    s += ", ";
    s += json_number(v.y() * 1e3, 3);
    s += ", ";
    s += json_number(v.z() * 1e3, 3);
    s += "]";
    return s;
  };
  std::string j = "{\n";
  j += "  \"scenario\": " + json_quote(scenario) + ",\n";
  j += "  \"seed\": " + std::to_string(seed) + ",\n";
  j += "  \"status\": " + json_quote(control::to_string(r.status)) + ",\n";
  j += "  \"reason\": " + json_quote(r.reason) + ",\n";
  j += "  \"poses_observed\": " + std::to_string(run.observations.size()) + ",\n";
  j += "  \"poses_kept\": " + std::to_string(r.kept) + ",\n";
  j += "  \"skipped\": [";
  for (std::size_t i = 0; i < run.skipped.size(); ++i) j += (i ? ", " : "") + json_quote(run.skipped[i]);
  j += "],\n";
  j += "  \"residual_mm\": {\"max_abs\": " + vec_mm(r.max_abs) + ", \"rms\": " + vec_mm(r.rms) + "},\n";
  j += "  \"per_pose\": [\n";
  for (std::size_t i = 0; i < r.poses.size(); ++i) {
    const auto& p = r.poses[i];
    j += "    {\"name\": " + json_quote(p.name) + ", \"rms_mm\": " + vec_mm(p.rms) + ", \"max_abs_mm\": " + vec_mm(p.max_abs) +
         ", \"outlier\": " + (p.outlier ? "true" : "false") + "}" + (i + 1 < r.poses.size() ? ",\n" : "\n");
  }
  j += "  ],\n";
  const Eigen::Isometry3d& X = r.X_Base_CamR;
  j += "  \"X_Base_CamR\": [";
  for (int i = 0; i < 4; ++i)
    for (int k = 0; k < 4; ++k) j += json_number(X.matrix()(i, k), 6) + (i == 3 && k == 3 ? "" : ", ");
  j += "]";
  if (truth != nullptr) {
    j += ",\n  \"error_vs_truth\": {\"translation_mm\": " + json_number(translation_error(X, *truth) * 1e3, 3) +
         ", \"rotation_deg\": " + json_number(rotation_error_deg(X, *truth), 4) + "}";
  }
  j += "\n}\n";
  return j;
}

namespace {

class RigBoardDevices final : public BaseCalibrationDevices {
 public:
  RigBoardDevices(const CellConfig& config, const vision::StereoCalibration& stereo, const Eigen::Isometry3d& X_Base_CamR_true,
                  std::uint64_t seed)
      : config_(config.base_calibration),
        X_CamR_Base_true_(X_Base_CamR_true.inverse()),
        seed_(seed),
        arm_(wire_.b(), config.arm.can.link.node_id, sim_arm_limits(config.arm), millis(10),
             config.arm.can.link.heartbeat_period, config.arm.can.link.heartbeat_timeout, config.arm.can.link.fd),
        link_(wire_.a(), config.arm.can.link),
        renderer_(stereo, rig::RenderSettings{}) {
    wire_.set_time_source([](void* self) { return static_cast<RigBoardDevices*>(self)->now_; }, this);
    arm_.start(now_);
  }
  drivers::ArmLink& arm() override { return link_; }
  Nanos now() override { return now_; }
  void wait(Nanos dt) override {
    for (Nanos end = now_ + dt; now_ < end;) {
      now_ += kStep;
      arm_.poll(now_);
      link_.poll(now_);
    }
  }
  bool capture(cv::Mat& left, cv::Mat& right, std::string&) override {
    // Where the arm's mechanics hold the board, not where it says it does.
    const Eigen::Isometry3d X_CamR_Board = X_CamR_Base_true_ * control::to_isometry(arm_.model().tool()) * X_Tool_Board(config_);
    renderer_.render_board(config_.board.cols, config_.board.rows, config_.board.square, X_CamR_Board, seed_ * 1000 + shots_++,
                           left, right);
    return true;
  }

 private:
  BaseCalibrationConfig config_;
  Eigen::Isometry3d X_CamR_Base_true_;
  std::uint64_t seed_;
  std::uint64_t shots_ = 0;
  Nanos now_ = 0;
  drivers::SimCanWire wire_;
  drivers::SimCanArm arm_;
  drivers::CanArmLink link_;
  rig::StereoRenderer renderer_;
};

class LiveDevices final : public BaseCalibrationDevices {
 public:
  explicit LiveDevices(const CellConfig& config)
      : link_(make_arm_link(config.arm, bus_)),
        left_(settings(config.cameras, config.cameras.left)),
        right_(settings(config.cameras, config.cameras.right)),
        wait_(config.cameras.lost_after / 2) {
    left_.activate();
    right_.activate();
    stereo_ = std::make_unique<drivers::StereoCamera>(left_, right_, millis(5), config.cameras.lost_after);
  }
  ~LiveDevices() override {
    left_.deactivate();
    right_.deactivate();
  }
  drivers::ArmLink& arm() override { return *link_; }
  Nanos now() override { return monotonic_now(); }
  void wait(Nanos dt) override {
    const timespec ts = to_timespec(dt);
    clock_nanosleep(CLOCK_MONOTONIC, 0, &ts, nullptr);
    link_->poll(monotonic_now());
  }
  bool capture(cv::Mat& left, cv::Mat& right, std::string& why) override {
    // A few tries: the first pair after a move may be one exposed while moving.
    for (int attempt = 0; attempt < 3; ++attempt) {
      stereo_->trigger();
      drivers::StereoFrame f;
      const drivers::PairStatus s = stereo_->next(f, wait_);  // a dropped trigger is retried before the camera counts as lost
      if (s == drivers::PairStatus::kPair) {
        left = cv::Mat(f.left.height, f.left.width, CV_8UC1, const_cast<std::uint8_t*>(f.left.pixels),
                       static_cast<std::size_t>(f.left.stride))
                   .clone();
        right = cv::Mat(f.right.height, f.right.width, CV_8UC1, const_cast<std::uint8_t*>(f.right.pixels),
                        static_cast<std::size_t>(f.right.stride))
                    .clone();
        return true;
      }
      why = s == drivers::PairStatus::kLeftLost ? "left camera lost" : s == drivers::PairStatus::kRightLost ? "right camera lost"
                                                                                                               : "no pair within half of lost_after_ms";
      if (s != drivers::PairStatus::kTimeout) return false;
    }
    return false;
  }

 private:
  // calibrate-base triggers both cameras by software: it needs one pair per pose.
  static drivers::CameraSettings settings(const CameraConfig& c, const drivers::CameraUnitSettings& own) {
    drivers::CameraSettings s = camera_settings(c, own);
    s.trigger = drivers::TriggerMode::kSoftware;
    return s;
  }
  std::unique_ptr<drivers::SocketCanBus> bus_;
  std::unique_ptr<drivers::ArmLink> link_;
  drivers::AravisCamera left_, right_;
  Nanos wait_;
  std::unique_ptr<drivers::StereoCamera> stereo_;
};

}  // namespace

std::unique_ptr<BaseCalibrationDevices> make_rig_board_devices(const CellConfig& config, const vision::StereoCalibration& stereo,
                                                               const Eigen::Isometry3d& X_Base_CamR_true, std::uint64_t seed) {
  return std::make_unique<RigBoardDevices>(config, stereo, X_Base_CamR_true, seed);
}

std::unique_ptr<BaseCalibrationDevices> make_live_devices(const CellConfig& config) {
  if (config.arm.transport == ArmTransport::kSimulated || config.cameras.source != CameraSource::kAravis)
    throw std::invalid_argument(config.file +
                                ": calibrate-base on the live cell needs devices.arm.transport can or serial and "
                                "devices.cameras.source aravis (with the simulated ones it runs the rig's calibration-board)");
  return std::make_unique<LiveDevices>(config);
}

}  // namespace markcell::host
