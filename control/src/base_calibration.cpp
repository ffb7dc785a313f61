#include "markcell/control/base_calibration.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "markcell/common/geometry.hpp"

namespace markcell::control {

std::string_view to_string(BaseCalibrationStatus s) {
  switch (s) {
    case BaseCalibrationStatus::kOk: return "ok";
    case BaseCalibrationStatus::kTooFewPoses: return "too few poses";
    case BaseCalibrationStatus::kDegenerate: return "degenerate";
    case BaseCalibrationStatus::kAboveLimit: return "above limit";
  }
  return "?";
}

std::vector<Eigen::Vector3d> board_corners(const BoardGeometry& board) {
  std::vector<Eigen::Vector3d> c;
  c.reserve(static_cast<std::size_t>(board.cols * board.rows));
  for (int j = 0; j < board.rows; ++j)
    for (int i = 0; i < board.cols; ++i) c.emplace_back(i * board.square, j * board.square, 0.0);
  return c;
}

namespace {

struct Pairs {
  std::vector<Eigen::Vector3d> a_CamR, b_Base;
  std::vector<int> pose;  // which observation each pair came from
};

Pairs pair_up(const std::vector<BoardObservation>& obs, const std::vector<Eigen::Vector3d>& corners,
              const Eigen::Isometry3d& X_Tool_Board, const std::vector<bool>& keep) {
  Pairs p;
  for (std::size_t k = 0; k < obs.size(); ++k) {
    if (!keep[k]) continue;
    const Eigen::Isometry3d X_Base_Board = obs[k].X_Base_Tool * X_Tool_Board;
    for (std::size_t i = 0; i < corners.size(); ++i) {
      p.a_CamR.push_back(obs[k].corners_CamR[i]);
      p.b_Base.push_back(X_Base_Board * corners[i]);
      p.pose.push_back(static_cast<int>(k));
    }
  }
  return p;
}

// Residuals of every observation under a fit (kept or not: an outlier's are reported too).
void residuals(const std::vector<BoardObservation>& obs, const std::vector<Eigen::Vector3d>& corners,
               const Eigen::Isometry3d& X_Tool_Board, const Eigen::Isometry3d& X_Base_CamR, BaseCalibration& out) {
  out.poses.clear();
  for (const auto& o : obs) {
    PoseResidual r;
    r.name = o.name;
    const Eigen::Isometry3d X_Base_Board = o.X_Base_Tool * X_Tool_Board;
    Eigen::Vector3d sq = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < corners.size(); ++i) {
      const Eigen::Vector3d e = X_Base_CamR * o.corners_CamR[i] - X_Base_Board * corners[i];
      r.max_abs = r.max_abs.cwiseMax(e.cwiseAbs());
      sq += e.cwiseProduct(e);
    }
    r.rms = (sq / static_cast<double>(corners.size())).cwiseSqrt();
    r.rms_norm = r.rms.norm();
    out.poses.push_back(r);
  }
}

}  // namespace

BaseCalibration calibrate_base(const std::vector<BoardObservation>& observations, const BoardGeometry& board,
                               const Eigen::Isometry3d& X_Tool_Board, const BaseCalibrationLimits& limits) {
  const std::vector<Eigen::Vector3d> corners = board_corners(board);
  for (const auto& o : observations)
    if (o.corners_CamR.size() != corners.size()) {
      std::ostringstream s;
      s << o.name << ": " << o.corners_CamR.size() << " corners, the " << board.cols << "x" << board.rows
        << " board has " << corners.size();
      throw std::invalid_argument(s.str());
    }
  BaseCalibration out;
  const auto too_few = [&](int n) {
    out.status = BaseCalibrationStatus::kTooFewPoses;
    out.reason = std::to_string(n) + " usable poses, at least " + std::to_string(limits.min_poses) + " are needed";
    return out;
  };
  if (static_cast<int>(observations.size()) < limits.min_poses) return too_few(static_cast<int>(observations.size()));

  // First fit on every pose; then the poses that stand out are left out and the fit is
  // made again on the rest (one round: a second outlier pass would start eating good
  // poses on a rig whose residuals are all small).
  std::vector<bool> keep(observations.size(), true);
  Pairs p = pair_up(observations, corners, X_Tool_Board, keep);
  geometry::RigidFit fit = geometry::fit_rigid(p.a_CamR, p.b_Base);
  if (!fit.valid) {
    out.status = BaseCalibrationStatus::kDegenerate;
    out.reason = "the board corners of all poses are (nearly) collinear";
    return out;
  }
  residuals(observations, corners, X_Tool_Board, fit.X_B_A, out);
  std::vector<double> pose_rms;
  for (const auto& r : out.poses) pose_rms.push_back(r.rms_norm);
  std::nth_element(pose_rms.begin(), pose_rms.begin() + static_cast<std::ptrdiff_t>(pose_rms.size() / 2), pose_rms.end());
  const double median = pose_rms[pose_rms.size() / 2];
  const double cut = std::max(limits.outlier_factor * median, limits.outlier_floor);
  int kept = 0;
  for (std::size_t k = 0; k < observations.size(); ++k) {
    keep[k] = out.poses[k].rms_norm <= cut;
    kept += keep[k] ? 1 : 0;
  }
  if (kept < limits.min_poses) return too_few(kept);
  if (kept < static_cast<int>(observations.size())) {
    p = pair_up(observations, corners, X_Tool_Board, keep);
    fit = geometry::fit_rigid(p.a_CamR, p.b_Base);
    residuals(observations, corners, X_Tool_Board, fit.X_B_A, out);
  }
  for (std::size_t k = 0; k < observations.size(); ++k) out.poses[k].outlier = !keep[k];

  out.X_Base_CamR = fit.X_B_A;
  out.kept = kept;
  Eigen::Vector3d sq = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < p.a_CamR.size(); ++i) {
    const Eigen::Vector3d e = fit.X_B_A * p.a_CamR[i] - p.b_Base[i];
    out.max_abs = out.max_abs.cwiseMax(e.cwiseAbs());
    sq += e.cwiseProduct(e);
  }
  out.rms = (sq / static_cast<double>(p.a_CamR.size())).cwiseSqrt();
  if (out.rms.maxCoeff() > limits.max_rms || out.max_abs.maxCoeff() > limits.max_abs) {
    std::ostringstream s;
    s.precision(2);
    s << std::fixed << "residual RMS " << out.rms.x() * 1e3 << "/" << out.rms.y() * 1e3 << "/" << out.rms.z() * 1e3
      << " mm, max " << out.max_abs.x() * 1e3 << "/" << out.max_abs.y() * 1e3 << "/" << out.max_abs.z() * 1e3
      << " mm (x/y/z); the limits are " << limits.max_rms * 1e3 << " mm RMS and " << limits.max_abs * 1e3 << " mm max";
    out.status = BaseCalibrationStatus::kAboveLimit;
    out.reason = s.str();
    return out;
  }
  out.status = BaseCalibrationStatus::kOk;
  return out;
}

}  // namespace markcell::control
