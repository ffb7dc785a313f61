#pragma once
// The simulated arm as the cameras see it, drawn into replayed frames in closed loop: the
// rig's recordings are rendered before the run, so the arm (which moves only in the run)
// is painted over each stereo pair as the vision task takes it, from the simulated arm's
// own tool pose. It hides macro-features exactly when the real arm would, and the
// tracker must keep the pose from the rest and re-acquire them.
//
// The arm's shape is a plain three-link model in the base frame: a shoulder above the
// base origin, an upper arm and a forearm of equal length meeting at an elbow bent
// upwards in the vertical plane through the wrist, and the spray tool from the wrist to
// the nozzle along the nozzle frame's +Z (out of the surface). Capsules, flat grey.
#include <array>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "markcell/common/triple_buffer.hpp"
#include "markcell/drivers/arm.hpp"
#include "markcell/vision/frame_source.hpp"
#include "markcell/vision/panel_tracker.hpp"
#include "markcell/vision/render.hpp"

namespace markcell::host::rig {

struct ArmShape {
  Eigen::Vector3d shoulder_Base{0.0, 0.0, 0.45};
  double upper_arm = 0.75, forearm = 0.75, tool = 0.25;      // m
  double upper_radius = 0.07, fore_radius = 0.055, tool_radius = 0.03;
  std::uint8_t grey = 75;
};

// The arm's three capsules in CamR for a nozzle pose.
std::array<vision::Occluder, 3> arm_occluders(const ArmShape& shape, const Eigen::Isometry3d& X_CamR_Base,
                                              const Eigen::Isometry3d& X_Base_Nozzle);

class ArmOverlay {
 public:
  ArmOverlay(const vision::StereoCalibration& cameras, const Eigen::Isometry3d& X_CamR_Base, ArmShape shape = {});
  // Control lane (the simulated world, every tick): the arm's tool pose now.
  void publish(const drivers::ToolPose& tool) noexcept { tool_.write(tool); }
  // Vision lane: copies the pair into one of three buffers of its own, paints the arm
  // at its newest pose over it and points `frame` there. Allocation-free once the
  // buffers have the frame's size (the first pair).
  void apply(vision::StereoFrameRef& frame) noexcept;
  std::uint64_t painted() const { return painted_; }
  // Of the panel's MFs whose place the estimate knows, how many the arm drawn into the
  // last pair hides from either camera (what the closed loop costs the tracker).
  int hidden_macro_features(const msg::PoseEstimate& estimate) const noexcept;

 private:
  vision::StereoRenderer renderer_;
  Eigen::Isometry3d X_CamR_Base_;
  ArmShape shape_;
  TripleBuffer<drivers::ToolPose> tool_;
  bool have_tool_ = false;
  std::array<cv::Mat, 3> left_, right_;
  std::size_t next_ = 0;
  std::uint64_t painted_ = 0;
  std::array<vision::Occluder, 3> drawn_CamR_{};  // the capsules painted into the last pair
  std::array<vision::Occluder, 3> drawn_CamL_{};
  bool drawn_ = false;
  Eigen::Isometry3d X_CamL_CamR_;
};

}  // namespace markcell::host::rig
