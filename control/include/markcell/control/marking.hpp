#pragma once
// The marking sequence (paper Fig. 9) as the `marking` task of the control lane:
//
//   idle -> (PLC panel present, cycle enabled, an inspection record) -> acquire: the
//   vision task re-initialises the panel's MFs; the inter-calibration pairs them with the
//   record (X_P_SL, Table I metrics; above the limit: no marking, PLC fault) and each
//   defect gets its tool pose -> hold (the arm at home) until the refits place every
//   defect surely enough, or waiting longer would cost one -> for each defect,
//   downstream first: approach (the arm
//   follows the nozzle pose predicted for the time the set-point takes effect), settle
//   (within tolerance for the settle time, on a fresh prediction), spray (one valve
//   pulse) -> home -> PLC done (or fault) -> wait for the panel to leave -> idle.
//
// Every defect ends marked or skipped with a reason; every panel ends with a result.
// Fixed storage; step() is bounded and allocates nothing.
#include <array>
#include <atomic>
#include <cstdint>
#include <numbers>
#include <span>
#include <string_view>

#include <Eigen/Geometry>

#include "markcell/common/fixed_string.hpp"
#include "markcell/common/fixed_vector.hpp"
#include "markcell/common/param.hpp"
#include "markcell/common/triple_buffer.hpp"
#include "markcell/control/executive.hpp"
#include "markcell/control/intercalibration.hpp"
#include "markcell/control/planner.hpp"
#include "markcell/control/plc_io.hpp"
#include "markcell/control/predictor.hpp"
#include "markcell/control/spray_valve.hpp"
#include "markcell/control/tool_pose.hpp"
#include "markcell/drivers/arm.hpp"
#include "markcell/msg/line_arrival.hpp"
#include "markcell/msg/pose_estimate.hpp"
#include "markcell/msg/tracker_request.hpp"

namespace markcell::control {

inline constexpr int kMaxDefects = 16;
inline constexpr int kMaxDefectPoints = 256;

// An inspection record, validated, in fixed storage (what the record reader hands over).
// Panel types a cell knows at most (a recipe and a tracker model each).
inline constexpr int kMaxPanelTypes = 16;

struct PanelJob {
  FixedString<63> panel_id;
  FixedString<31> panel_type;
  int panel_type_index = 0;  // in the configuration's panel_types: which tracker
  FixedVector<Eigen::Vector3d, msg::kMaxMacroFeatures> mfs_SL;  // the record's MFs, the panel type's order
  struct Defect {
    int id = 0;
    FixedVector<Eigen::Vector3d, kMaxDefectPoints> points_SL;  // its surface points
  };
  FixedVector<Defect, kMaxDefects> defects;
  // Pairing by panel id: the line's arrival counter the record was offered for (0: none,
  // records in order). The sequence answers it at once when the line has moved on to
  // another panel, or when that announcement's panel went by without it.
  std::uint32_t announced = 0;
};

enum class SkipReason : std::uint8_t {
  kNone,
  kIntercalibration,  // the panel's inter-calibration failed or exceeded its limit
  kToolPose,          // degenerate point cluster
  kOutOfReach,        // the spraying pose never came within the arm's reach
  kNotSettled,        // the arm did not settle on the moving target in time
  kNoPrediction,      // the panel was not tracked (lost, occluded) when it was needed
  kNotFound,          // the panel's MFs were not found
  kStopped,           // safe stop, e-stop or the panel left before its turn
  kPlanned,           // the plan: the line carries it out of reach before its turn
  kNoPanel,           // the record expired: its panel never came
  kPlacement,         // the inter-calibration never placed it surely enough (MFs too few, too close)
  kCutShort,          // its pulse was cut short: panel present dropped (or glitched) during it
};
std::string_view to_string(SkipReason r);

struct DefectResult {
  int id = 0;
  bool sprayed = false;
  SkipReason skipped = SkipReason::kNone;
  ToolPoseStatus tool = ToolPoseStatus::kOk;
  Nanos approach_start = -1;
  Nanos spray_requested = -1;
  // How surely the inter-calibration in use places its centre (Intercalibration::
  // placement_sigma), m: above the limit the arm follows it but does not spray.
  double placement_sigma = 0;
  // What the controller believed at the spray: the defect's centre in CamR there and then.
  Eigen::Vector3d predicted_centre_CamR = Eigen::Vector3d::Zero();
  Eigen::Isometry3d X_Base_Nozzle = Eigen::Isometry3d::Identity();  // last set-point
  // The plan made once the panel's motion was known: the verdict, and when it expected
  // the pulse (executive clock; -1: not planned feasible).
  PlanVerdict plan = PlanVerdict::kNotPlanned;
  Nanos planned_spray = -1;
};

struct PanelResult {
  std::uint64_t serial = 0;  // panels handled since start
  FixedString<63> panel_id;
  bool fault = false;
  FixedString<119> reason;  // when fault
  Intercalibration intercalibration;
  FixedVector<DefectResult, kMaxDefects> defects;  // one per defect of the record, in its order
  Nanos started = 0, finished = 0;
  Nanos planned_at = -1;  // when the plan was made (-1: never, the panel ended first)

