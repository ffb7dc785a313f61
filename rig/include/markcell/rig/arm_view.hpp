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
#include <memory>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "markcell/common/triple_buffer.hpp"
#include "markcell/drivers/arm.hpp"
#include "markcell/vision/frame_source.hpp"
#include "markcell/vision/panel_tracker.hpp"
#include "markcell/rig/render.hpp"

namespace markcell::rig {

struct ArmShape {
  Eigen::Vector3d shoulder_Base{0.0, 0.0, 0.45};
  double upper_arm = 0.75, forearm = 0.75, tool = 0.25;      // m
  double upper_radius = 0.07, fore_radius = 0.055, tool_radius = 0.03;
  std::uint8_t grey = 75;
};

// The arm's three capsules in CamR for a nozzle pose.
std::array<rig::Occluder, 3> arm_occluders(const ArmShape& shape, const Eigen::Isometry3d& X_CamR_Base,
                                              const Eigen::Isometry3d& X_Base_Nozzle);

// What drawing the arm cost the tracker, over a run.
struct ArmOverlayStats {
  std::uint64_t drawn = 0;       // pairs the arm was drawn into
  std::uint64_t hid_pairs = 0;   // of them, those where it hid at least one known MF
  std::uint64_t hidden_mfs = 0;  // the MFs hidden, summed over pairs
};

// A frame source in front of another: each pair the inner source hands out is copied into
// one of three buffers of its own and the arm painted over it at the simulated arm's
// newest tool pose (read from the cell's simulated world, host::Cell::sim_tool_poses). The
// cell's vision task sees only a frame source; the rig puts this one in front of the
// configured one. Allocation-free after construction (the buffers have the cameras' size).
class ArmOverlaySource final : public vision::FrameSource {
 public:
  ArmOverlaySource(std::unique_ptr<vision::FrameSource> inner, const vision::StereoCalibration& cameras,
                   const Eigen::Isometry3d& X_CamR_Base, TripleBuffer<drivers::ToolPose>& tool_poses, ArmShape shape = {});
  void start(Nanos epoch) override { inner_->start(epoch); }
  void stop() noexcept override { inner_->stop(); }
  vision::FrameResult next(Nanos now, vision::StereoFrameRef& out) noexcept override;
  std::uint64_t skipped() const override { return inner_->skipped(); }
  // Of the panel's MFs whose place the estimate knows, how many the arm drawn into the
  // last pair hides from either camera (what the closed loop costs the tracker).
  void tracked(const msg::PoseEstimate& estimate) noexcept override;
  vision::FrameSource& inner() { return *inner_; }
  // Read after the run (the vision lane stopped).
  const ArmOverlayStats& stats() const { return stats_; }

 private:
  void paint(vision::StereoFrameRef& frame) noexcept;
  std::unique_ptr<vision::FrameSource> inner_;
  TripleBuffer<drivers::ToolPose>& tool_poses_;
  rig::StereoRenderer renderer_;
  Eigen::Isometry3d X_CamR_Base_;
  ArmShape shape_;
  bool have_tool_ = false;
  std::array<cv::Mat, 3> left_, right_;
  std::size_t next_ = 0;
  ArmOverlayStats stats_;
  std::array<rig::Occluder, 3> drawn_CamR_{};  // the capsules painted into the last pair
  std::array<rig::Occluder, 3> drawn_CamL_{};
  bool drawn_ = false;
  Eigen::Isometry3d X_CamL_CamR_;
};

}  // namespace markcell::rig
