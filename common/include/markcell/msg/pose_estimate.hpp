#pragma once
// The vision lane's message to the marking task: the panel's pose in one stereo pair and
// what it rests on. A leaf (plain Eigen, no OpenCV): the tracker in vision/ publishes it,
// control/ reads it, neither includes the other (uORB's msg/ plays this role in PX4).
#include <cstdint>
#include <string_view>

#include <Eigen/Geometry>

#include "markcell/common/fixed_vector.hpp"
#include "markcell/common/time.hpp"

namespace markcell::msg {

// Macro-features a panel type may have: the size of every array below.
inline constexpr int kMaxMacroFeatures = 16;

enum class TrackStatus : std::uint8_t {
  kTracking,        // pose from tracked MFs
  kReinitialised,   // MFs found anew this frame; X_CamR_P is the identity
  kSearching,       // no panel found (reason says why)
  kLost,            // too few MFs this frame; pose is the last one
};

inline std::string_view to_string(TrackStatus s) {
  switch (s) {
    case TrackStatus::kTracking: return "tracking";
    case TrackStatus::kReinitialised: return "reinitialised";
    case TrackStatus::kSearching: return "searching";
    case TrackStatus::kLost: return "lost";
  }
  return "?";
}

// One macro-feature of the panel type: what this frame saw of it, and where the tracker
// holds it in P.
struct MacroFeatureObservation {
  bool valid = false;     // seen in both views this frame
  bool inlier = false;    // and consistent with the rigid motion
  Eigen::Vector2d left = Eigen::Vector2d::Zero(), right = Eigen::Vector2d::Zero();  // observed pixels
  Eigen::Vector3d p_CamR = Eigen::Vector3d::Zero();
  // Its position in P (where known): what the inter-calibration pairs with the inspection
  // record. Copied with every estimate so that a reader across lanes never needs the
  // tracker itself.
  Eigen::Vector3d reference_P = Eigen::Vector3d::Zero();
  bool reference_known = false;
  // Frames it was seen in and used since P was set up (its position in P averages them);
  // 0 for an MF only placed through the inspection record so far.
  int reference_observed = 0;
};

struct PoseEstimate {
  std::uint64_t seq = 0;
  Nanos time = 0;                   // capture time of the frame pair
  TrackStatus status = TrackStatus::kSearching;
  std::string_view reason;          // why there is no pose (static text)
  std::uint32_t reference_serial = 0;  // changes whenever P is set up anew
  Nanos reference_time = 0;            // capture time of the frame that set P up
  Eigen::Isometry3d X_CamR_P = Eigen::Isometry3d::Identity();
  int tracked = 0;                  // MFs seen in both views
  int inliers = 0;                  // MFs used for the pose
  double rms = 0;                   // residual of the rigid fit, metres
  FixedVector<MacroFeatureObservation, kMaxMacroFeatures> mfs;  // one per MF of the panel type, in its order
  bool has_pose() const { return status == TrackStatus::kTracking || status == TrackStatus::kReinitialised; }
};

}  // namespace markcell::msg