  // The panel's defects counted by outcome: the one count the journal, the replay's
  // progress, the report and the tests use.
  // (A pulse cut short is both: sprayed, and skipped with that reason.)
  struct Tally {
    int sprayed = 0;
    int skipped = 0;  // with a reason
  };
  Tally tally() const {
    Tally t;
    for (const DefectResult& d : defects) {
      t.sprayed += d.sprayed ? 1 : 0;
      t.skipped += d.skipped != SkipReason::kNone ? 1 : 0;
    }
    return t;
  }
};

// The marking sequence's parameters. The ones in Visit() are the configuration's
// `marking:` section, declared here once (key, unit, range, what it does); the struct's
// initialisers are their only defaults. The others come from elsewhere: X_Base_CamR from
// the base calibration, timing's arm limits from `arm.limits`, timing.pulse from `spray`,
// require_result_ack from whether there is a results file.
struct MarkingParams {
  Eigen::Isometry3d X_Base_CamR = Eigen::Isometry3d::Identity();
  double standoff = 0.20;            // m, nozzle to surface (paper: 20 cm pre-contact)
  Nanos command_lead = millis(35);   // set-points are for now + lead (link and arm latency, pursuit lag)
  double settle_position = 0.0015;   // m
  double settle_angle = 0.6 * std::numbers::pi / 180.0;  // rad
  Nanos settle_time = millis(40);
  Nanos max_prediction_age = millis(400);  // newest pose older than this: wait, do not spray
  Nanos acquire_timeout = seconds(10);
  Nanos home_timeout = seconds(10);
  // A panel present (cycle enabled) this long with no inspection record: PLC fault, the
  // panel's result says so, nothing moves.
  Nanos record_timeout = seconds(5);
  // A record waiting this long (the sequence idle) with no panel present expires: its
  // panel's result is a fault saying so, the PLC hears fault, the next record moves up.
  Nanos record_expiry = seconds(300);
  // With a results file: the PLC hears done (or fault) only once the panel's result is
  // written and synced (acknowledge_result); past this, fault.
  bool require_result_ack = false;
  Nanos result_ack_timeout = seconds(2);
  // The line's travel in CamR (need not be unit length: the sequence normalises it).
  Eigen::Vector3d line_direction_CamR = Eigen::Vector3d::UnitX();  // downstream defects go first
  IntercalibrationLimits intercalibration;
  PredictorParams predictor;
  int min_defect_points = 6;
  // The plan (reach, limits, settle overhead, pulse, defect timeout) is made once this
  // many poses of the panel have come after its inter-calibration: the motion is known.
  // Its reach, pulse and defect timeout are the sequence's too.
  ArmTimingModel timing;
  int plan_after_poses = 6;
  // A panel entering the view shows the MFs of its leading edge first; fitted to those,
  // the inter-calibration levers their noise out to the defects beyond. The sequence
  // holds the arm at home after the inter-calibration until refits with the MFs that
  // come into view place every defect within intercalibration.max_placement_sigma, at
  // most this long, and no longer than the plan says it can wait without losing a
  // defect. 0: start at once (defects not yet placed are followed until they are).
  Nanos placement_hold = seconds(6);

