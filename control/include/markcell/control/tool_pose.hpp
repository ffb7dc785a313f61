#pragma once
// The tool pose for one defect (paper III.B): from the defect's surface points (in P,
// whose z is the depth from the right camera at re-initialisation):
//  - the contact point: the point with the smallest depth;
//  - a least-squares plane through the points (the smallest principal axis);
//  - the frame O_V: origin at the defect's centre on that plane, Z the plane's normal
//    out of the surface towards the cameras, X the camera's x axis projected into the
//    plane, Y = Z x X;
//  - the nozzle: on Z at the stand-off from the surface (measured from the contact
//    point, so that the nozzle never comes closer than that), looking back along -Z.
// The spray aims at the defect's centre, not at the contact point as the paper's stamp
// did: a ding's nearest point lies on its rim, up to its radius off the centre, and the
// spray has to cover the centre.
#include <cstdint>
#include <span>
#include <string_view>

#include <Eigen/Geometry>

#include "markcell/drivers/arm.hpp"

namespace markcell::control {

enum class ToolPoseStatus : std::uint8_t { kOk, kTooFewPoints, kCollinear, kFacingAway };
std::string_view to_string(ToolPoseStatus s);

struct DefectToolPose {
  ToolPoseStatus status = ToolPoseStatus::kTooFewPoints;
  Eigen::Vector3d contact = Eigen::Vector3d::Zero();   // P
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();    // P, on the plane
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();   // P, towards the cameras
  Eigen::Isometry3d X_P_Tool = Eigen::Isometry3d::Identity();    // O_V
  Eigen::Isometry3d X_P_Nozzle = Eigen::Isometry3d::Identity();  // the spraying pose
  double plane_rms = 0;  // m
  bool ok() const { return status == ToolPoseStatus::kOk; }
};

// `camera_P`: the right camera's position in P (the origin, for P as the tracker sets it).
DefectToolPose tool_pose(std::span<const Eigen::Vector3d> points_P, double standoff,
                         const Eigen::Vector3d& camera_P = Eigen::Vector3d::Zero(), int min_points = 6);

// The arm link's tool pose (position, rotation vector) and the rigid transform it is.
drivers::ToolPose to_tool_pose(const Eigen::Isometry3d& X_Base_Tool);
Eigen::Isometry3d to_isometry(const drivers::ToolPose& pose);

}  // namespace markcell::control
