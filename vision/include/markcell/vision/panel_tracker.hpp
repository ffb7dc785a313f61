#pragma once
// The paper's pose and motion estimator (sections II, III.A) as a bounded-time step:
// a panel type's macro-features (MFs) are found again when a new panel enters the view,
// then followed frame to frame in both views and triangulated, and the rigid motion of
// the MF set gives the panel's pose.
//
// Frames: CamR (the tracking frame) and P, the panel frame the tracker sets up at
// re-initialisation: P is where CamR was when the panel's MFs were found, so X_CamR_P is
// the identity on that frame and the panel's motion since then afterwards. The
// inspection station's frame follows from one inter-calibration per panel:
// X_CamR_SL(t) = X_CamR_P(t) * X_P_SL.
//
// Model (immutable: the panel type, the rig, the parameters) plus a workspace allocated
// once at construction: process() allocates nothing and every loop in it has a bound
// fixed by the configuration.
#include <array>
#include <cstdint>
#include <string>
#include <string_view>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "markcell/common/fixed_vector.hpp"
#include "markcell/common/param.hpp"
#include "markcell/common/time.hpp"
#include "markcell/msg/pose_estimate.hpp"
#include "markcell/vision/hole_fit.hpp"
#include "markcell/vision/optical_flow.hpp"
#include "markcell/vision/stereo_rig.hpp"

namespace markcell::vision {

// The messages this task publishes are leaves in common/ (msg/), read by control/.
using msg::kMaxMacroFeatures;
using msg::MacroFeatureObservation;
using msg::PoseEstimate;
using msg::TrackStatus;
using msg::to_string;

inline constexpr int kTemplateRadius = 7;  // 15x15 template patches

// What an MF is on the panel: a corner (of the outline, a cut-out, a character line's
// end), refined as a Shi-Tomasi corner; or a round or oval hole's centre, refined by an
// ellipse fitted to its edge (hole_fit.hpp) in each view.
// kUnseen: an MF of the panel type that this station cannot measure (a hole too large for
// the template at the inspection scanner's scale, a corner its fixture hides): kept in
// the panel type's order, never searched for; the inspection record gives it as `~`.
enum class MfKind : std::uint8_t { kCorner, kHole, kUnseen };
std::string_view to_string(MfKind k);
// What select-mfs is asked for at a click: a corner, a hole, or whichever is there (or,
// from code, an MF this station does not see).
enum class MfKindRequest : std::uint8_t { kAuto, kCorner, kHole, kUnseen };
struct MfPick {
  Eigen::Vector2d px = Eigen::Vector2d::Zero();
  MfKindRequest kind = MfKindRequest::kAuto;
};

// A panel type's MFs as the installation engineer picked them on a reference image of
// the left camera (markcell select-mfs), with their template patches.
struct PanelTypeModel {
  std::string name;
  int image_width = 0, image_height = 0;
  int search_x = 160, search_y = 40;  // half range of the panel's shift at re-initialisation, px
  struct Mf {
    Eigen::Vector2d reference_px = Eigen::Vector2d::Zero();  // on the reference image
    MfKind kind = MfKind::kCorner;
    double hole_radius_px = 0;  // a hole's mean semi-axis on the reference image (its rays' reach follows)
    Patch template_patch;  // level 0
    Patch coarse_template;  // at the coarse search level
  };
  FixedVector<Mf, kMaxMacroFeatures> mfs;  // in the order the engineer picked them
  int count() const { return mfs.ssize(); }
};
inline constexpr int kCoarseLevel = 2;

// Where an MF clicked at `clicked` goes: the strongest Shi-Tomasi corner within
// `snap_radius` px of the click (a disc; 0: no search), refined to sub-pixel. It may end
// at most snap_limit_px(snap_radius) from the click: a corner farther away is another
// feature than the one clicked (a round hole's rim beside its centre), refused with both
// positions, never taken without a word.
//
// A hole: its edge searched on rays from the click out to the snap radius (at least 14
// px), its fitted centre may likewise end at most snap_limit_px from the click, and it
// must fit the template (a radius of at most kMaxHoleMfRadiusPx). Asked for neither
// kind, a click inside a clean hole's edge (at least 3/4 of the rays meet it, 0.2 px
// rms) is a hole, anything else a corner.
inline constexpr double kMaxHoleMfRadiusPx = kTemplateRadius - 1;
// A corner's least Shi-Tomasi score (smaller eigenvalue of the 5x5 gradient matrix per
// pixel, grey^2): e-coat's texture and the sensor's noise score about 1, an edge turning
// between panel and background hundreds.
inline constexpr double kMinCornerStrength = 20;
struct SnapResult {
  Eigen::Vector2d p = Eigen::Vector2d::Zero();  // where the MF goes
  double moved_px = 0;                          // from the click
  MfKind kind = MfKind::kCorner;
  double hole_radius_px = 0;                    // a hole's
  std::string problem;                          // empty: usable; else why not
  bool ok() const { return problem.empty(); }
};
SnapResult snap_macro_feature(const cv::Mat& reference_left, const Eigen::Vector2d& clicked, int snap_radius,
                              MfKindRequest kind = MfKindRequest::kAuto);
// The snap radius, or 1 px with none (the sub-pixel refinement's own allowance).
double snap_limit_px(int snap_radius);

// Builds a model from a reference image and MF positions, each through
// snap_macro_feature. Throws naming the MF and its SnapResult's problem.
PanelTypeModel make_panel_type(const std::string& name, const cv::Mat& reference_left, const std::vector<MfPick>& picks,
                               int snap_radius, int search_x, int search_y);
// OpenCV FileStorage YAML: panel_type, image_width, image_height, search_x_px,
// search_y_px, macro_features (Nx2 px), kinds (N of corner, hole; absent: all corners),
// hole_radius_px (N, 0 for a corner), templates and coarse_templates (N rows of patch
// values). Errors name the file and the key.
void save_panel_type(const std::string& path, const PanelTypeModel& model);
PanelTypeModel load_panel_type(const std::string& path);

// The tracker's parameters. The ones in Visit() are the configuration's `vision:`
// section, declared here once (key, unit, range, what it does); the initialisers are
// their only defaults.
struct TrackerParams {
  LkParams lk;
  int pyramid_levels = 3;
  int corner_radius = 5;            // Shi-Tomasi refinement window, half size
  double corner_agree_px = 1.0;     // the right view's corner within this of LK's match
  double forward_backward_px = 0.5; // forward-backward consistency of frame-to-frame LK
  double epipolar_px = 1.0;         // max distance from the epipolar line
  double epipolar_jump_px = 0.2;    // max change of a tracked MF's rectified row difference between frames
  double min_ncc = 0.75;            // template match score that counts as found
  int min_macro_features = 4;       // fewer than this: no pose
  double inlier_m = 0.008;          // rigid-motion consistency of an MF, metres (depth noise is ~2 mm)
  double depth_min = 2.0, depth_max = 4.5;  // where a panel can be, metres from CamR
  int lost_frames_to_reinit = 15;   // frames without a pose before the MFs are searched anew
  int reinit_local_px = 0;          // each MF's own search around the panel's common shift (0: the shift's only)
  int ransac_iterations = 64;
  int reference_samples = 256;      // frames averaged into each MF's position in P