  template <class V>
  void Visit(V& v) {
    v(Param{"standoff_m", Unit::kMetre, 0.01, 1.0, "nozzle to surface when spraying (the paper's pre-contact point)"},
      standoff);
    v(Param{"command_lead_ms", Unit::kMillisecond, 0, 1000,
            "set-points are for now + this: CAN and arm latency, and the arm's pursuit lag"},
      command_lead);
    v(Param{"settle_mm", Unit::kMillimetre, 0.05, 50.0, "the arm is on target within this ..."}, settle_position);
    v(Param{"settle_deg", Unit::kDegree, 0.01, 30.0, "... and this ..."}, settle_angle);
    v(Param{"settle_ms", Unit::kMillisecond, 0, 10'000, "... for this long before the valve opens"}, settle_time);
    v(Param{"max_prediction_age_ms", Unit::kMillisecond, 1, 60'000, "newest panel pose older than this: wait, do not spray"},
      max_prediction_age);
    v(Param{"defect_timeout_s", Unit::kSecond, 0.1, 600.0, "a defect not sprayed within this is skipped, with the reason"},
      timing.defect_timeout);
    v(Param{"acquire_timeout_s", Unit::kSecond, 0.1, 600.0, "the panel's MFs must be found within this of panel present"},
      acquire_timeout);
    v(Param{"home_timeout_s", Unit::kSecond, 0.1, 600.0, "the arm must be home within this of being sent there"},
      home_timeout);
    v(Param{"predictor", Unit::kNone, 0, 0, "kalman | two-frame (the paper's: last motion applied again)"},
      Choice<PredictorKind, 2>{predictor.kind, {{{"kalman", PredictorKind::kKalman}, {"two-frame", PredictorKind::kTwoFrame}}}});
    v(Param{"intercalibration_limit_mm", Unit::kMillimetre, 0.1, 1000.0,
            "max |error| per axis of the inspection-to-marking fit; above: no marking, PLC fault"},
      intercalibration.max_abs_error);
    v(Param{"placement_limit_mm", Unit::kMillimetre, 0.1, 1000.0,
            "a defect the fit places less surely (1 sigma, from its MFs' layout) is followed, not sprayed"},
      intercalibration.max_placement_sigma);
    v(Param{"placement_hold_s", Unit::kSecond, 0.0, 600.0,
            "the arm waits at home up to this (less if the plan says so) for refits to place every defect"},
      placement_hold);
    v(Param{"line_direction", Unit::kNone, -1.0, 1.0, "the line's travel in CamR: downstream defects are marked first"},
      line_direction_CamR);
    v(Param{"accel_sigma_m_s2", Unit::kMetrePerSecond2, 1e-6, 10.0, "Kalman: the line's speed fluctuation"},
      predictor.accel_sigma);
    v(Param{"lateral_sigma_mm", Unit::kMillimetre, 1e-3, 100.0, "Kalman: one MF's position noise across the view ..."},
      predictor.lateral_sigma);
    v(Param{"depth_sigma_mm", Unit::kMillimetre, 1e-3, 100.0, "... and along it (stereo depth)"}, predictor.depth_sigma);
    v(Param{"plan_settle_ms", Unit::kMillisecond, 0, 60'000,
            "the plan's time from arriving on a defect to its pulse (lead, pursuit, settle)"},
      timing.settle);
    v(Param{"record_timeout_s", Unit::kSecond, 0.1, 600.0,
            "panel present this long without an inspection record: PLC fault, nothing moves"},
      record_timeout);
    v(Param{"record_expiry_s", Unit::kSecond, 1.0, 86400.0,
            "a record waiting this long with no panel present: its panel's result a fault"},
      record_expiry);
  }
  // What no single key's range says: report(key, message) for each problem.
  template <class Report>
  void validate(Report&& report) const {
    if (line_direction_CamR.norm() < 0.5) report("line_direction", "must be a unit vector (the line's travel in CamR)");
  }
};

enum class MarkingState : std::uint8_t { kIdle, kAcquire, kHold, kApproach, kSpraying, kHome, kReporting, kWaitRelease };
std::string_view to_string(MarkingState s);

// Fig. 8 of the paper: at each new pose, where the predictor had put the current defect
// at that frame's time, and where the pose puts it.
struct PredictionSample {
  Nanos time = 0;
  int defect = 0;
  Eigen::Vector3d estimated_CamR = Eigen::Vector3d::Zero();
  Eigen::Vector3d predicted_CamR = Eigen::Vector3d::Zero();
  // The panel frame P this estimate is in: the capture time of the frame that set it up
  // (where X_CamR_P was the identity) and the defect's centre in it, so that the rig can
  // score the tracked motion apart from the inter-calibration.
  Nanos reference_time = 0;
  Eigen::Vector3d centre_P = Eigen::Vector3d::Zero();
  int inliers = 0, count = 0;
};

// A panel frame P as the tracker set it up: the MFs it found then and where it put them.
// P's place on the panel is fixed by these, to their triangulation noise: the rig takes
// that out to score the tracked motion alone (the tool poses and the inter-calibration
// live in the same P, so it moves no spray).
struct PanelFrameRecord {
  Nanos reference_time = 0;
  struct Mf {
    Eigen::Vector3d p_P = Eigen::Vector3d::Zero();
    bool found = false;  // found then (else p_P means nothing)
  };
  FixedVector<Mf, msg::kMaxMacroFeatures> mfs;  // one per MF of the panel type
};

// An MF's position in P counts as measured once averaged over this many frames.
inline constexpr int kMeasuredFrames = 10;

// The inter-calibration's fits for one pose, made where the pose is made: on the vision
// lane, with its 30 ms budget. (RANSAC over up to 16 MFs ran 93-337 us of the 1 kHz
// control lane's marking task, budget 200 us, on a loaded machine.) The marking sequence
// takes the one its state asks for; the fit is the same function on the same inputs.
struct PoseFits {
  std::uint32_t job_serial = 0;  // msg::TrackerRequest::job_serial these are for; 0: none made
  Intercalibration known;        // over every MF with a position in P (a new P)
  Intercalibration measured;     // over the MFs measured in kMeasuredFrames frames or more (a refit)
  int measured_count = 0;
  std::array<bool, msg::kMaxMacroFeatures> measured_mask{};
};

struct MarkingEstimate {
  msg::PoseEstimate pose;
  PoseFits fits;
};

// The panel under way, as the operator page shows it (host/operator_page.hpp): what the
// marking task is doing and each defect's state, published at the end of every step
// (wait-free; one reader, the service's thread). A defect's centre is in the tracker's P
// `reference_serial` names: the page draws it on the live view's pose of that P.
struct DefectProgress {
  int id = 0;
  bool sprayed = false;
  SkipReason skipped = SkipReason::kNone;
  bool placed = false;  // its centre in P is known (the inter-calibration placed it)
  Eigen::Vector3d centre_P = Eigen::Vector3d::Zero();
};
struct MarkingProgress {
  MarkingState state = MarkingState::kIdle;
  bool on_panel = false;            // a panel is under way (false: the last one's, if any)
  std::uint64_t panel_serial = 0;   // its PanelResult::serial (0: no panel yet)
  FixedString<63> panel_id;
  FixedString<31> panel_type;
  int current = -1;                 // the defect being marked (index), -1: none
  std::uint32_t reference_serial = 0;  // the P the centres are in (0: not placed yet)
  FixedVector<DefectProgress, kMaxDefects> defects;
};

// On the vision lane, with each pose of a panel whose record is known: bounded, no allocation.
void fit_pose_to_record(const msg::TrackerRequest& job, const msg::PoseEstimate& e, const IntercalibrationLimits& limits,
                        PoseFits& out) noexcept;

class MarkingSequence {
 public:
  static constexpr std::size_t kPredictionLog = 1 << 13;
  static constexpr std::size_t kPanelFrameLog = 16;
  MarkingSequence(const MarkingParams& params, drivers::ArmLink& arm, SprayValve& valve, drivers::GpioLines& lines,
                  const PlcLineMap& plc, const PlcIo& plc_io, TripleBuffer<MarkingEstimate>& estimates,
                  TripleBuffer<msg::TrackerRequest>& tracker_requests);

  // Each panel type's own parameters, by the index a PanelJob names it by (the
  // configuration's panel_types order): at start-up, and again from the service's thread
  // on a reload (wait-free). A panel runs on its type's from the moment its record is
  // taken, on the newest set given by then: never changed mid-panel. The keys a recipe
  // may change (the cell's kRecipeKeys) matter only within a panel. False (nothing
  // changed) beyond kMaxPanelTypes. Allocates nothing.
  bool set_recipes(std::span<const MarkingParams> per_panel_type);
  // From the record reader (another thread): one record waits; false when one already does.
  bool offer_job(const PanelJob& job);
  // No job waiting: the next offer_job from the same thread will be taken.
  bool can_offer() const { return !job_waiting_.load(std::memory_order_acquire); }
  // Pairing by panel id (docs/line.md), before the cell starts: the line's announcements
  // (the newest; written by the panel-id source). A panel present starts only with the
  // waiting record whose id the line announced last, once per announcement (its
  // counter); a record for another id is answered as one whose panel never came; a
  // panel without its record goes by unmarked with the announced id in its result. No
  // word from the source for `silent`: safe stop (the cell can no longer tell panels
  // apart; the fault's source is `source`, a literal). Null (the default): records pair
  // with panels in order.
  void use_line_arrivals(TripleBuffer<msg::LineArrival>* arrivals, Nanos silent, const char* source = "plc_link") {
    arrivals_ = arrivals;
    line_silent_ = silent;
    line_source_ = source;
  }
  TaskResult step(const TaskContext& ctx) noexcept;
  static TaskResult task(TaskContext& ctx, void* self) { return static_cast<MarkingSequence*>(self)->step(ctx); }

  MarkingState state() const { return state_; }
  // Completed panels, newest last (wait-free for a reader on another lane).
  TripleBuffer<PanelResult>& results() { return results_; }
  std::uint64_t panels_completed() const { return completed_.load(std::memory_order_acquire); }
  // The panel under way, after every step (one reader: the service's thread).
  TripleBuffer<MarkingProgress>& progress() { return progress_; }
  // From the results writer (another thread), once result `serial` is on disk and synced.
  // True: the PLC hears the result as written. False: the sequence had given up waiting
  // (result_ack_timeout) and told the PLC fault first; the writer then appends that
  // (ResultsFile::late_json), so that the file's last line on the panel is what the PLC
  // heard. One atomic decides which came first, so the two never disagree.
  bool acknowledge_result(std::uint64_t serial);
  // Read after the run (simulated cells, tests).
  const PanelResult& current() const { return result_; }
  // The parameters the current (or last) panel runs on: its type's recipe.
  const MarkingParams& panel_params() const { return params_; }
  std::size_t prediction_samples() const { return std::min(prediction_count_, kPredictionLog); }
  const PredictionSample& prediction_sample(std::size_t i) const { return prediction_log_[i]; }
  // The current panel's frames P (its first kPanelFrameLog), oldest first.
  std::size_t panel_frames() const { return std::min(panel_frame_count_, kPanelFrameLog); }
  const PanelFrameRecord& panel_frame(std::size_t i) const { return panel_frame_log_[i]; }

 private:
  TaskResult advance(const TaskContext& ctx) noexcept;
  void publish_progress() noexcept;
  void on_estimate(const msg::PoseEstimate& e, const PoseFits& fits, Nanos now);
  void start_panel(Nanos now);
  // False: no usable P (the panel failed, or a new search was asked for). `now`: the
  // control lane's time (e.time is the frame's, a vision latency earlier).
  bool intercalibrate_panel(const msg::PoseEstimate& e, const PoseFits& fits, Nanos now);
  void request_search();
  void refine_intercalibration(const msg::PoseEstimate& e, const PoseFits& fits);
  void write_tracker_request(msg::TrackerRequest& req) const;
  void place_tools(const Intercalibration& ic);
  // The MFs the tracker has not measured, placed through the record, for it to pick up.
  void place_unmeasured_mfs(const msg::PoseEstimate& e, const Intercalibration& ic);
  void next_defect(Nanos now);
  void approach(Nanos now, const TaskContext& ctx);
  void finish_panel(Nanos now);
  void plan_panel(Nanos now);
  // The plan's inputs for the defects not yet done (the one under way first): their
  // spraying poses now and the line's motion; returns how many.
  std::size_t plan_inputs(Nanos now, int first, Eigen::Vector3d& velocity);
  void hold(Nanos now, int mfs_in_view);
  bool every_defect_placed() const;
  // Usable, not skipped, and placed by the inter-calibration within the limit.
  bool placed(int defect) const;
  // The first position from next_ in order_ holding a placed defect; -1: none.
  int next_placed() const;
  Nanos latest_start(Nanos now);
  void panel_without_record(Nanos now);
  // Why a record is answered without its panel: it waited record_expiry; the line
  // announced another panel (`instead`); its panel went by before it came.
  enum class Expiry : std::uint8_t { kWaited, kAnotherAnnounced, kPanelWentBy };
  void record_without_panel(Nanos now, Expiry why = Expiry::kWaited, const msg::LineArrival* instead = nullptr);
  void take_job(Nanos now);
  void report_to_plc();
  void fail_panel(Nanos now, std::string_view reason, SkipReason skip);
  void set_plc(int line, bool value);
  Eigen::Isometry3d nozzle_in_base(const Eigen::Isometry3d& X_CamR_P, int defect) const;

  MarkingParams params_;  // the panel's: its panel type's recipe from take_job on
  struct RecipeTable {
    FixedVector<MarkingParams, kMaxPanelTypes> per_type;  // empty: params_ for every panel
  };
  TripleBuffer<RecipeTable> recipes_{RecipeTable{}};  // written by set_recipes, read by take_job
  drivers::ArmLink& arm_;
  SprayValve& valve_;
  drivers::GpioLines& lines_;
  const PlcLineMap plc_;
  const PlcIo& plc_io_;
  TripleBuffer<MarkingEstimate>& estimates_;
  TripleBuffer<msg::TrackerRequest>& tracker_requests_;
  PosePredictor predictor_;

  std::atomic<bool> job_waiting_{false};
  PanelJob mailbox_;
  PanelJob job_;
  MarkingState state_ = MarkingState::kIdle;
  PanelResult result_;
  TripleBuffer<PanelResult> results_;
  TripleBuffer<MarkingProgress> progress_;
  std::atomic<std::uint64_t> completed_{0};
  // The latest result's fate: 2 * serial once written in time, 2 * serial + 1 once the
  // sequence gave up waiting for it (set by compare-and-swap from either side).
  std::atomic<std::uint64_t> result_fate_{0};
  std::uint32_t reset_serial_ = 0;
  std::uint32_t job_serial_ = 0;        // the panel's job, for the vision lane's fits
  std::uint32_t serial_at_reset_ = 0;   // tracker serial when the search was asked for
  std::uint32_t latest_serial_ = 0;
  std::uint32_t intercal_serial_ = 0;   // the P the panel's tool poses are in (0: none yet)
  std::uint32_t placement_serial_ = 0;
  // Searches per panel whose MFs the record did not support; at kIntercalibrationAttempts
  // the panel fails.
  static constexpr int kIntercalibrationAttempts = 3;
  int intercal_failures_ = 0;
  bool search_when_home_ = false;  // a repeated search, asked for once the arm is home
  std::array<DefectToolPose, kMaxDefects> tools_{};
  std::array<int, kMaxDefects> order_{};
  int next_ = 0;                        // position in order_
  int defect_ = -1;                     // the defect being marked (index into job_)
  Nanos deadline_ = 0;
  Nanos settled_since_ = -1;
  bool home_sent_ = false;
  Nanos home_sent_at_ = 0;
  int poses_since_intercal_ = 0;
  int intercal_mfs_ = 0;                // MFs the inter-calibration in use was fitted to
  Nanos present_since_ = -1;  // panel present (cycle enabled) in idle without a record
  std::uint64_t drops_at_start_ = 0;  // the PLC filter's panel-present falls when the panel started
  bool panel_left(const PlcInputs& plc) const { return !plc.panel_present || plc.panel_present_drops != drops_at_start_; }
  Nanos record_since_ = -1;   // a record waiting in idle without a panel
  // Pairing by panel id: the line's announcements, the last one a panel used (its
  // counter), and when the sequence first ran (the source's silence counts from then).
  TripleBuffer<msg::LineArrival>* arrivals_ = nullptr;
  Nanos line_silent_ = seconds(1);
  const char* line_source_ = "plc_link";
  std::uint32_t arrival_used_ = 0;
  Nanos first_step_ = -1;
  // The newest announcement is fresh (not used by a panel yet) and names the waiting job.
  bool announced(const msg::LineArrival& a) const {
    return a.counter != arrival_used_ && a.counter != 0 && a.panel_id.view() == mailbox_.panel_id.view();
  }
  void check_line_source(const TaskContext& ctx, Nanos now) noexcept;
  bool fault_until_next_panel_ = false;  // an expired record's fault, held with no panel to release it
  bool planned_ = false;
  Nanos hold_until_ = 0;                // the hold ends then at the latest
  int hold_most_mfs_ = 0;               // the most MFs a pose used during the hold
  int hold_fewer_mfs_ = 0;              // poses running with fewer than that
  std::array<PlanDefect, kMaxDefects> plan_in_{}, plan_delayed_{};
  std::array<PlanEntry, kMaxDefects> plan_out_{};
  std::array<PredictionSample, kPredictionLog> prediction_log_{};
  std::size_t prediction_count_ = 0;
  std::array<PanelFrameRecord, kPanelFrameLog> panel_frame_log_{};
  std::size_t panel_frame_count_ = 0;
};

}  // namespace markcell::control
