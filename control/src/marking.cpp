#include "markcell/control/marking.hpp"

#include <algorithm>
#include <cmath>

namespace markcell::control {

std::string_view to_string(SkipReason r) {
  switch (r) {
    case SkipReason::kNone: return "";
    case SkipReason::kIntercalibration: return "inter-calibration failed or above its limit";
    case SkipReason::kPlacement: return "inter-calibration placed it too unsurely (its MFs too few or too close together)";
    case SkipReason::kToolPose: return "no tool pose for the defect's points";
    case SkipReason::kOutOfReach: return "spraying pose out of the arm's reach";
    case SkipReason::kPlanned: return "planned out: not within the arm's reach in its turn (the plan's verdict says why)";
    case SkipReason::kNotSettled: return "arm did not settle on the moving target in time";
    case SkipReason::kNoPrediction: return "panel not tracked when the defect's turn came";
    case SkipReason::kNotFound: return "panel's macro-features not found";
    case SkipReason::kStopped: return "stopped before the defect's turn (safe stop or panel left)";
    case SkipReason::kNoPanel: return "its panel never came (the record expired)";
    case SkipReason::kCutShort: return "its spray was cut short (panel present dropped during the pulse)";
  }
  return "?";
}

std::string_view to_string(MarkingState s) {
  switch (s) {
    case MarkingState::kIdle: return "idle";
    case MarkingState::kAcquire: return "acquire";
    case MarkingState::kHold: return "hold";
    case MarkingState::kApproach: return "approach";
    case MarkingState::kSpraying: return "spraying";
    case MarkingState::kHome: return "home";
    case MarkingState::kReporting: return "reporting";
    case MarkingState::kWaitRelease: return "wait-release";
  }
  return "?";
}

namespace {
// The configuration gives the line's direction as written; the sequence sorts defects
// along it as a unit vector.
MarkingParams with_unit_line_direction(MarkingParams p) {
  p.line_direction_CamR.normalize();
  return p;
}
}  // namespace

MarkingSequence::MarkingSequence(const MarkingParams& params, drivers::ArmLink& arm, SprayValve& valve,
                                 drivers::GpioLines& lines, const PlcLineMap& plc, const PlcIo& plc_io,
                                 TripleBuffer<MarkingEstimate>& estimates,
                                 TripleBuffer<msg::TrackerRequest>& tracker_requests)
    : params_(with_unit_line_direction(params)),
      arm_(arm),
      valve_(valve),
      lines_(lines),
      plc_(plc),
      plc_io_(plc_io),
      estimates_(estimates),
      tracker_requests_(tracker_requests),
      predictor_(params.predictor) {}

bool MarkingSequence::offer_job(const PanelJob& job) {
  if (job_waiting_.load(std::memory_order_acquire)) return false;
  mailbox_ = job;
  job_waiting_.store(true, std::memory_order_release);
  return true;
}

bool MarkingSequence::acknowledge_result(std::uint64_t serial) {
  const std::uint64_t written = 2 * serial;
  std::uint64_t fate = result_fate_.load(std::memory_order_acquire);
  while (fate < written)
    if (result_fate_.compare_exchange_weak(fate, written, std::memory_order_acq_rel)) return true;
  return fate == written;
}

void MarkingSequence::set_plc(int line, bool value) {
  if (line >= 0) (void)lines_.set(line, value);
}

Eigen::Isometry3d MarkingSequence::nozzle_in_base(const Eigen::Isometry3d& X_CamR_P, int defect) const {
  return params_.X_Base_CamR * X_CamR_P * tools_[static_cast<std::size_t>(defect)].X_P_Nozzle;
}

TaskResult MarkingSequence::step(const TaskContext& ctx) noexcept {
  const TaskResult r = advance(ctx);
  publish_progress();
  return r;
}

// A copy of under 1 KiB per step: what the operator page needs, never the sequence itself.
void MarkingSequence::publish_progress() noexcept {
  MarkingProgress& p = progress_.write_slot();
  p.state = state_;
  p.on_panel = state_ != MarkingState::kIdle && state_ != MarkingState::kWaitRelease && result_.serial != 0;
  p.panel_serial = result_.serial;
  p.panel_id = result_.panel_id;
  p.panel_type = job_.panel_type;
  p.current = state_ == MarkingState::kApproach || state_ == MarkingState::kSpraying ? defect_ : -1;
  p.reference_serial = intercal_serial_;
  p.defects.clear();
  for (std::size_t k = 0; k < result_.defects.size(); ++k) {
    const DefectResult& d = result_.defects[k];
    p.defects.push_back(DefectProgress{d.id, d.sprayed, d.skipped, intercal_serial_ != 0 && tools_[k].ok(), tools_[k].centre});
  }
  progress_.publish();
}

// Pairing by panel id: the source's newest word, and a safe stop when it has been silent
// too long (a PLC that stopped answering can no longer say which panel comes).
void MarkingSequence::check_line_source(const TaskContext& ctx, Nanos now) noexcept {
  if (first_step_ < 0) first_step_ = now;
  arrivals_->update();
  const Nanos heard = std::max(arrivals_->read().heard, first_step_);
  if (now - heard > line_silent_ && !ctx.safe_stopped()) {
    FixedString<119> detail;
    detail.format("the line's panel-id source has not answered for %lld ms (limit %lld ms)",
                  static_cast<long long>((now - heard) / millis(1)), static_cast<long long>(line_silent_ / millis(1)));
    ctx.safe_stop().trigger(now, FaultCode::kDeviceFault, line_source_, detail.view());
  }
}

TaskResult MarkingSequence::advance(const TaskContext& ctx) noexcept {
  const Nanos now = ctx.now();
  if (arrivals_ != nullptr) check_line_source(ctx, now);
  if (estimates_.update()) on_estimate(estimates_.read().pose, estimates_.read().fits, now);
  if (ctx.safe_stopped() && state_ != MarkingState::kReporting) {
    // The safe stop has closed the valve and held the arm; the panel ends here, and its
    // result (a fault, with what was and was not sprayed) is recorded all the same.
    if (state_ != MarkingState::kIdle && state_ != MarkingState::kWaitRelease) {
      fail_panel(now, "safe stop during the marking sequence", SkipReason::kStopped);
      finish_panel(now);
    }
    return TaskResult::kOk;
  }
  const PlcInputs& plc = plc_io_.inputs();
  switch (state_) {
    case MarkingState::kIdle: {
      const bool waiting = job_waiting_.load(std::memory_order_acquire);
      if (!waiting || plc.panel_present) record_since_ = -1;
      else if (record_since_ < 0) record_since_ = now;
      else if (now - record_since_ > params_.record_expiry) {
        record_without_panel(now);
        break;
      }
      if (waiting && arrivals_ != nullptr && mailbox_.announced != 0 && !plc.panel_present) {
        // Pairing by id, the record offered for an announcement: the line has moved on
        // to another panel (its panel was taken off before the station), or its panel
        // went by without it (the record came late). It is answered now, so that the
        // next announced panel's record is not held behind it.
        const msg::LineArrival& a = arrivals_->read();
        if (a.counter != mailbox_.announced) {
          record_without_panel(now, Expiry::kAnotherAnnounced, &a);
          break;
        }
        if (a.counter == arrival_used_) {
          record_without_panel(now, Expiry::kPanelWentBy);
          break;
        }
      }
      if (!plc.panel_present || !plc.cycle_enable) present_since_ = -1;
      else if (waiting && arrivals_ == nullptr) start_panel(now);
      else if (waiting && announced(arrivals_->read())) start_panel(now);
      else if (waiting && arrivals_->read().counter != arrival_used_) {
        // The line announced another panel than the waiting record's (that panel was
        // taken off between the announcement and the station): the record's panel never
        // comes; this one goes by unmarked (its record, if any, is not the waiting one).
        arrival_used_ = arrivals_->read().counter;
        record_without_panel(now, Expiry::kAnotherAnnounced, &arrivals_->read());
        fault_until_next_panel_ = false;  // the panel at the station hears it and releases it as it leaves
      } else if (present_since_ < 0) present_since_ = now;
      else if (now - present_since_ > params_.record_timeout) panel_without_record(now);
      break;
    }
    case MarkingState::kAcquire:
      if (panel_left(plc)) fail_panel(now, "panel left before its macro-features were found", SkipReason::kStopped);
      else if (now > deadline_ && search_when_home_)
        fail_panel(now, "arm did not reach home in time to search again for the macro-features",
                   SkipReason::kIntercalibration);
      else if (now > deadline_) fail_panel(now, "macro-features not found in time", SkipReason::kNotFound);
      else if (search_when_home_) {
        // The new search waits for the arm at home: in the view, its outline crossing the
        // panel's edges makes corners that stand still while the panel moves.
        const auto& s = arm_.state();
        if ((s.flags & drivers::kHomed) != 0 && s.received > home_sent_at_ + params_.command_lead) {
          search_when_home_ = false;
          request_search();
          deadline_ = now + params_.acquire_timeout;
        }
      }
      break;
    case MarkingState::kHold:
      if (panel_left(plc)) fail_panel(now, "panel left before its marking began", SkipReason::kStopped);
      else if (now >= hold_until_) next_defect(now);  // no pose came to end it earlier
      break;
    case MarkingState::kApproach:
      if (panel_left(plc)) fail_panel(now, "panel left during the marking sequence", SkipReason::kStopped);
      else approach(now, ctx);
      break;
    case MarkingState::kSpraying: {
      const std::uint64_t n = valve_.pulse_count();
      auto& d = result_.defects[static_cast<std::size_t>(defect_)];
      if (!valve_.open() && n > 0 && valve_.pulse(n - 1).requested_start == d.spray_requested &&
          (valve_.pulse(n - 1).closed >= 0 || valve_.pulse(n - 1).cut_short)) {
        // A pulse the valve's interlock cut short laid down too little paint, or none:
        // the defect is not marked (a second pulse on a wet spot would be a blot).
        if (valve_.pulse(n - 1).cut_short) d.skipped = SkipReason::kCutShort;
        else d.sprayed = true;
        if (panel_left(plc)) fail_panel(now, "panel left during the marking sequence", SkipReason::kStopped);
        else next_defect(now);
      } else if (panel_left(plc)) {
        fail_panel(now, "panel left during the marking sequence", SkipReason::kStopped);
      }
      break;
    }
    case MarkingState::kHome: {
      if (!home_sent_) {
        drivers::ArmCommand home;
        home.mode = drivers::ArmMode::kHome;
        home.time = now;
        arm_.send(home, now);
        home_sent_ = true;
        home_sent_at_ = now;
        deadline_ = now + params_.home_timeout;
      }
      // Homed, in a state the arm sent after it received the command.
      const auto& s = arm_.state();
      if ((s.flags & drivers::kHomed) != 0 && s.received > home_sent_at_ + params_.command_lead) finish_panel(now);
      else if (now > deadline_) {
        // A panel that failed before keeps that reason first: it is why the arm went home.
        if (result_.fault) {
          const FixedString<119> first = result_.reason;
          result_.reason.format("%s; then the arm did not reach home in time", first.c_str());
        } else {
          result_.reason.assign("arm did not reach home in time");
        }
        result_.fault = true;
        finish_panel(now);
      }
      break;
    }
    case MarkingState::kReporting: {
      const std::uint64_t written = 2 * result_.serial;
      std::uint64_t fate = result_fate_.load(std::memory_order_acquire);
      if (fate == written) {
        report_to_plc();
      } else if (now > deadline_) {
        // Given up on, unless the writer's acknowledgement came in the meantime.
        if (result_fate_.compare_exchange_strong(fate, written + 1, std::memory_order_acq_rel) || fate != written) {
          result_.fault = true;
          result_.reason.assign("results file not written in time");
        }
        report_to_plc();
      }
      break;
    }
    case MarkingState::kWaitRelease:
      if (!plc.panel_present) {  // the PLC has seen the answer: both lines drop for the next panel
        set_plc(plc_.done, false);
        if (!fault_until_next_panel_) set_plc(plc_.fault, false);
        state_ = MarkingState::kIdle;
      }
      break;
  }
  return TaskResult::kOk;
}

bool MarkingSequence::set_recipes(std::span<const MarkingParams> per_panel_type) {
  if (per_panel_type.size() > static_cast<std::size_t>(kMaxPanelTypes)) return false;
  RecipeTable& table = recipes_.write_slot();
  table.per_type.clear();
  for (const MarkingParams& p : per_panel_type) table.per_type.push_back(with_unit_line_direction(p));
  recipes_.publish();
  return true;
}

void MarkingSequence::take_job(Nanos now) {
  // The waiting record becomes the panel's job (the mailbox is free for the next) and its
  // result starts: every defect listed, none yet sprayed or skipped.
  job_ = mailbox_;
  job_waiting_.store(false, std::memory_order_release);
  // The panel's own process settings: its type's recipe, the newest set (a copy of
  // fixed size), kept to the panel's end.
  recipes_.update();
  const RecipeTable& recipes = recipes_.read();
  if (job_.panel_type_index >= 0 && job_.panel_type_index < recipes.per_type.ssize())
    params_ = recipes.per_type[static_cast<std::size_t>(job_.panel_type_index)];
  result_ = PanelResult{};
  result_.serial = completed_.load(std::memory_order_relaxed) + 1;
  result_.panel_id = job_.panel_id.view();
  result_.started = now;
  for (const PanelJob::Defect& d : job_.defects) result_.defects.emplace_back()->id = d.id;
}

void MarkingSequence::start_panel(Nanos now) {
  present_since_ = -1;
  if (arrivals_ != nullptr) arrival_used_ = arrivals_->read().counter;
  ++job_serial_;
  drops_at_start_ = plc_io_.inputs().panel_present_drops;
  take_job(now);
  set_plc(plc_.done, false);
  set_plc(plc_.fault, false);
  fault_until_next_panel_ = false;
  set_plc(plc_.busy, true);
  request_search();
  intercal_serial_ = 0;
  intercal_failures_ = 0;
  search_when_home_ = false;
  prediction_count_ = 0;
  panel_frame_count_ = 0;
  defect_ = -1;
  next_ = 0;
  home_sent_ = false;
  planned_ = false;
  poses_since_intercal_ = 0;
  deadline_ = now + params_.acquire_timeout;
  state_ = MarkingState::kAcquire;
}

void fit_pose_to_record(const msg::TrackerRequest& job, const msg::PoseEstimate& e, const IntercalibrationLimits& limits,
                        PoseFits& out) noexcept {
  out.job_serial = job.job_serial;
  // The record's MFs and the estimate's, paired by index, as the inter-calibration takes them.
  const std::size_t n = std::min(job.mfs_SL.size(), e.mfs.size());
  std::array<Eigen::Vector3d, msg::kMaxMacroFeatures> mfs_P{};
  std::array<bool, msg::kMaxMacroFeatures> known{};
  out.measured_mask.fill(false);
  out.measured_count = 0;
  for (std::size_t i = 0; i < n; ++i) {
    mfs_P[i] = e.mfs[i].reference_P;
    known[i] = e.mfs[i].reference_known;
    out.measured_mask[i] = known[i] && e.mfs[i].reference_observed >= kMeasuredFrames;
    out.measured_count += out.measured_mask[i] ? 1 : 0;
  }
  const std::span<const Eigen::Vector3d> mfs_SL(job.mfs_SL.data(), n), in_P(mfs_P.data(), n);
  out.known = intercalibrate(mfs_SL, in_P, std::span(known.data(), n), limits);
  out.measured = intercalibrate(mfs_SL, in_P, std::span(out.measured_mask.data(), n), limits);
}

void MarkingSequence::write_tracker_request(msg::TrackerRequest& req) const {
  req.reset_serial = reset_serial_;
  req.panel_type = job_.panel_type_index;
  req.job_serial = job_serial_;
  req.mfs_SL = job_.mfs_SL;
}

void MarkingSequence::request_search() {
  // Ask the vision lane for a fresh search; poses of the previous P no longer count.
  msg::TrackerRequest& req = tracker_requests_.write_slot();
  req = msg::TrackerRequest{};
  ++reset_serial_;
  write_tracker_request(req);
  tracker_requests_.publish();
  serial_at_reset_ = latest_serial_;
}

void MarkingSequence::on_estimate(const msg::PoseEstimate& e, const PoseFits& fits, Nanos now) {
  latest_serial_ = std::max(latest_serial_, e.reference_serial);
  const auto marking = [this] {
    return state_ == MarkingState::kAcquire || state_ == MarkingState::kHold || state_ == MarkingState::kApproach ||
           state_ == MarkingState::kSpraying;
  };
  if (!marking()) return;
  if (e.reference_serial <= serial_at_reset_ || !e.has_pose()) return;
  if (fits.job_serial != job_serial_) return;  // (made before the vision lane had this panel's record)
  if (e.reference_serial != intercal_serial_) {
    // A new P (the first search, or a re-search after the panel was lost): pair its MFs
    // with the record again; the tool poses live in P.
    if (!intercalibrate_panel(e, fits, now) || !marking()) return;
  } else {
    refine_intercalibration(e, fits);
  }
  if (defect_ >= 0) {
    PredictionSample& s = prediction_log_[prediction_count_ % kPredictionLog];
    const Eigen::Vector3d c = tools_[static_cast<std::size_t>(defect_)].centre;
    s.time = e.time;
    s.defect = job_.defects[static_cast<std::size_t>(defect_)].id;
    s.estimated_CamR = e.X_CamR_P * c;
    s.predicted_CamR = predictor_.ready() ? Eigen::Vector3d(predictor_.predict(e.time) * c) : s.estimated_CamR;
    s.reference_time = e.reference_time;
    s.centre_P = c;
    s.inliers = e.inliers;
    s.count = e.mfs.ssize();
    ++prediction_count_;
  }
  // The MFs the fit used set the filter's measurement noise (their layout: how well the
  // pose is pinned down in each direction).
  std::array<Eigen::Vector3d, msg::kMaxMacroFeatures> used{};
  std::size_t n = 0;
  for (const msg::MacroFeatureObservation& mf : e.mfs)
    if (mf.inlier) used[n++] = mf.reference_P;
  predictor_.update(e.time, e.X_CamR_P, std::span(used.data(), n));
  if (state_ == MarkingState::kAcquire && predictor_.ready()) {
    state_ = MarkingState::kHold;
    hold_until_ = now + params_.placement_hold;
    hold_most_mfs_ = 0;
    hold_fewer_mfs_ = 0;
  }
  if (state_ == MarkingState::kHold) hold(now, e.inliers);
  if (!planned_ && ++poses_since_intercal_ >= params_.plan_after_poses &&
      (state_ == MarkingState::kApproach || state_ == MarkingState::kSpraying))
    plan_panel(now);
}

void MarkingSequence::plan_panel(Nanos now) {
  planned_ = true;
  result_.planned_at = now;
  // The defects not yet done, in their order (the one under way first), where their
  // spraying poses are now and how the line moves them (the predictor's motion over 1 s).
  const int first = defect_ >= 0 && state_ == MarkingState::kApproach ? next_ - 1 : next_;
  Eigen::Vector3d velocity;
  const std::size_t n = plan_inputs(now, first, velocity);
  const auto& tool = arm_.state().tool.position;
  plan_marking(std::span(plan_in_.data(), n), Eigen::Vector3d(tool[0], tool[1], tool[2]), velocity, params_.timing,
               std::span(plan_out_.data(), n));
  bool current_out = false;
  for (std::size_t k = 0; k < n; ++k) {
    const PlanEntry& e = plan_out_[k];
    DefectResult& r = result_.defects[static_cast<std::size_t>(e.index)];
    r.plan = e.verdict;
    if (e.verdict == PlanVerdict::kFeasible) {
      r.planned_spray = now + static_cast<Nanos>(e.spray_time * 1e9);
      if (e.index == defect_) deadline_ = std::max(deadline_, r.planned_spray + params_.timing.defect_timeout);
    }
    if (e.verdict == PlanVerdict::kFeasible || e.verdict == PlanVerdict::kNotPlanned) continue;
    // Reported now, never attempted: the arm's time goes to the defects it can mark.
    r.skipped = SkipReason::kPlanned;
    if (e.index == defect_ && state_ == MarkingState::kApproach) current_out = true;
  }
  if (current_out) next_defect(now);
}

std::size_t MarkingSequence::plan_inputs(Nanos now, int first, Eigen::Vector3d& velocity) {
  // Where the defects' spraying poses are now and how the line moves them (the
  // predictor's motion over 1 s).
  const Eigen::Isometry3d X_now = predictor_.predict(now), X_later = predictor_.predict(now + seconds(1));
  velocity.setZero();
  std::size_t n = 0;
  for (int k = first; k < job_.defects.ssize(); ++k) {
    const int i = order_[static_cast<std::size_t>(k)];
    const auto d = static_cast<std::size_t>(i);
    const Eigen::Vector3d p = nozzle_in_base(X_now, i).translation();
    if (n == 0) velocity = nozzle_in_base(X_later, i).translation() - p;
    plan_in_[n++] = PlanDefect{i, p, tools_[d].ok()};
  }
  return n;
}

bool MarkingSequence::every_defect_placed() const {
  // The defects still to do (a hold after a new search mid-panel comes after some).
  for (int i = 0; i < job_.defects.ssize(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    const DefectResult& r = result_.defects[k];
    if (tools_[k].ok() && !r.sprayed && r.skipped == SkipReason::kNone && !placed(i)) return false;
  }
  return true;
}

Nanos MarkingSequence::latest_start(Nanos now) {
  // The longest delay (within the hold's limit) after which the plan still marks as many
  // defects as starting now; the line keeps moving them meanwhile. Bisection, 16 rounds.
  Eigen::Vector3d velocity;
  const std::size_t n = plan_inputs(now, next_, velocity);
  const auto& tool = arm_.state().tool.position;
  const Eigen::Vector3d arm(tool[0], tool[1], tool[2]);
  const auto feasible_after = [&](double delay) {
    for (std::size_t k = 0; k < n; ++k) {
      plan_delayed_[k] = plan_in_[k];
      plan_delayed_[k].position_Base += velocity * delay;
    }
    return plan_marking(std::span(plan_delayed_.data(), n), arm, velocity, params_.timing, std::span(plan_out_.data(), n))
        .feasible;
  };
  const int now_feasible = feasible_after(0.0);
  double lo = 0.0, hi = to_seconds(std::max<Nanos>(hold_until_ - now, 0));
  if (feasible_after(hi) >= now_feasible) return hold_until_ - now;
  for (int round = 0; round < 16; ++round) {
    const double mid = 0.5 * (lo + hi);
    (feasible_after(mid) >= now_feasible ? lo : hi) = mid;
  }
  return static_cast<Nanos>(lo * 1e9);
}

void MarkingSequence::hold(Nanos now, int mfs_in_view) {
  // Once the motion is known, the plan bounds the wait (the arm's reach).
  if (poses_since_intercal_ >= params_.plan_after_poses) hold_until_ = std::min(hold_until_, now + latest_start(now));
  // So does the view: with the arm at home nothing hides the panel, and once it shows
  // fewer MFs than it has (three poses running) it is leaving the view; later, the pose
  // would rest on fewer MFs and no refit can come.
  hold_fewer_mfs_ = mfs_in_view < hold_most_mfs_ ? hold_fewer_mfs_ + 1 : 0;
  hold_most_mfs_ = std::max(hold_most_mfs_, mfs_in_view);
  if (every_defect_placed() || now >= hold_until_ || hold_fewer_mfs_ >= 3) next_defect(now);
}

bool MarkingSequence::intercalibrate_panel(const msg::PoseEstimate& e, const PoseFits& fits, Nanos now) {
  const std::size_t n = std::min(job_.mfs_SL.size(), e.mfs.size());
  if (panel_frame_count_ < kPanelFrameLog) {
    PanelFrameRecord& frame = panel_frame_log_[panel_frame_count_++];
    frame.reference_time = e.reference_time;
    frame.mfs.clear();
    for (const msg::MacroFeatureObservation& mf : e.mfs) frame.mfs.push_back({mf.reference_P, mf.reference_known});
  }
  const Intercalibration& fit = fits.known;  // made on the vision lane with this pose
  intercal_serial_ = e.reference_serial;
  if (!fit.ok()) {
    // A search that found corners the record does not support (a person or the arm in
    // front of the panel, taken for MFs) is made again, a few times; a record that is not
    // this panel's fails every time. (Not with a pulse in flight: its result comes first.)
    result_.intercalibration = fit;  // the latest fit, until one passes
    if (++intercal_failures_ < kIntercalibrationAttempts && state_ != MarkingState::kSpraying) {
      serial_at_reset_ = latest_serial_;  // this P's poses no longer count
      if (state_ == MarkingState::kApproach) --next_;  // the defect under way is taken up again
      defect_ = -1;
      settled_since_ = -1;
      drivers::ArmCommand home;
      home.mode = drivers::ArmMode::kHome;
      home.time = now;
      arm_.send(home, now);
      home_sent_at_ = now;
      search_when_home_ = true;
      deadline_ = now + params_.home_timeout;  // then acquire_timeout for the search
      state_ = MarkingState::kAcquire;
      return false;
    }
    fail_panel(now, to_string(fit.status), SkipReason::kIntercalibration);
    return false;
  }
  result_.intercalibration = fit;
  const Intercalibration& ic = result_.intercalibration;
  intercal_mfs_ = ic.inliers;
  // Tool poses in P, and the defects' order: downstream first.
  place_tools(ic);
  // (A P set up anew mid-sequence orders only the defects not yet taken.)
  std::array<double, kMaxDefects> key{};
  for (int i = 0; i < job_.defects.ssize(); ++i) {
    key[static_cast<std::size_t>(i)] = tools_[static_cast<std::size_t>(i)].centre.dot(params_.line_direction_CamR);
    if (next_ == 0) order_[static_cast<std::size_t>(i)] = i;
  }
  std::sort(order_.begin() + next_, order_.begin() + job_.defects.ssize(),
            [&](int a, int b) { return key[static_cast<std::size_t>(a)] > key[static_cast<std::size_t>(b)]; });
  place_unmeasured_mfs(e, ic);
  // The anchor the predictors follow: the centroid of the MFs found.
  Eigen::Vector3d anchor = Eigen::Vector3d::Zero();
  int count = 0;
  for (std::size_t i = 0; i < n; ++i)
    if (e.mfs[i].reference_known) anchor += e.mfs[i].reference_P, ++count;
  predictor_.reset(anchor / std::max(count, 1));
  if (state_ == MarkingState::kApproach || state_ == MarkingState::kSpraying) settled_since_ = -1;
  return true;
}

void MarkingSequence::place_unmeasured_mfs(const msg::PoseEstimate& e, const Intercalibration& ic) {
  const std::size_t n = std::min(job_.mfs_SL.size(), e.mfs.size());
  msg::TrackerRequest& req = tracker_requests_.write_slot();
  write_tracker_request(req);
  req.reference_serial = e.reference_serial;
  req.placement_serial = ++placement_serial_;
  req.known.fill(false);
  for (std::size_t i = 0; i < n; ++i) {
    req.known[i] = job_.mfs_SL[i].allFinite() && (!e.mfs[i].reference_known || e.mfs[i].reference_observed == 0);
    req.reference_P[i] = ic.X_P_SL * job_.mfs_SL[i];
  }
  tracker_requests_.publish();
}

void MarkingSequence::place_tools(const Intercalibration& ic) {
  std::array<Eigen::Vector3d, kMaxDefectPoints> pts{};
  for (int i = 0; i < job_.defects.ssize(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    const auto& d = job_.defects[k];
    for (std::size_t j = 0; j < d.points_SL.size(); ++j) pts[j] = ic.X_P_SL * d.points_SL[j];
    tools_[k] = tool_pose(std::span(pts.data(), d.points_SL.size()), params_.standoff, Eigen::Vector3d::Zero(),
                          params_.min_defect_points);
    result_.defects[k].tool = tools_[k].status;
    result_.defects[k].placement_sigma = ic.placement_sigma(tools_[k].centre);
  }
}

void MarkingSequence::refine_intercalibration(const msg::PoseEstimate& e, const PoseFits& fits) {
  // A panel that enters the view shows a few MFs on its leading edge when P is set up;
  // fitted to those alone, the inter-calibration's rotation error is levered out to the
  // defects beyond them. The other MFs come into view, are tracked, and their positions
  // in P settle (kMeasuredFrames); once more of them have been measured than the fit in
  // use had, the vision lane's fit over those is taken, and the tool poses with it
  // (their order stays: the sequence is under way). At most once per MF, bounded.
  if (fits.measured_count <= intercal_mfs_) return;
  intercal_mfs_ = fits.measured_count;  // tried with these; a failed refit keeps the fit in use
  if (!fits.measured.ok()) return;
  result_.intercalibration = fits.measured;
  place_tools(result_.intercalibration);
  place_unmeasured_mfs(e, result_.intercalibration);
}

bool MarkingSequence::placed(int defect) const {
  const auto k = static_cast<std::size_t>(defect);
  return tools_[k].ok() && result_.defects[k].skipped == SkipReason::kNone &&
         result_.defects[k].placement_sigma <= params_.intercalibration.max_placement_sigma;
}

int MarkingSequence::next_placed() const {
  for (int k = next_; k < job_.defects.ssize(); ++k)
    if (placed(order_[static_cast<std::size_t>(k)])) return k;
  return -1;
}

void MarkingSequence::next_defect(Nanos now) {
  // A defect the inter-calibration does not yet place surely enough waits behind the next
  // one it does (the order otherwise kept): the arm's time goes to what it can spray now,
  // and the refits meanwhile may place the other.
  if (const int k = next_placed(); k >= 0)
    std::rotate(order_.begin() + next_, order_.begin() + k, order_.begin() + k + 1);
  while (next_ < job_.defects.ssize()) {
    defect_ = order_[static_cast<std::size_t>(next_++)];
    auto& r = result_.defects[static_cast<std::size_t>(defect_)];
    if (!tools_[static_cast<std::size_t>(defect_)].ok()) {
      r.skipped = SkipReason::kToolPose;
      continue;
    }
    if (r.skipped == SkipReason::kPlanned) continue;
    r.approach_start = now;
    // A defect the plan expects later (the line has yet to bring it within reach) has
    // its timeout counted from then.
    deadline_ = std::max(now, r.planned_spray) + params_.timing.defect_timeout;
    settled_since_ = -1;
    state_ = MarkingState::kApproach;
    return;
  }
  defect_ = -1;
  state_ = MarkingState::kHome;
}

void MarkingSequence::approach(Nanos now, const TaskContext& ctx) {
  auto& r = result_.defects[static_cast<std::size_t>(defect_)];
  const bool fresh = predictor_.ready() && now - predictor_.last_update() <= params_.max_prediction_age;
  // Placed surely enough by the inter-calibration in use; a refit with more MFs may
  // still come (refine_intercalibration) while the arm follows.
  const bool placed_now = r.placement_sigma <= params_.intercalibration.max_placement_sigma;
  if (!placed_now && next_placed() >= 0) {
    // Another defect placed meanwhile goes first; this one follows it (next_defect).
    --next_;  // order_[next_] is this defect again
    next_defect(now);
    return;
  }
  if (now > deadline_) {
    const Eigen::Isometry3d X = nozzle_in_base(predictor_.predict(now), defect_);
    r.skipped = !placed_now ? SkipReason::kPlacement
                : !fresh ? SkipReason::kNoPrediction
                : X.translation().norm() > params_.timing.reach ? SkipReason::kOutOfReach : SkipReason::kNotSettled;
    next_defect(now);
    return;
  }
  if (!predictor_.ready()) return;
  const Nanos t_cmd = now + params_.command_lead;
  const Eigen::Isometry3d target = nozzle_in_base(predictor_.predict(t_cmd), defect_);
  if (target.translation().norm() > params_.timing.reach) {
    settled_since_ = -1;
    return;  // not (yet) reachable: wait, the line may bring it in
  }
  drivers::ArmCommand move;
  move.mode = drivers::ArmMode::kMove;
  move.time = t_cmd;
  move.target = to_tool_pose(target);
  arm_.send(move, now);
  r.X_Base_Nozzle = target;
  // Settled: where the arm reports itself against where the nozzle should have been then.
  const drivers::ArmState& s = arm_.state();
  const Eigen::Isometry3d then = nozzle_in_base(predictor_.predict(s.received), defect_);
  const Eigen::Vector3d pos(s.tool.position[0], s.tool.position[1], s.tool.position[2]);
  const double angle = Eigen::AngleAxisd(to_isometry(s.tool).linear().transpose() * then.linear()).angle();
  const bool within = (pos - then.translation()).norm() <= params_.settle_position && angle <= params_.settle_angle;
  // (The arm's state carries no mode over CAN: position, orientation and freshness decide.)
  if (!within || !fresh || !placed_now || s.received < r.approach_start) {
    settled_since_ = -1;
    return;
  }
  if (settled_since_ < 0) settled_since_ = now;
  if (now - settled_since_ < params_.settle_time) return;
  const Nanos start = now + 1;  // the valve task opens it on its next run
  if (valve_.request(start, params_.timing.pulse, ctx.safe_stopped()) != PulseRequest::kAccepted) return;
  r.spray_requested = start;
  r.predicted_centre_CamR = predictor_.predict(start) * tools_[static_cast<std::size_t>(defect_)].centre;
  state_ = MarkingState::kSpraying;
}

void MarkingSequence::fail_panel(Nanos now, std::string_view reason, SkipReason skip) {
  // Whatever ends the panel closes the valve on this tick, mid-pulse or not.
  valve_.cancel(now);
  if (state_ == MarkingState::kSpraying && defect_ >= 0) {
    auto& d = result_.defects[static_cast<std::size_t>(defect_)];
    if (!d.sprayed && d.skipped == SkipReason::kNone) d.skipped = SkipReason::kCutShort;
  }
  result_.fault = true;
  result_.reason = reason;
  for (int i = 0; i < job_.defects.ssize(); ++i) {
    auto& d = result_.defects[static_cast<std::size_t>(i)];
    if (!d.sprayed && d.skipped == SkipReason::kNone) d.skipped = skip;
  }
  defect_ = -1;
  next_ = job_.defects.ssize();
  if (state_ == MarkingState::kIdle || state_ == MarkingState::kWaitRelease || state_ == MarkingState::kReporting) return;
  state_ = MarkingState::kHome;
  home_sent_ = false;
  deadline_ = now + params_.home_timeout;
}

void MarkingSequence::panel_without_record(Nanos now) {
  // The panel goes by unmarked: the arm never moved, the PLC hears fault, and the result
  // records it (the inspection station's record may still come: it waits for the next).
  result_ = PanelResult{};
  result_.serial = completed_.load(std::memory_order_relaxed) + 1;
  result_.panel_id.assign("(no record)");
  fault_until_next_panel_ = false;  // a panel came: it releases any earlier fault as it leaves
  result_.started = present_since_;
  result_.fault = true;
  result_.reason.assign("panel present without an inspection record");
  if (arrivals_ != nullptr) {  // pairing by id: the panel is the one the line announced, if it did
    const msg::LineArrival& a = arrivals_->read();
    if (a.counter != 0 && a.counter != arrival_used_ && !a.panel_id.empty()) {
      result_.panel_id = a.panel_id;
      result_.reason.format("panel '%s' present without its inspection record", a.panel_id.c_str());
    } else {
      result_.reason.assign("panel present, but the line announced no new panel id");
    }
    arrival_used_ = a.counter;
  }
  present_since_ = -1;
  job_.defects.clear();  // (no copy of a whole empty job on the control lane)
  job_.mfs_SL.clear();
  finish_panel(now);
}

void MarkingSequence::record_without_panel(Nanos now, Expiry why, const msg::LineArrival* instead) {
  // The record is taken off the mailbox and answered, so the next one (the next panel's)
  // is not held behind it; nothing moved.
  record_since_ = -1;
  take_job(now);
  result_.fault = true;
  result_.reason.assign("inspection record expired: its panel never came");
  if (why == Expiry::kAnotherAnnounced && instead != nullptr)
    result_.reason.format("inspection record expired: the line announced panel '%s' instead", instead->panel_id.c_str());
  if (why == Expiry::kPanelWentBy) result_.reason.assign("inspection record expired: its panel went by before it came");
  fault_until_next_panel_ = true;  // no panel to release it: the PLC sees it until the next comes
  for (DefectResult& d : result_.defects) d.skipped = SkipReason::kNoPanel;
  finish_panel(now);
}

void MarkingSequence::finish_panel(Nanos now) {
  result_.finished = now;
  results_.write(result_);
  completed_.fetch_add(1, std::memory_order_acq_rel);
  if (!params_.require_result_ack) {
    report_to_plc();
    return;
  }
  deadline_ = now + params_.result_ack_timeout;
  state_ = MarkingState::kReporting;  // the PLC hears nothing before the result is on disk
}

void MarkingSequence::report_to_plc() {
  set_plc(plc_.busy, false);
  if (result_.fault) set_plc(plc_.fault, true);
  else set_plc(plc_.done, true);
  state_ = MarkingState::kWaitRelease;
}

}  // namespace markcell::control