  template <class V>
  void Visit(V& v) {
    v(Param{"epipolar_px", Unit::kPixel, 0.05, 20.0, "a left/right pair further than this from its epipolar line is rejected"},
      epipolar_px);
    v(Param{"epipolar_jump_px", Unit::kPixel, 0.02, 20.0,
            "a tracked MF whose left/right row difference (rectified) changes more than this between frames is left out "
            "that frame (the arm across one view's window)"},
      epipolar_jump_px);
    v(Param{"min_ncc", Unit::kNone, 0.0, 1.0, "template match that counts as found (re-initialisation, reacquisition)"},
      min_ncc);
    v(Param{"lk_window_px", Unit::kOddWindowPx, 5, 2 * kMaxLkRadius + 1, "pyramidal Lucas-Kanade window (odd)"}, lk.radius);
    v(Param{"pyramid_levels", Unit::kNone, 3, kMaxPyramidLevels, "levels of the image pyramids"}, pyramid_levels);
    v(Param{"min_macro_features", Unit::kNone, 3, kMaxMacroFeatures, "fewer MFs consistent with a rigid motion: no pose"},
      min_macro_features);
    v(Param{"inlier_mm", Unit::kMillimetre, 0.1, 100.0,
            "an MF further than this from the rigid motion is an outlier (stereo depth noise ~2 mm)"},
      inlier_m);
    v(Param{"depth_min_m", Unit::kMetre, 0.1, 50.0, "where a panel can be, from the right camera ..."}, depth_min);
    v(Param{"depth_max_m", Unit::kMetre, 0.1, 50.0, "... to here"}, depth_max);
    v(Param{"forward_backward_px", Unit::kPixel, 0.01, 10.0, "frame-to-frame LK forward-backward consistency"},
      forward_backward_px);
    v(Param{"lost_frames_to_reinit", Unit::kNone, 1, 10'000, "frames without a pose before the MFs are searched anew"},
      lost_frames_to_reinit);
    v(Param{"reinit_local_px", Unit::kPixel, 0, 200,
            "at re-initialisation, how far each MF may lie from where the panel's common shift puts it (a panel turned "
            "or nearer than the reference: the inspection station's scanner; 0 on a line that only translates the panel)"},
      reinit_local_px);
  }
  // What no single key's range says: report(key, message) for each problem.
  template <class Report>
  void validate(Report&& report) const {
    if (depth_min >= depth_max) report("depth_max_m", "must be greater than depth_min_m");
  }
};

// One MF as a station measures it on a single stereo pair (markcell inspect): where it is
// in both views, where that puts it in the left camera's frame, and how well it was seen.
struct MfMeasurement {
  bool found = false;
  Eigen::Vector2d left = Eigen::Vector2d::Zero(), right = Eigen::Vector2d::Zero();  // observed pixels
  Eigen::Vector3d p_CamL = Eigen::Vector3d::Zero();  // triangulated (DLT), the left camera's frame, m
  double epipolar_px = 0;      // the pair's distance from its epipolar line (undistorted, symmetric)
  double corner_response = 0;  // a corner's Shi-Tomasi score at the left pixel (grey^2 per pixel); 0 for a hole
  double hole_rms_px = 0;      // a hole's ellipse fit residual in the left view; 0 for a corner
};
struct StereoMeasurement {
  int found = 0;
  std::string_view reason;  // empty when at least min_macro_features were found; else why not (static text)
  FixedVector<MfMeasurement, kMaxMacroFeatures> mfs;  // the panel type's order
  bool ok() const { return reason.empty(); }
};

class PanelTracker {
 public:
  PanelTracker(const StereoRig& rig, const PanelTypeModel& model, const TrackerParams& params);
  // One stereo pair (8-bit, the rig's size). Bounded time, no allocation.
  const PoseEstimate& process(std::uint64_t seq, Nanos time, const cv::Mat& left, const cv::Mat& right);
  // A new panel: the next frame searches for the MFs.
  void reset();
  // The inspection station's step (the same search, match, refinement and checks as a
  // re-initialisation; the rig being the scanner's pair): the MFs found anew on this one
  // pair, each with its quality. Leaves the tracker searching.
  const StereoMeasurement& measure(const cv::Mat& left, const cv::Mat& right);
  // The MFs' positions in P (valid where `known`), set at re-initialisation; an MF not
  // found then can be given its position (from the inspection record through the
  // inter-calibration) so that it is picked up when it comes into view.
  const std::array<Eigen::Vector3d, kMaxMacroFeatures>& reference_P() const { return reference_P_; }
  const std::array<bool, kMaxMacroFeatures>& reference_known() const { return known_; }
  void set_reference(int mf, const Eigen::Vector3d& p_P);
  const PoseEstimate& last() const { return estimate_; }
  const PanelTypeModel& model() const { return model_; }

