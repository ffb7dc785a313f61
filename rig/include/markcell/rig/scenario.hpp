#pragma once
// The rig's named scenarios, each generated deterministically from a seed, and the
// generator that turns one into a recording (vision/RECORDING.md) with its ground truth
// and the inspection station's record.
//
//   paper-door        the paper's door: 3 dings, sled 1.2-1.6 cm/s fluctuating, 36 s
//   paper-fender      the fender: 4 defects, same line
//   paper-curved      the door on a rotated sled (a curved line section, about Y0)
//   line-fast         a real line: 15 cm/s +-10 %, the door crossing the whole view
//   occlusion-person  paper-door with a person walking through the view
//   frame-drops       paper-door with frames lost (10 %, and a burst of 15)
//   nine-defects      the door with 9 dings about 30 cm apart (the paper's capacity)
//   calibration-board a checkerboard on the gripper at the configured robot poses (15
//                     in the example), the camera where the configured X_Base_CamR is
//                     not quite: what `markcell calibrate-base` must find
#include <atomic>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Geometry>

#include "markcell/common/time.hpp"
#include "markcell/rig/inspection.hpp"
#include "markcell/rig/line_motion.hpp"
#include "markcell/vision/panel_tracker.hpp"
#include "markcell/rig/render.hpp"

namespace markcell::rig {

// recording.yaml's `generator` of the recordings `markcell sim` makes.
inline constexpr std::string_view kRigGenerator = "markcell sim";

struct PersonWalk {
  Nanos enter = 0, leave = 0;      // crossing the view between these times
  Eigen::Vector3d from_CamR, to_CamR;  // the person's feet-to-head axis moves between these points (its middle)
};

struct Scenario {
  std::string name;
  std::string panel_type;
  std::uint64_t seed = 1;
  double fps = 30.0;
  Nanos duration = seconds(36);
  SpeedProfile speed;
  LinePath path;
  std::vector<DefectSpec> defects;
  std::vector<PersonWalk> people;
  double drop_ratio = 0.0;                 // frames lost at random
  std::uint64_t drop_burst_start = 0, drop_burst_length = 0;  // and a burst of lost frames
  double exposure_drift = 0.04;            // relative amplitude of a slow exposure drift
  Eigen::Isometry3d X_SL_Panel = Eigen::Isometry3d::Identity();  // the panel at the inspection station
  InspectionNoise inspection;
  // calibration-board: the true camera pose relative to the configured one (a few
  // centimetres and a degree: an installation's nominal drawing against reality).
  Eigen::Isometry3d X_CamRnominal_CamR = Eigen::Isometry3d::Identity();
  bool board_only = false;  // calibration-board: no panel, no line
};

const std::vector<std::string>& scenario_names();
// Throws std::invalid_argument naming the known scenarios for an unknown name.
Scenario make_scenario(const std::string& name, std::uint64_t seed);

struct GenerateOptions {
  Nanos max_duration = -1;   // shorten the scenario (tests); -1: whole
  double fps = -1;           // override the frame rate; -1: the scenario's
  // Looked at before each frame: non-zero (a signal's number) throws GenerationStopped.
  const std::atomic<int>* stop = nullptr;
};

// Rendering stopped by a signal: the folder holds the frames rendered so far and no
// recording.yaml (so it is not a recording).
struct GenerationStopped : std::runtime_error {
  GenerationStopped(const std::string& what, int sig) : std::runtime_error(what), signal(sig) {}
  int signal = 0;
};

// Writes the scenario to `folder` as a recording of `panel` (the scenario's panel type,
// load_panel): frames (those not dropped), truth, defects, the stereo calibration used,
// the panel's mesh, and inspection.yaml. Returns the frames written.
std::size_t generate_recording(const Scenario& scenario, const rig::Panel& panel, const std::string& folder,
                               const vision::StereoCalibration& marking, const vision::StereoCalibration& scanner,
                               const rig::RenderSettings& render, const GenerateOptions& options = {});

// The panel type's file as the installation engineer would make it with select-mfs: the
// panel rendered square to the left camera, its MFs where the camera model projects
// them (then snapped to the corner, as the tool does). Also returns the reference image.
vision::PanelTypeModel reference_panel_type(const Scenario& scenario, const rig::Panel& panel,
                                            const vision::StereoCalibration& marking,
                                            const rig::RenderSettings& render, cv::Mat* reference_left = nullptr);

// Whether frame `index` of the scenario is lost (deterministic from its seed).
bool frame_dropped(const Scenario& scenario, std::uint64_t index);

}  // namespace markcell::rig
