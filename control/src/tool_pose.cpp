#include "markcell/control/tool_pose.hpp"

#include <cmath>

#include <Eigen/Eigenvalues>

namespace markcell::control {

std::string_view to_string(ToolPoseStatus s) {
  switch (s) {
    case ToolPoseStatus::kOk: return "ok";
    case ToolPoseStatus::kTooFewPoints: return "too few surface points";
    case ToolPoseStatus::kCollinear: return "surface points (nearly) collinear: no plane";
    case ToolPoseStatus::kFacingAway: return "surface seen edge-on from the cameras";
  }
  return "?";
}

DefectToolPose tool_pose(std::span<const Eigen::Vector3d> points, double standoff, const Eigen::Vector3d& camera_P,
                         int min_points) {
  DefectToolPose r;
  if (static_cast<int>(points.size()) < std::max(min_points, 3)) return r;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  r.contact = points[0];
  for (const auto& p : points) {
    mean += p;
    if (p.z() < r.contact.z()) r.contact = p;
  }
  mean /= static_cast<double>(points.size());
  Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
  for (const auto& p : points) C += (p - mean) * (p - mean).transpose();
  C /= static_cast<double>(points.size());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(C);  // ascending eigenvalues
  const Eigen::Vector3d ev = eig.eigenvalues();
  // A plane needs spread in two directions: the middle axis at least 1 % of the largest.
  if (!(ev(2) > 0) || ev(1) < 1e-4 * ev(2)) {
    r.status = ToolPoseStatus::kCollinear;
    return r;
  }
  Eigen::Vector3d n = eig.eigenvectors().col(0).normalized();
  const Eigen::Vector3d to_camera = (camera_P - mean).normalized();
  if (n.dot(to_camera) < 0) n = -n;
  if (n.dot(to_camera) < 0.17) {  // more than ~80 degrees off the line of sight
    r.status = ToolPoseStatus::kFacingAway;
    return r;
  }
  r.normal = n;
  r.plane_rms = std::sqrt(std::max(ev(0), 0.0));
  // The defect's centre: the points' centroid is on the plane already.
  r.centre = mean;
  Eigen::Vector3d x = Eigen::Vector3d::UnitX() - n * n.x();
  if (x.norm() < 1e-6) x = Eigen::Vector3d::UnitY() - n * n.y();
  x.normalize();
  Eigen::Matrix3d R;
  R.col(0) = x;
  R.col(1) = n.cross(x);
  R.col(2) = n;
  r.X_P_Tool.linear() = R;
  r.X_P_Tool.translation() = r.centre;
  // Stand-off from the surface's nearest point along the normal, so the nozzle never
  // comes nearer than `standoff` to any of the defect's points.
  const double lift = std::max(0.0, (r.contact - r.centre).dot(n));
  r.X_P_Nozzle = r.X_P_Tool * Eigen::Translation3d(0, 0, standoff + lift);
  r.status = ToolPoseStatus::kOk;
  return r;
}

drivers::ToolPose to_tool_pose(const Eigen::Isometry3d& X) {
  drivers::ToolPose p;
  const Eigen::AngleAxisd aa(X.linear());
  const Eigen::Vector3d r = aa.axis() * aa.angle();
  for (int i = 0; i < 3; ++i) {
    p.position[static_cast<std::size_t>(i)] = X.translation()(i);
    p.rotation[static_cast<std::size_t>(i)] = r(i);
  }
  return p;
}

Eigen::Isometry3d to_isometry(const drivers::ToolPose& p) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  const Eigen::Vector3d r(p.rotation[0], p.rotation[1], p.rotation[2]);
  const double angle = r.norm();
  if (angle > 1e-15) X.linear() = Eigen::AngleAxisd(angle, r / angle).toRotationMatrix();
  X.translation() = Eigen::Vector3d(p.position[0], p.position[1], p.position[2]);
  return X;
}

}  // namespace markcell::control
