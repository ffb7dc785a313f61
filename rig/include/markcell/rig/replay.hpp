#pragma once
// The rig's runs: a recording replayed through the cell in simulated time (the same
// executable, configuration and tasks as the live cell; the arm, valve and PLC on their
// simulated twins), scored against the recording's ground truth, and reported.
//
//   markcell replay RECORDING --out DIR    an existing recording
//   markcell sim SCENARIO --out DIR        a scenario generated into DIR/recording, then replayed
//   markcell replay RECORDING --gpio-sim DIR --out DIR
//                                          in real time on the configured real devices (a
//                                          libgpiod chip, the CAN arm link), the rig's
//                                          world behind them (rig/hil_peer.hpp); scored alike
//
// Each run replays the recording once per predictor (the configured one first, then the
// other), so both are reported from the same frames.
#include <atomic>
#include <optional>
#include <string>
#include <vector>

#include "markcell/sim/plc_script.hpp"

#include <Eigen/Geometry>

#include "markcell/control/marking.hpp"
#include "markcell/host/cell.hpp"
#include "markcell/host/config.hpp"
#include "markcell/rig/arm_view.hpp"
#include "markcell/rig/scoring.hpp"

namespace markcell::rig {

struct ReplayOptions {
  std::string out_dir;
  bool progress = false;            // a progress line on stderr while it runs
  bool both_predictors = true;      // also replay with the predictor not configured
  Nanos tail = seconds(15);         // simulated time after the last frame for the panel to finish
  double radius = 0.010;            // a spray within this of a defect's centre marks it, m
  // The simulated arm drawn into the frames in closed loop (rig/arm_view.hpp): by default
  // only into the rig's own recordings (recording.yaml's `generator: markcell sim`); a
  // real recording shows the real arm already, and another tool's is its own scene.
  enum class ArmDrawing { kRigRecordings, kAlways, kNever };
  ArmDrawing draw_arm = ArmDrawing::kRigRecordings;
  // The stereo calibration to replay with (--calibration). Empty: the recording's, which
  // must then agree with the configuration's calibration.stereo.
  std::string calibration;
  // The PLC's inputs scripted on top of the panel-present line the replay drives itself
  // (markcell/sim/plc_script.hpp): an e-stop, a cycle disable, a panel leaving early.
  std::vector<sim::PlcEvent> plc_events;
  bool plc_script_given = false;  // --plc-script: it, not a scenario's own script
  // Real devices, real time: the gpio-sim chip's sysfs folder the rig's peer drives the
  // PLC's inputs and reads the valve through (/sys/devices/platform/gpio-sim.N/gpiochipM).
  // Empty: simulated devices in simulated time. The arm is not drawn into the frames.
  std::string gpio_sim;
  // With gpio_sim, for an arm on a serial line: the line's other end, where the rig's arm
  // answers (a second port with a null-modem cable, or socat's other pty).
  std::string arm_serial_peer;
  // Set (to the signal's number) when the user asks the run to stop (StopSignalWatcher):
  // looked at every 100 ms of simulated time (every 5 ms in real time); the run then ends
  // there, reported as stopped, and the other predictor's run is not made.
  const std::atomic<int>* stop = nullptr;
};

struct TimedPoint {
  Nanos time = 0;
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
};

// One panel-present episode of a replay: the panel the cell handled in it, scored on the
// sprays made from its start to the next panel's.
struct PanelRun {
  control::PanelResult result;
  Score score;                                  // when the recording has ground truth
};

struct PredictorRun {
  std::string predictor;
  // Every panel the run handled, in order: one per panel-present episode the recording
  // and the PLC script give (the rig's own: present from the first frame to the last).
  std::vector<PanelRun> panels;
  int episodes = 0;                             // panel-present episodes the PLC gave (panels expected)
  Score score;                                  // all of them together (defects listed per panel, in order)
  control::PanelResult panel;                   // the first panel (plan, inter-calibration, plots)
  bool scored = false;                          // the recording has ground truth
  std::optional<Eigen::Vector3d> prediction_max_abs;  // at the sprays, CamR axes, m
  struct DefectPrediction {
    int id = 0;
    Eigen::Vector3d abs = Eigen::Vector3d::Zero();  // |predicted - true| centre at its spray, CamR, m
  };
  std::vector<DefectPrediction> prediction_per_defect;
  Eigen::Vector3d one_frame_max_abs = Eigen::Vector3d::Zero();  // estimated vs one-frame-ahead prediction, m
  // Panel pose error: where the tracked pose puts the defect being marked vs where the
  // true motion puts that point of P, every frame of the approach, m; P placed on the
  // panel as its set-up MFs place it (PanelFrameRecord); and its max over the frames with
  // MFs missing (occluded or out of view). setup_frame: the same with P taken as exactly
  // CamR at set-up, which adds P's own placement error (one frame's triangulation of the
  // MFs then in view) though no spray moves with it.
  double pose_error_max = 0, pose_error_rms = 0, pose_error_missing_max = 0, pose_error_setup_frame_max = 0;
  int pose_samples = 0, pose_samples_missing = 0;
  // The whole chain: the defect's position from the inspection record, through the
  // inter-calibration and the tracked pose, vs truth, m.
  double defect_error_max = 0, defect_error_rms = 0;
  double seconds_per_defect = 0;
  std::uint64_t deadline_misses = 0, overruns = 0;
  host::VisionStats vision;
  ArmOverlayStats arm;                          // synthetic recordings: the arm drawn into the frames
  std::uint64_t frames_skipped = 0;
  std::uint64_t peer_late_ticks = 0;            // real devices: the rig peer's ticks begun a period late
  std::string timing_report;
  std::vector<std::string> faults;
  std::vector<control::PredictionSample> samples;        // every panel's, in order
  std::vector<control::PanelFrameRecord> panel_frames;   // every panel's (its first 16 each)
  std::vector<TimedPoint> truth_samples;        // the same defect's true position at each sample
  sim::CommandLogText command_log;              // every command to the arm and the valve edge (can/serial/valve.log)
  int stopped_by = 0;                           // the signal that ended the run early (0: it ran to its end)
  Nanos stopped_at = 0;                         // when, from the run's start
};

struct ReplayReport {
  std::string scenario;
  std::string recording;
  std::string panel_type;
  std::string calibration;                      // the stereo calibration replayed with (and plotted with)
  std::string devices = "simulated";            // what the cell ran on, and its clock with it
  std::vector<std::string> index_problems;      // frames.csv lines refused (not replayed), with why
  std::vector<PredictorRun> runs;               // runs[0]: the configured predictor
  // A run stopped by a signal: the report is partial (its score counts what was done by
  // then) and says so, by the signal's name; empty when every run ran to its end.
  std::string stopped;
};

// Throws (naming the file and what is wrong) when the recording or the configuration
// cannot be used.
ReplayReport replay_recording(const host::CellConfig& config, const std::string& recording, const ReplayOptions& options);

// DIR/report.json and the plots; returns the files written.
std::vector<std::string> write_report(const ReplayReport& report, const host::CellConfig& config, const std::string& out_dir);
// The marking table (with the paper's figures beside), the timing table and the paths.
std::string report_table(const ReplayReport& report, const std::vector<std::string>& files);

// The inspection station's figures of a recording the rig made (its
// recording/inspection/mfs.csv: rig/inspection.hpp): MFs measured, their epipolar
// residuals and their errors against the truth. None for another tool's recording.
struct InspectionFigures {
  int mfs = 0, measured = 0;
  double epipolar_median = 0, epipolar_max = 0, error_median_mm = 0, error_max_mm = 0;
  std::vector<double> errors_mm;  // each measured MF's
};
std::optional<InspectionFigures> inspection_figures(const std::string& recording);

}  // namespace markcell::rig
