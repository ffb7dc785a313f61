#include "markcell/rig/replay.hpp"
#include "markcell/host/stop_signal.hpp"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <stdexcept>
#include <thread>

#include "markcell/common/geometry.hpp"
#include "markcell/control/tool_pose.hpp"
#include "markcell/drivers/gpiod_lines.hpp"
#include "markcell/host/inspection_record.hpp"
#include "markcell/host/service_loop.hpp"
#include "markcell/rig/hil_peer.hpp"
#include "markcell/vision/frame_source.hpp"
#include "markcell/vision/recording.hpp"
#include "markcell/rig/panel.hpp"
#include "markcell/rig/render.hpp"
#include "markcell/rig/scenario.hpp"

namespace markcell::rig {

// The rig runs the service's cell: its configuration, its cell and their helpers.
using namespace markcell::host;

namespace {

// The recorded truth between frames: translation linear, rotation by slerp.
class TruthTrack {
 public:
  TruthTrack(const std::vector<vision::TruthPose>& truth, const vision::RecordingFrameSource& source) {
    for (const auto& t : truth) poses_.push_back({source.to_cell_time(t.time), t.X_CamR_Panel});
    std::sort(poses_.begin(), poses_.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  }
  bool empty() const { return poses_.empty(); }
  Eigen::Isometry3d at(Nanos t) const {
    if (t <= poses_.front().first) return poses_.front().second;
    if (t >= poses_.back().first) return poses_.back().second;
    const auto it = std::lower_bound(poses_.begin(), poses_.end(), t, [](const auto& p, Nanos v) { return p.first < v; });
    const auto& b = *it;
    const auto& a = *(it - 1);
    const double f = static_cast<double>(t - a.first) / static_cast<double>(b.first - a.first);
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() = Eigen::Quaterniond(a.second.linear()).slerp(f, Eigen::Quaterniond(b.second.linear())).toRotationMatrix();
    X.translation() = (1 - f) * a.second.translation() + f * b.second.translation();
    return X;
  }

 private:
  std::vector<std::pair<Nanos, Eigen::Isometry3d>> poses_;
};

bool has_task(const CellConfig& c, const std::string& name) {
  return std::any_of(c.executive.tasks.begin(), c.executive.tasks.end(), [&](const auto& t) { return t.name == name; });
}

// A real-device replay's checks: the configuration must name real devices for the peer to
// stand behind.
void check_real_devices(const CellConfig& c, const ReplayOptions& options) {
  if (c.gpio.simulated)
    throw std::runtime_error(c.file + ": devices.gpio.simulated is true: a replay on real devices (--gpio-sim) needs the "
                                      "libgpiod chip the gpio-sim lines are on");
  if (c.arm.transport == ArmTransport::kSimulated)
    throw std::runtime_error(c.file + ": devices.arm.transport must be can or serial for a replay on real devices "
                                      "(--gpio-sim): the rig's simulated arm stands behind the cell's real arm link");
  if (c.arm.transport == ArmTransport::kSerial && options.arm_serial_peer.empty())
    throw std::runtime_error(c.file + ": devices.arm.transport is serial: a replay on real devices needs the serial "
                                      "line's other end for the rig's arm (--arm-serial-peer DEVICE)");
  if (c.arm.transport != ArmTransport::kSerial && !options.arm_serial_peer.empty())
    throw std::runtime_error(c.file + ": --arm-serial-peer is given but devices.arm.transport is not serial");
}

// The panels' scores as one: every spray and every panel's defects, in order; the
// marking error over all marked defects.
Score merge_scores(const std::vector<PanelRun>& panels, ScoredOn on) {
  Score all;
  all.scored_on = on;
  double sum_sq = 0;
  for (const PanelRun& p : panels) {
    const Score& s = p.score;
    all.sprays.insert(all.sprays.end(), s.sprays.begin(), s.sprays.end());
    all.defects.insert(all.defects.end(), s.defects.begin(), s.defects.end());
    all.planned += s.planned, all.marked += s.marked, all.skipped += s.skipped, all.false_sprays += s.false_sprays;
    all.error_max = std::max(all.error_max, s.error_max);
    sum_sq += s.error_rms * s.error_rms * s.marked;
  }
  all.error_rms = all.marked > 0 ? std::sqrt(sum_sq / all.marked) : 0.0;
  return all;
}

// `pose_log_folder`: where this run's poses.csv and mf_tracks.csv go (empty: none).
PredictorRun run_once(const CellConfig& base, const std::string& recording, const control::PanelJob& job,
                      control::PredictorKind kind, const ReplayOptions& options, const vision::Recording& rec,
                      const std::optional<rig::Panel>& panel, const std::string& pose_log_folder) {
  const std::string predictor(control::to_string(kind));
  const bool real = !options.gpio_sim.empty();
  CellConfig cfg = base;
  cfg.cameras.source = CameraSource::kRecording;
  cfg.cameras.recording = recording;
  cfg.marking.predictor.kind = kind;
  cfg.watchdog.systemd = false;  // no service manager in a rig run
  cfg.results_file.clear();      // the rig writes its report, not the plant's results
  cfg.record_folder.clear();
  cfg.line = LineConfig{};       // records pair with panels in order: the replay has no line PLC
  cfg.watchdog.device.enabled = false;
  if (!real) {  // (a real-device run's configuration was checked before the first run)
    cfg.gpio.simulated = true;
    cfg.arm.transport = ArmTransport::kSimulated;
    cfg.executive.lock_memory = false;
    for (auto& lane : cfg.executive.lanes) lane.priority = 0, lane.core = -1;  // simulated time needs no privileges
  }

  Cell cell(cfg, real ? ClockKind::kReal : ClockKind::kSimulated);
  std::unique_ptr<HilPeer> peer;
  if (real) {
    auto* lines = dynamic_cast<drivers::GpiodLines*>(&cell.gpio_device());
    if (lines == nullptr) throw std::logic_error("a real-device replay without the libgpiod driver");
    std::array<unsigned, kLineRoleCount> offsets{};
    for (std::size_t i = 0; i < kLineRoleCount; ++i) offsets[i] = lines->offset(static_cast<int>(i));
    int priority = 0;  // the world runs above every lane of the cell, when they have priorities
    for (const auto& lane : cfg.executive.lanes) priority = std::max(priority, lane.priority > 0 ? std::min(lane.priority + 1, 99) : 0);
    peer = std::make_unique<HilPeer>(cfg, options.gpio_sim, offsets, priority, options.arm_serial_peer);
    peer->start();
  } else {
    cell.enable_command_log(std::size_t{1} << 18);
  }
  // The configured source replays the recording; the rig draws its arm in front of it.
  std::unique_ptr<vision::FrameSource> configured = cell.release_frame_source();
  auto& source = static_cast<vision::RecordingFrameSource&>(*configured);
  ArmOverlaySource* overlay = nullptr;
  const bool draw_arm = options.draw_arm == ReplayOptions::ArmDrawing::kAlways ||
                        (options.draw_arm == ReplayOptions::ArmDrawing::kRigRecordings && rec.manifest().generator == kRigGenerator);
  if (!real && draw_arm) {
    auto wrapped = std::make_unique<ArmOverlaySource>(std::move(configured), cell.stereo_rig()->calibration(),
                                                      cell.X_Base_CamR().inverse(), *cell.sim_tool_poses());
    overlay = wrapped.get();
    configured = std::move(wrapped);
  }
  cell.use_frame_source(std::move(configured));
  if (!pose_log_folder.empty()) cell.enable_pose_queue();  // (the service loop below writes it)
  control::MarkingSequence& marking = *cell.marking();
  // Each panel the cell handled, taken as the next panel is about to come (the sequence
  // then waits for panel present: its logs stand still) and at the end.
  struct Handled {
    control::PanelResult result;
    std::vector<control::PredictionSample> samples;
    std::vector<control::PanelFrameRecord> frames;
  };
  std::vector<Handled> handled;
  const auto take_panel = [&](const control::PanelResult& r) {
    if (r.serial == 0 || (!handled.empty() && handled.back().result.serial >= r.serial)) return;
    Handled h{r, {}, {}};
    for (std::size_t i = 0; i < marking.prediction_samples(); ++i) h.samples.push_back(marking.prediction_sample(i));
    for (std::size_t i = 0; i < marking.panel_frames(); ++i) h.frames.push_back(marking.panel_frame(i));
    handled.push_back(std::move(h));
  };
  // Every panel-present episode is a panel: the inspection record offered as it comes
  // (the same record each time, the recording being of one panel; the id numbered from
  // the second on, "#2", so each result is told apart).
  int episodes_offered = 0;
  bool present = false;
  const auto drive = [&](LineRole line, bool level) {
    if (line == LineRole::kPlcPanelPresent && level && !present) {
      const std::uint64_t done = marking.panels_completed();
      if (done > 0 && (handled.empty() || handled.back().result.serial < done)) {
        marking.results().update();  // (the newest completed panel, published by the marking lane)
        take_panel(marking.results().read());
      }
      control::PanelJob next = job;
      if (++episodes_offered > 1) {
        const std::string id = std::string(job.panel_id.view()) + "#" + std::to_string(episodes_offered);
        if (id.size() <= 63) next.panel_id.assign(id);
      }
      if (marking.can_offer()) marking.offer_job(next);
    }
    if (line == LineRole::kPlcPanelPresent) present = level;
    if (peer) peer->drive(line, level);
    else cell.drive_sim_input(line, level);
  };
  control::SimClock* clock = cell.sim_clock();
  const auto now = [&] { return clock != nullptr ? clock->global_now() : cell.clock().now(0); };
  const Nanos start = now();  // the PLC script's and the command log's zero (0 in simulated time)
  cell.start();
  const Nanos end = source.end_time();
  const bool tty = options.progress && isatty(STDERR_FILENO) != 0;
  auto progress = [&](Nanos t) {
    if (!options.progress) return;
    if (real) {  // the lanes are running: only what is safe to read from here
      std::fprintf(stderr, "%s[%s] t=%5.1f/%.1f s  real time, real devices  panels done %llu%s", tty ? "\r" : "",
                   predictor.c_str(), to_seconds(t - start), to_seconds(end - start),
                   static_cast<unsigned long long>(marking.panels_completed()), tty ? "   " : "\n");
      return;
    }
    const auto& p = marking.current();
    const int sprayed = p.tally().sprayed;
    std::fprintf(stderr, "%s[%s] t=%5.1f/%.1f s  %-12s sprayed %d/%d  frames %llu%s", tty ? "\r" : "", predictor.c_str(),
                 to_seconds(t), to_seconds(end), std::string(control::to_string(marking.state())).c_str(), sprayed,
                 p.defects.ssize(), static_cast<unsigned long long>(cell.vision_stats()->frames), tty ? "   " : "\n");
  };

  // Time runs through the service's own loop (host/service_loop.hpp), as under `markcell
  // run`: looked at every second, the run ends with the panel done, or `tail` after the
  // last frame. The line brings the panel at the start and takes it away with the
  // recording's end: two PLC events around the user's script (after its events of the
  // same time, as the line moves on its own).
  std::vector<sim::PlcEvent> events = options.plc_events;
  const Nanos leaves = end - now();
  events.insert(std::upper_bound(events.begin(), events.end(), leaves, [](Nanos t, const sim::PlcEvent& e) { return t < e.at; }),
                sim::PlcEvent{leaves, LineRole::kPlcPanelPresent, false});
  events.insert(events.begin(), sim::PlcEvent{0, LineRole::kPlcPanelPresent, true});
  std::uint64_t episodes = 0;  // rising edges of panel present: the panels the run should handle
  for (bool level = false; const auto& e : events)
    if (e.line == LineRole::kPlcPanelPresent) {
      episodes += e.level && !level ? 1 : 0;
      level = e.level;
    }
  std::vector<std::string> cell_faults;
  const auto fault_line = [](const control::Fault& f) {
    char line[256];
    std::snprintf(line, sizeof line, "t=%.3f s %s %s: %s", to_seconds(f.time), std::string(control::to_string(f.code)).c_str(),
                  f.source.c_str(), f.detail.c_str());
    return std::string(line);
  };
  ServiceOptions service;
  service.clock = real ? ClockKind::kReal : ClockKind::kSimulated;
  service.duration = leaves + options.tail;
  service.plc_events = std::move(events);
  service.drive = drive;
  service.step = seconds(1);
  service.panels = episodes;  // (or the recording's end and the tail, whichever first)
  service.journal = false;
  service.on_fault = [&](const control::Fault& f) { cell_faults.push_back(fault_line(f)); };
  service.on_step = [&](Nanos) { progress(now()); };
  service.pose_log_folder = pose_log_folder;
  service.pose_log_mode = PoseLog::Mode::kTruncate;  // the run's own, as its commands.log
  ServiceLoop loop(cfg, cell, std::move(service));
  // A stop asked for is seen within 100 ms of simulated time (a few hundred ms of
  // computing at most) or 5 ms of real time.
  int stopped_by = 0;
  const LoopEnd ended = loop.supervise([&](Nanos timeout) {
    const Nanos until = monotonic_now() + timeout;
    for (;;) {
      if (options.stop != nullptr && (stopped_by = options.stop->load(std::memory_order_acquire)) != 0) return stopped_by;
      const Nanos left = until - monotonic_now();
      if (left <= 0) return 0;
      std::this_thread::sleep_for(std::chrono::nanoseconds(std::min<Nanos>(left, millis(5))));
    }
  });
  if (ended == LoopEnd::kWedged)
    throw std::runtime_error("the simulated cell wedged at t=" + std::to_string(to_seconds(clock->global_now())) + " s");
  const Nanos stopped_at = now() - start;
  if (options.progress && tty) std::fprintf(stderr, "\n");
  cell.shutdown(control::FaultCode::kShutdown, "rig", "replay finished");
  if (peer) peer->stop();

  take_panel(marking.current());  // the last (finished or not: a stop, the recording's end)
  PredictorRun run;
  run.predictor = predictor;
  run.stopped_by = stopped_by;
  run.stopped_at = stopped_by != 0 ? stopped_at : 0;
  run.episodes = static_cast<int>(episodes);
  run.panel = handled.empty() ? marking.current() : handled.front().result;
  for (const Handled& h : handled) {
    run.panels.push_back({h.result, {}});
    run.samples.insert(run.samples.end(), h.samples.begin(), h.samples.end());
    run.panel_frames.insert(run.panel_frames.end(), h.frames.begin(), h.frames.end());
  }
  run.vision = *cell.vision_stats();
  if (overlay != nullptr) run.arm = overlay->stats();
  run.frames_skipped = source.skipped();
  run.timing_report = cell.executive().timing_report();
  run.command_log = peer ? peer->command_log_text(start, cfg.arm.can.interface) : cell.command_log_text();
  if (peer) {
    run.peer_late_ticks = peer->late_ticks();
    if (!peer->error().empty()) run.faults.push_back("rig peer: " + peer->error());
    if (peer->priority_refused()) run.faults.push_back("rig peer: SCHED_FIFO refused, its thread ran at normal priority");
  }
  for (std::size_t i = 0; i < cell.executive().spec().tasks.size(); ++i) {
    run.deadline_misses += cell.executive().task_stats(static_cast<int>(i)).deadline_misses.load();
    run.overruns += cell.executive().task_stats(static_cast<int>(i)).overruns.load();
  }
  control::Fault f;
  while (cell.faults().pop(f)) cell_faults.push_back(fault_line(f));
  run.faults.insert(run.faults.end(), cell_faults.begin(), cell_faults.end());
  // Seconds per defect: each panel from its first approach to its end, over all sprayed.
  int sprayed = 0;
  Nanos busy = 0;
  for (const PanelRun& p : run.panels) {
    Nanos first = -1;
    for (const control::DefectResult& d : p.result.defects)
      if (d.approach_start >= 0 && (first < 0 || d.approach_start < first)) first = d.approach_start;
    const int n = p.result.tally().sprayed;
    if (n > 0 && first >= 0) busy += std::max<Nanos>(0, p.result.finished - first), sprayed += n;
  }
  if (sprayed > 0) run.seconds_per_defect = to_seconds(busy) / sprayed;

  // Scoring against the recording's truth.
  if (!rec.manifest().has_truth || !rec.manifest().has_defects) return run;
  const TruthTrack truth(rec.truth(), source);
  if (truth.empty()) return run;
  // Sprays land on the panel the recording shows: its own mesh (`panel_mesh`), never
  // another panel's; a recording without one is scored on the aim alone.
  // (read before the run, in replay_recording).
  const std::vector<Eigen::Vector3d>& true_mfs = rec.manifest().macro_features_Panel;
  std::vector<TrueDefect> defects;
  for (const auto& d : rec.defects()) defects.push_back({d.id, d.p_Panel});
  auto true_centre = [&](int id, Nanos t) -> std::optional<Eigen::Vector3d> {
    for (const auto& d : defects)
      if (d.id == id) return truth.at(t) * d.p_Panel;
    return std::nullopt;
  };
  std::vector<Spray> sprays;
  const Eigen::Isometry3d X_CamR_Base = cell.X_Base_CamR().inverse();
  // What the simulated world saw at the nozzle: the peer's behind real devices, else the cell's.
  if (const sim::NozzleWitness* nozzle = peer ? &peer->nozzle() : cell.sim_nozzle(); nozzle != nullptr) {
    if (nozzle->total() > nozzle->kept())
      run.faults.push_back("rig: the oldest " + std::to_string(nozzle->total() - nozzle->kept()) + " of " +
                           std::to_string(nozzle->total()) + " valve openings not scored (the newest " +
                           std::to_string(nozzle->kept()) + " kept)");
    for (std::size_t i = nozzle->total() - nozzle->kept(); i < nozzle->total(); ++i)
      sprays.push_back({nozzle->spray(i).time, X_CamR_Base * control::to_isometry(nozzle->spray(i).tool),
                        nozzle->spray(i).open_for});
  }
  // Each panel is scored on the sprays from its start to the next panel's (the first's
  // from the run's start, the last's to its end), so none is lost or counted twice.
  const auto truth_at = [&](Nanos t) { return truth.at(t); };
  for (std::size_t k = 0; k < run.panels.size(); ++k) {
    PanelRun& p = run.panels[k];
    std::vector<SkippedDefect> skipped;
    for (const control::DefectResult& d : p.result.defects)
      if (d.skipped != control::SkipReason::kNone) skipped.push_back({d.id, std::string(control::to_string(d.skipped))});
    std::vector<Spray> mine;
    for (const Spray& s : sprays)
      if ((k == 0 || s.time >= p.result.started) && (k + 1 == run.panels.size() || s.time < run.panels[k + 1].result.started))
        mine.push_back(s);
    p.score = panel ? score_sprays(*panel, truth_at, defects, mine, skipped, options.radius)
                    : score_sprays_by_aim(truth_at, defects, mine, skipped, options.radius);
  }
  run.score = merge_scores(run.panels, panel ? ScoredOn::kSurface : ScoredOn::kAim);
  run.scored = true;
  for (const PanelRun& p : run.panels)
    for (const control::DefectResult& d : p.result.defects) {
      if (!d.sprayed) continue;
      if (const auto c = true_centre(d.id, d.spray_requested)) {
        const Eigen::Vector3d e = (d.predicted_centre_CamR - *c).cwiseAbs();
        run.prediction_max_abs = run.prediction_max_abs ? run.prediction_max_abs->cwiseMax(e) : e;
        run.prediction_per_defect.push_back({d.id, e});
      }
    }
  // Where each panel frame P truly lies: the rigid fit of its set-up MFs' true positions
  // (CamR at that frame) onto where P put them, X_P_CamRref; once per P.
  std::vector<std::pair<Nanos, Eigen::Isometry3d>> placements;
  for (const auto& frame : run.panel_frames) {
    if (true_mfs.empty()) break;  // no true MFs to place P with: P taken as CamR at its set-up frame
    std::vector<Eigen::Vector3d> a, b;
    const std::size_t n = std::min(frame.mfs.size(), true_mfs.size());
    for (std::size_t k = 0; k < n; ++k)
      if (frame.mfs[k].found) {
        a.push_back(truth.at(frame.reference_time) * true_mfs[k]);
        b.push_back(frame.mfs[k].p_P);
      }
    // Robust: a search can take another corner for an MF (a person in front); the
    // inter-calibration leaves it out, and so does this.
    std::array<bool, msg::kMaxMacroFeatures> inlier{};
    geometry::RobustFitOptions robust;
    robust.inlier_threshold = 0.01;
    const geometry::RigidFit fit = geometry::fit_rigid_robust(a, b, robust, std::span(inlier.data(), a.size()));
    placements.emplace_back(frame.reference_time, fit.valid ? fit.X_B_A : Eigen::Isometry3d::Identity());
  }
  auto X_P_CamRref = [&](Nanos reference_time) {  // identity for a P not logged
    for (const auto& [time, X] : placements)
      if (time == reference_time) return X;
    return Eigen::Isometry3d(Eigen::Isometry3d::Identity());
  };
  double sq_pose = 0, sq_defect = 0;
  for (const auto& s : run.samples) {
    const auto c = true_centre(s.defect, s.time);
    run.truth_samples.push_back({s.time, c ? *c : Eigen::Vector3d::Zero()});
    run.one_frame_max_abs = run.one_frame_max_abs.cwiseMax((s.predicted_CamR - s.estimated_CamR).cwiseAbs());
    if (!c) continue;
    // P is (about) CamR at the frame that set it up, placed on the panel as above: the truth
    // moves the defect's centre in P from there to now.
    const Eigen::Isometry3d motion = truth.at(s.time) * truth.at(s.reference_time).inverse();
    const Eigen::Vector3d moved = motion * X_P_CamRref(s.reference_time).inverse() * s.centre_P;
    const double e = (s.estimated_CamR - moved).norm(), d = (s.estimated_CamR - *c).norm();
    run.pose_error_setup_frame_max = std::max(run.pose_error_setup_frame_max, (s.estimated_CamR - motion * s.centre_P).norm());
    run.pose_error_max = std::max(run.pose_error_max, e);
    run.defect_error_max = std::max(run.defect_error_max, d);
    sq_pose += e * e;
    sq_defect += d * d;
    ++run.pose_samples;
    if (s.inliers < s.count) {
      run.pose_error_missing_max = std::max(run.pose_error_missing_max, e);
      ++run.pose_samples_missing;
    }
  }
  if (run.pose_samples > 0) {
    run.pose_error_rms = std::sqrt(sq_pose / run.pose_samples);
    run.defect_error_rms = std::sqrt(sq_defect / run.pose_samples);
  }
  return run;
}

}  // namespace

namespace {
// Where two stereo calibrations differ most: each K, D, R (as the angle between them) and
// T compared entry by entry, the sizes exactly. Empty when they agree to 1e-9 relative.
std::string largest_difference(const vision::StereoCalibration& a, const vision::StereoCalibration& b) {
  std::string worst;
  double worst_excess = 0;
  const auto compare = [&](const std::string& name, double va, double vb) {
    const double tolerance = 1e-9 * std::max({1.0, std::abs(va), std::abs(vb)});
    const double excess = std::abs(va - vb) / tolerance;
    if (excess > 1 && excess > worst_excess) {
      worst_excess = excess;
      char text[160];
      std::snprintf(text, sizeof text, "%s %.10g vs %.10g", name.c_str(), va, vb);
      worst = text;
    }
  };
  for (int cam = 0; cam < 2; ++cam) {
    const vision::CameraModel& ca = cam == 0 ? a.left : a.right;
    const vision::CameraModel& cb = cam == 0 ? b.left : b.right;
    const std::string k = cam == 0 ? "K1" : "K2", d = cam == 0 ? "D1" : "D2";
    if (ca.width != cb.width || ca.height != cb.height)
      return "image size " + std::to_string(ca.width) + "x" + std::to_string(ca.height) + " vs " + std::to_string(cb.width) +
             "x" + std::to_string(cb.height);
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) compare(k + "[" + std::to_string(i) + "][" + std::to_string(j) + "]", ca.K(i, j), cb.K(i, j));
    const auto coeff = [](const vision::CameraModel& c, int i) {
      return !c.distortion.empty() && i < static_cast<int>(c.distortion.total()) ? c.distortion.at<double>(i) : 0.0;
    };
    for (int i = 0; i < 14; ++i) compare(d + "[" + std::to_string(i) + "]", coeff(ca, i), coeff(cb, i));
  }
  const double angle = Eigen::AngleAxisd(a.X_CamR_CamL.linear().transpose() * b.X_CamR_CamL.linear()).angle();
  if (angle > 1e-9) {
    char text[96];
    std::snprintf(text, sizeof text, "R: %.3g deg apart", angle * 180 / M_PI);
    if (worst_excess < angle / 1e-9) worst = text;
  }
  for (int i = 0; i < 3; ++i)
    compare("T[" + std::to_string(i) + "] (X_CamR_CamL, m)", a.X_CamR_CamL.translation()[i], b.X_CamR_CamL.translation()[i]);
  return worst;
}
}  // namespace

ReplayReport replay_recording(const CellConfig& base_config, const std::string& recording, const ReplayOptions& options) {
  if (!has_task(base_config, "vision") || !has_task(base_config, "marking"))
    throw std::runtime_error(base_config.file + ": executive.tasks needs the vision and marking tasks for a rig run");
  const vision::Recording rec = vision::Recording::open(recording);
  // The recording's own calibration, unless the user says which: a configuration made for
  // another pair of cameras would triangulate every MF wrongly without a word.
  CellConfig config = base_config;
  const std::string recorded = (std::filesystem::path(recording) / rec.manifest().calibration).string();
  if (!options.calibration.empty()) {
    config.calibration.stereo = options.calibration;
  } else {
    const std::string diff = largest_difference(vision::load_stereo_calibration(recorded),
                                                vision::load_stereo_calibration(config.calibration.stereo));
    if (!diff.empty())
      throw std::runtime_error("the recording's calibration " + recorded + " and the configuration's calibration.stereo " +
                               config.calibration.stereo + " differ (largest difference: " + diff +
                               "); say which to replay with: --calibration FILE");
    config.calibration.stereo = recorded;
  }
  const std::string inspection = (std::filesystem::path(recording) / "inspection.yaml").string();
  if (!std::filesystem::exists(inspection))
    throw std::runtime_error(inspection + ": missing: a rig run needs the inspection station's record of the panel");
  const control::PanelJob job = read_inspection_record(inspection, config.panel_types);
  if (job.panel_type.view() != rec.manifest().panel_type)
    throw std::runtime_error(inspection + ": panel_type '" + std::string(job.panel_type.view()) + "' but the recording is of '" +
                             rec.manifest().panel_type + "'");
  // The panel's surface, read before anything runs: a bad mesh is an error up front.
  std::optional<rig::Panel> panel;
  if (!rec.manifest().panel_mesh.empty())
    panel = rig::load_panel_mesh(rec.manifest().panel_type,
                                 (std::filesystem::path(rec.folder()) / rec.manifest().panel_mesh).string(),
                                 rec.manifest().panel_mesh_metres_per_unit);
  ReplayReport report;
  report.scenario = rec.manifest().scenario.empty() ? std::filesystem::path(recording).filename().string() : rec.manifest().scenario;
  report.recording = recording;
  report.panel_type = rec.manifest().panel_type;
  report.calibration = config.calibration.stereo;
  report.index_problems = rec.index_problems();
  if (!options.gpio_sim.empty()) {
    check_real_devices(config, options);
    report.devices = "real: gpio chip " + config.gpio.chip +
                     (config.arm.transport == ArmTransport::kCan ? ", CAN " + config.arm.can.interface
                                                                 : ", serial " + config.arm.serial.device) +
                     "; rig peer through gpio-sim " + options.gpio_sim +
                     (options.arm_serial_peer.empty() ? "" : " and serial " + options.arm_serial_peer);
  }
  using control::PredictorKind;
  std::vector<PredictorKind> kinds{config.marking.predictor.kind};
  if (options.both_predictors)
    kinds.push_back(config.marking.predictor.kind == PredictorKind::kKalman ? PredictorKind::kTwoFrame : PredictorKind::kKalman);
  // The main run's pose log beside its commands.log (vision/RECORDING.md, "The pose log").
  if (!options.out_dir.empty()) std::filesystem::create_directories(options.out_dir);
  for (const auto& k : kinds) {
    report.runs.push_back(
        run_once(config, recording, job, k, options, rec, panel, report.runs.empty() ? options.out_dir : std::string()));
    const PredictorRun& r = report.runs.back();
    if (r.stopped_by != 0) {  // the other predictor's run is not begun
      char at[64];
      std::snprintf(at, sizeof at, " at t=%.3f s of the ", to_seconds(r.stopped_at));
      report.stopped = signal_name(r.stopped_by) + at + r.predictor + " run";
      break;
    }
  }
  return report;
}

}  // namespace markcell::rig
