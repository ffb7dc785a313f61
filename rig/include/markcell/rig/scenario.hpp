#pragma once
// The rig's scenarios are files (config/scenarios/NAME.yaml, docs/rig.md "Scenario
// files"): a panel type, the line's motion and curve, defects with centres and radii,
// people walking through the view, frame drops, a PLC script, a seed, the duration and
// the frame rate; or a calibration board on the gripper (`kind: calibration-board`).
// Each is generated deterministically from its seed into a recording
// (vision/RECORDING.md) with its ground truth and the inspection station's record.
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
  double board_offset_m = 0.02, board_angle_rad = 0.015;  // calibration-board: bounds of that offset
  std::string plc_script;   // PLC inputs during the replay (markcell/sim/plc_script.hpp); empty: none
};

// Reads a scenario file. Throws std::runtime_error "FILE:LINE: KEY: what is wrong" (an
// unknown key, a value out of its range, a rotation that is not one, a PLC script
// outside the file's folder), or FileRefused for a file that is not a regular one of at
// most 1 MiB. The scenario's name is the file's stem.
Scenario load_scenario(const std::string& path);
// The scenario with another seed (noise, speed fluctuation, drops, the board's offset).
Scenario with_seed(Scenario scenario, std::uint64_t seed);
// The shipped scenarios' folder for a configuration file: `scenarios/` beside it.
std::string scenario_folder(const std::string& config_file);
// The names of the scenario files in a folder (their stems), sorted.
std::vector<std::string> scenario_names(const std::string& folder);
// A scenario file from a name (FOLDER/NAME.yaml) or a path (ending in .yaml or .yml, or
// with a '/'). Throws std::invalid_argument listing the folder's names for an unknown one.
std::string scenario_file(const std::string& name_or_file, const std::string& folder);
// scenario_file, load_scenario and with_seed in one.
Scenario find_scenario(const std::string& name_or_file, const std::string& folder, std::uint64_t seed);
// calibration-board: draws X_CamRnominal_CamR from the seed within the offset's bounds.
void draw_board_offset(Scenario& scenario);

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