 private:
  void reinitialise();
  void track();
  bool find_right(int mf, const Eigen::Vector2d& left, Eigen::Vector2d& right) const;
  bool verify_pair(int mf, const Eigen::Vector2d& left, const Eigen::Vector2d& right) const;
  // The MF's sub-pixel position near `p` in `image`, as its kind is found: a corner, or a
  // hole's fitted centre (within its radius of `p`).
  bool refine(int mf, const Pyramid& image, Eigen::Vector2d& p) const;
  void fit_pose();
  void reacquire();

  const StereoRig& rig_;
  const PanelTypeModel model_;
  const TrackerParams params_;
  const LkParams level0_lk_;  // params_.lk on level 0 only: for a guess known to a pixel or two
  Pyramid left_[2];
  Pyramid right_;
  int cur_ = 0;
  bool have_previous_ = false;
  bool searching_ = true;
  int lost_frames_ = 0;
  PoseEstimate estimate_;
  StereoMeasurement measurement_;
  void refine_reference(const Eigen::Isometry3d& X_CamR_P);

  std::array<Eigen::Vector3d, kMaxMacroFeatures> reference_P_{};
  std::array<bool, kMaxMacroFeatures> known_{};
  // Each MF's position in P as first known (the frame that set P up, or the record), and
  // the running sum of where the fitted poses put its observations since.
  std::array<Eigen::Vector3d, kMaxMacroFeatures> first_P_{}, sum_P_{};
  std::array<int, kMaxMacroFeatures> samples_{};
  std::array<int, kMaxMacroFeatures> observed_{};
  std::array<bool, kMaxMacroFeatures> set_up_{};   // found when P was set up (not placed)
  std::array<bool, kMaxMacroFeatures> tracked_{};  // has a left/right position from the previous frame
  std::array<Eigen::Vector2d, kMaxMacroFeatures> prev_left_{}, prev_right_{}, velocity_{};
  std::array<double, kMaxMacroFeatures> row_{};  // each MF's rectified row difference when last accepted
  double epipolar_row(const Eigen::Vector2d& left, const Eigen::Vector2d& right) const;
  std::array<Patch, kMaxMacroFeatures> patch_{};   // left template per MF, taken at re-initialisation
  std::array<HoleFitParams, kMaxMacroFeatures> hole_params_{};  // each hole MF's rays, from its radius (start-up)
};

}  // namespace markcell::vision
