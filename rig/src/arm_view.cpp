#include "markcell/rig/arm_view.hpp"

#include <cmath>
#include <stdexcept>

#include "markcell/control/tool_pose.hpp"

namespace markcell::rig {

std::array<rig::Occluder, 3> arm_occluders(const ArmShape& shape, const Eigen::Isometry3d& X_CamR_Base,
                                              const Eigen::Isometry3d& X_Base_Nozzle) {
  const Eigen::Vector3d nozzle = X_Base_Nozzle.translation();
  const Eigen::Vector3d wrist = nozzle + shape.tool * X_Base_Nozzle.linear().col(2);
  const Eigen::Vector3d& S = shape.shoulder_Base;
  const Eigen::Vector3d reach = wrist - S;
  const double d = reach.norm();
  Eigen::Vector3d elbow = S + 0.5 * reach;  // stretched out (or the wrist on the shoulder)
  if (d > 1e-6 && d < shape.upper_arm + shape.forearm) {
    // Two links meeting at the elbow: law of cosines along the reach, bent upwards.
    const Eigen::Vector3d along = reach / d;
    Eigen::Vector3d up = Eigen::Vector3d::UnitZ() - Eigen::Vector3d::UnitZ().dot(along) * along;
    up = up.norm() > 1e-6 ? up.normalized() : Eigen::Vector3d::UnitX();
    const double x = (d * d + shape.upper_arm * shape.upper_arm - shape.forearm * shape.forearm) / (2 * d);
    const double h = std::sqrt(std::max(0.0, shape.upper_arm * shape.upper_arm - x * x));
    elbow = S + x * along + h * up;
  }
  return {rig::Occluder{X_CamR_Base * S, X_CamR_Base * elbow, shape.upper_radius, shape.grey},
          rig::Occluder{X_CamR_Base * elbow, X_CamR_Base * wrist, shape.fore_radius, shape.grey},
          rig::Occluder{X_CamR_Base * wrist, X_CamR_Base * nozzle, shape.tool_radius,
                           static_cast<std::uint8_t>(shape.grey / 2)}};
}

ArmOverlaySource::ArmOverlaySource(std::unique_ptr<vision::FrameSource> inner, const vision::StereoCalibration& cameras,
                                   const Eigen::Isometry3d& X_CamR_Base, TripleBuffer<drivers::ToolPose>& tool_poses,
                                   ArmShape shape)
    : inner_(std::move(inner)),
      tool_poses_(tool_poses),
      renderer_(cameras, rig::RenderSettings{}),
      X_CamR_Base_(X_CamR_Base),
      shape_(shape),
      X_CamL_CamR_(cameras.X_CamR_CamL.inverse()) {
  if (!inner_) throw std::invalid_argument("ArmOverlaySource: no frame source to draw the arm over");
  for (std::size_t i = 0; i < left_.size(); ++i) {
    left_[i].create(cameras.left.height, cameras.left.width, CV_8UC1);
    right_[i].create(cameras.right.height, cameras.right.width, CV_8UC1);
  }
}

vision::FrameResult ArmOverlaySource::next(Nanos now, vision::StereoFrameRef& out) noexcept {
  const vision::FrameResult got = inner_->next(now, out);
  drawn_ = false;
  if (got == vision::FrameResult::kFrame) paint(out);
  return got;
}

void ArmOverlaySource::paint(vision::StereoFrameRef& frame) noexcept {
  if (tool_poses_.update()) have_tool_ = true;
  if (!have_tool_ || frame.dropped || frame.left == nullptr || frame.right == nullptr) return;
  cv::Mat& left = left_[next_];
  cv::Mat& right = right_[next_];
  if (frame.left->size() != left.size() || frame.right->size() != right.size() || frame.left->type() != CV_8UC1 ||
      frame.right->type() != CV_8UC1)
    return;  // not the cameras' size: left as it is (the tracker reports it)
  frame.left->copyTo(left);
  frame.right->copyTo(right);
  drawn_CamR_ = arm_occluders(shape_, X_CamR_Base_, control::to_isometry(tool_poses_.read()));
  for (std::size_t i = 0; i < drawn_CamR_.size(); ++i) {
    drawn_CamL_[i] = drawn_CamR_[i];
    drawn_CamL_[i].a_CamR = X_CamL_CamR_ * drawn_CamR_[i].a_CamR;
    drawn_CamL_[i].b_CamR = X_CamL_CamR_ * drawn_CamR_[i].b_CamR;
  }
  drawn_ = true;
  renderer_.paint_occluders(drawn_CamR_.data(), drawn_CamR_.size(), left, right);
  frame.left = &left;
  frame.right = &right;
  next_ = (next_ + 1) % left_.size();
  ++stats_.drawn;
}

void ArmOverlaySource::tracked(const msg::PoseEstimate& e) noexcept {
  if (!drawn_ || !e.has_pose()) return;
  int hidden = 0;
  for (const msg::MacroFeatureObservation& mf : e.mfs) {
    if (!mf.reference_known) continue;
    const Eigen::Vector3d p_CamR = e.X_CamR_P * mf.reference_P;
    const Eigen::Vector3d p_CamL = X_CamL_CamR_ * p_CamR;
    bool h = false;
    for (std::size_t k = 0; k < drawn_CamR_.size() && !h; ++k)
      h = rig::hides(drawn_CamR_[k], p_CamR) || rig::hides(drawn_CamL_[k], p_CamL);
    hidden += h ? 1 : 0;
  }
  stats_.hid_pairs += hidden > 0 ? 1 : 0;
  stats_.hidden_mfs += static_cast<std::uint64_t>(hidden);
}

}  // namespace markcell::rig
