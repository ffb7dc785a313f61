#include "markcell/host/cell.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

#include "markcell/drivers/gpiod_lines.hpp"
#include "markcell/host/camera_frame_source.hpp"

namespace markcell::host {

// The cell's task table. Each entry is the one declaration of a task: its name, its kind
// (a control step or heavy per-frame work), whether a table must have it, what it needs
// beside it, and its binding. docs/executive.md's table is `markcell check-config
// --tasks`, checked by a test.
constexpr std::size_t kCellTaskCount = 7;

std::span<const Cell::TaskEntry> Cell::task_entries() {
  // The objects a binding needs are built from the configuration before binding; one
  // missing means the loader let through a table it should have refused.
  static const std::array<TaskEntry, kCellTaskCount> kCellTasks{{
      {{"plc_io", TaskKind::kControl, TaskPresence::kOptional, "drives the PLC handshake lines and takes the e-stop to the safe stop"},
       [](Cell& c, const std::string& n) { c.executive_->bind(n, &control::PlcIo::task, c.plc_io_.get()); }},
      {{"spray_valve", TaskKind::kControl, TaskPresence::kRequired, "opens and closes the valve on the tick"},
       [](Cell& c, const std::string& n) { c.executive_->bind(n, &control::SprayValve::task, c.spray_valve_.get()); }},
      {{"arm_link", TaskKind::kControl, TaskPresence::kRequired,
        "supervises the arm link: its faults to the safe stop, the arm held on a stop"},
       [](Cell& c, const std::string& n) {
         c.executive_->bind(n, &control::ArmSupervision::task, c.arm_supervision_.get());
       }},
      {{"sim_world", TaskKind::kControl, TaskPresence::kWithSimulatedDevices, "advances the simulated devices"},
       [](Cell& c, const std::string& n) {
         if (!c.sim_world_) throw std::logic_error("task '" + n + "' passed validation but the simulated world was not built");
         c.executive_->bind(n, &SimWorld::task, c.sim_world_.get());
       }},
      {{"vision", TaskKind::kHeavy, TaskPresence::kOptional, "turns each newest frame pair into macro-features and the panel's pose"},
       [](Cell& c, const std::string& n) {
         if (!c.vision_) throw std::logic_error("task '" + n + "' passed validation but the vision task was not built");
         c.executive_->bind(n, &VisionTask::task, c.vision_.get());
       }},
      {{"marking", TaskKind::kControl, TaskPresence::kOptional,
        "fits the inter-calibration, predicts, plans and runs the marking sequence",
        {{{"vision", ""}, {"plc_io", "panel present and the valve's interlock come from it"}}}},
       [](Cell& c, const std::string& n) {
         if (!c.marking_) throw std::logic_error("task '" + n + "' passed validation but the marking sequence was not built");
         c.executive_->bind(n, &control::MarkingSequence::task, c.marking_.get());
       }},
      {{"camera_trigger", TaskKind::kControl, TaskPresence::kOptional,
        "gives the camera trigger line a rising edge every other run (cameras on the trigger line)"},
       [](Cell& c, const std::string& n) {
         c.camera_trigger_ = std::make_unique<CameraTriggerTask>();
         c.camera_trigger_->gpio = c.gpio_.get();
         c.camera_trigger_->line = c.gpio_line(LineRole::kCameraTrigger);
         c.executive_->bind(n, &CameraTriggerTask::task, c.camera_trigger_.get());
       }},
  }};
  return kCellTasks;
}

TaskTable task_catalog() {
  static const auto kDecls = [] {
    const auto entries = Cell::task_entries();
    std::array<TaskDecl, kCellTaskCount> decls{};
    for (std::size_t i = 0; i < decls.size(); ++i) decls[i] = entries[i].decl;
    return decls;
  }();
  return kDecls;
}

drivers::CameraSettings camera_settings(const CameraConfig& c, const drivers::CameraUnitSettings& own) {
  drivers::CameraSettings s = c;  // what both cameras are set to ...
  s.set_own(own);                 // ... and this one's own settings
  return s;
}

drivers::SimArmLimits sim_arm_limits(const ArmConfig& arm) {
  drivers::SimArmLimits limits;
  limits.reach = arm.limits.reach;
  limits.max_speed = arm.limits.max_tcp_speed;
  limits.max_accel = arm.limits.max_tcp_accel;
  limits.home.position = arm.limits.home;
  return limits;
}

// `marking`'s plan settle and defect timeout, the arm's limits and the pulse.
control::ArmTimingModel arm_timing_model(const CellConfig& config, const control::ArmTimingModel& marking, Nanos pulse) {
  control::ArmTimingModel m = marking;
  m.max_speed = config.arm.limits.max_tcp_speed;
  m.max_accel = config.arm.limits.max_tcp_accel;
  m.reach = config.arm.limits.reach;
  m.pulse = pulse;
  return m;
}

control::ArmTimingModel arm_timing_model(const CellConfig& config) {
  return arm_timing_model(config, config.marking.timing, config.spray.pulse);
}

namespace {

// A marking section (the configuration's, or a panel type's with its recipe) completed
// with what the other sections give it. X_Base_CamR is the cell's, read at start-up.
control::MarkingParams assemble_marking(const CellConfig& config, control::MarkingParams m, Nanos pulse,
                                        const Eigen::Isometry3d& X_Base_CamR) {
  m.X_Base_CamR = X_Base_CamR;
  m.timing = arm_timing_model(config, m.timing, pulse);
  m.require_result_ack = !config.results_file.empty();
  return m;
}

}  // namespace

std::unique_ptr<drivers::ArmLink> make_arm_link(const ArmConfig& arm, std::unique_ptr<drivers::SocketCanBus>& bus_out) {
  switch (arm.transport) {
    case ArmTransport::kSimulated:
      break;
    case ArmTransport::kCan: {
      drivers::SocketCanConfig bus;
      bus.interface = arm.can.interface;
      bus.fd = arm.can.link.fd;
      const auto node = static_cast<std::uint32_t>(arm.can.link.node_id);
      bus.filter_ids = {drivers::canopen::kToolPositionId + node, drivers::canopen::kToolRotationId + node,
                        drivers::canopen::kHeartbeatId + node, drivers::canopen::kToolFdId + node};
      bus.filter_count = 4;
      bus_out = std::make_unique<drivers::SocketCanBus>(bus);
      return std::make_unique<drivers::CanArmLink>(*bus_out, arm.can.link);
    }
    case ArmTransport::kSerial:
      return std::make_unique<drivers::SerialArmLink>(arm.serial);
  }
  throw std::logic_error("make_arm_link: the simulated arm lives in the cell's simulated world");
}

control::TaskResult Cell::SimWorld::task(control::TaskContext& ctx, void* self) {
  auto* w = static_cast<SimWorld*>(self);
  w->arm->poll(ctx.now());
  w->tool_poses.write(w->arm->model().tool());
  // Runs after spray_valve in the tick: a valve that opened this tick is open now.
  w->nozzle.observe(ctx.now(), w->valve != nullptr && w->valve->open(), w->arm->model().tool(), w->log);
  return control::TaskResult::kOk;
}

control::TaskResult Cell::VisionTask::task(control::TaskContext& ctx, void* self) {
  auto* v = static_cast<VisionTask*>(self);
  if (v->requests->update()) {
    const msg::TrackerRequest& r = v->requests->read();
    v->job.job_serial = r.job_serial;
    v->job.mfs_SL = r.mfs_SL;
    if (r.reset_serial != v->reset_seen) {
      v->reset_seen = r.reset_serial;
      v->active = std::clamp(r.panel_type, 0, static_cast<int>(v->trackers.size()) - 1);
      v->trackers[static_cast<std::size_t>(v->active)]->reset();
    }
    vision::PanelTracker& t = *v->trackers[static_cast<std::size_t>(v->active)];
    if (r.reference_serial != 0 && r.reference_serial == t.last().reference_serial && r.placement_serial != v->hint_seen) {
      v->hint_seen = r.placement_serial;
      // Placed anew: MFs the tracker has no position for, or only a placed one it has not
      // measured yet; never one it has measured.
      const auto& mfs = t.last().mfs;
      for (std::size_t i = 0; i < mfs.size(); ++i)
        if (r.known[i] && (!mfs[i].reference_known || mfs[i].reference_observed == 0))
          t.set_reference(static_cast<int>(i), r.reference_P[i]);
    }
  }
  if (v->source == nullptr) return control::TaskResult::kOk;
  vision::StereoFrameRef f;
  const vision::FrameResult got = v->source->next(ctx.now(), f);
  if (got == vision::FrameResult::kStalled) {
    ++v->stats.stalls;
    control::Fault fault{ctx.now(), control::FaultCode::kDeviceFault, {}, {}};
    fault.source.assign("vision");
    fault.detail.assign("frame source stalled: no frame within its timeout");
    v->faults->push(fault);
    return control::TaskResult::kOk;
  }
  if (got != vision::FrameResult::kFrame) return control::TaskResult::kOk;
  ++v->stats.frames;
  if (f.dropped) {
    ++v->stats.dropped;
    control::Fault fault{ctx.now(), control::FaultCode::kFrameDropped, {}, {}};
    fault.source.assign("vision");
    fault.detail.assign(f.problem);
    v->faults->push(fault);
    return control::TaskResult::kOk;
  }
  const msg::PoseEstimate& e = v->trackers[static_cast<std::size_t>(v->active)]->process(f.seq, f.time, *f.left, *f.right);
  if (e.has_pose()) ++v->stats.poses;
  if (v->poses != nullptr) v->poses->push(e);  // a full queue counts the estimate, never waits
  if (v->live != nullptr) v->live->offer(f.seq, f.time, *f.left, *f.right, e);  // only when the page asked
  v->source->tracked(e);
  control::MarkingEstimate& out = v->estimates->write_slot();
  out.pose = e;
  out.fits = control::PoseFits{};
  if (v->job.job_serial != 0 && e.has_pose()) control::fit_pose_to_record(v->job, e, v->limits, out.fits);
  v->estimates->publish();
  return control::TaskResult::kOk;
}

control::TaskResult Cell::CameraTriggerTask::task(control::TaskContext&, void* self) {
  auto* t = static_cast<CameraTriggerTask*>(self);
  t->high = !t->high;
  // The trigger line is on the chip that also holds the valve and the PLC lines: one
  // that cannot be set is a fault of the cell, not a lost frame.
  return t->gpio->set(t->line, t->high) == drivers::GpioStatus::kOk ? control::TaskResult::kOk : control::TaskResult::kFault;
}

struct Cell::DeviceWatchdogSink final : control::WatchdogSink {
  explicit DeviceWatchdogSink(drivers::WatchdogDevice& d) : device(d) {}
  std::string_view name() const override { return "watchdog_device"; }
  void feed(Nanos) noexcept override { device.feed(); }
  drivers::WatchdogDevice& device;
};

Cell::Cell(const CellConfig& config, ClockKind clock)
    : config_(config), notifier_(config.watchdog.systemd_interval) {
  if (clock == ClockKind::kSimulated) {
    auto sim = std::make_unique<control::SimClock>(control::Executive::clock_lanes(config.executive));
    sim_clock_ = sim.get();
    clock_ = std::move(sim);
  } else {
    clock_ = std::make_unique<control::RealClock>();
  }

  if (config.gpio.simulated) {
    auto gpio = std::make_unique<drivers::SimGpioLines>();
    sim_gpio_ = gpio.get();
    if (clock == ClockKind::kSimulated)
      sim_gpio_->set_time_source([](void* c) { return static_cast<control::SimClock*>(c)->global_now(); }, sim_clock_);
    gpio_device_ = std::move(gpio);
  } else {
    gpio_device_ = std::make_unique<drivers::GpiodLines>(config.gpio.chip);
  }
  gpio_ = std::make_unique<drivers::MirroredGpioLines>(*gpio_device_);
  std::vector<drivers::LineRequest> requests;
  for (std::size_t i = 0; i < kLineRoleCount; ++i) {
    const auto role = static_cast<LineRole>(i);
    requests.push_back(drivers::LineRequest{config.gpio.lines[i].line, is_output(role), config.gpio.lines[i].active_low, false});
  }
  gpio_->configure(requests);
  gpio_safe_ = std::make_unique<control::GpioSafeOutputs>(
      *gpio_, config.safe_stop.plc_fault_line ? gpio_line(LineRole::kPlcFault) : -1);
  safe_stop_.add_output(*gpio_safe_);

  control::PlcLineMap map;
  map.panel_present = gpio_line(LineRole::kPlcPanelPresent);
  map.cycle_enable = gpio_line(LineRole::kPlcCycleEnable);
  map.estop = gpio_line(LineRole::kPlcEstop);
  map.ready = gpio_line(LineRole::kPlcReady);
  map.busy = gpio_line(LineRole::kPlcBusy);
  map.done = gpio_line(LineRole::kPlcDone);
  map.fault = gpio_line(LineRole::kPlcFault);
  plc_io_ = std::make_unique<control::PlcIo>(
      *gpio_, map, safe_stop_, config.gpio.input_filter,
      config.safe_stop.rearm == RearmConfig::kNever ? control::RearmPolicy::kNever : control::RearmPolicy::kCycleEnable);

  spray_valve_ = std::make_unique<control::SprayValve>(*gpio_, gpio_line(LineRole::kSprayValve), config.spray.min_pulse,
                                                       config.spray.max_pulse);
  // The valve opens only while the PLC's panel present holds (the marking task needs
  // plc_io in the table: the loader says so).
  const bool has_plc_io = std::any_of(config.executive.tasks.begin(), config.executive.tasks.end(),
                                      [](const control::TaskSpec& t) { return t.name == "plc_io"; });
  if (has_plc_io) spray_valve_->set_permit(&plc_io_->inputs().spray_permitted);

  // The arm link. A simulated arm is a CAN node on an in-memory wire, so the real CAN
  // codec and link state machine run in the simulated cell too.
  switch (config.arm.transport) {
    case ArmTransport::kSimulated: {
      sim_world_ = std::make_unique<SimWorld>();
      if (sim_clock_ != nullptr)
        sim_world_->wire.set_time_source([](void* c) { return static_cast<control::SimClock*>(c)->global_now(); }, sim_clock_);
      const drivers::SimArmLimits limits = sim_arm_limits(config.arm);
      sim_world_->arm = std::make_unique<drivers::SimCanArm>(
          sim_world_->wire.b(), config.arm.can.link.node_id, limits, millis(10),
          config.arm.can.link.heartbeat_period, config.arm.can.link.heartbeat_timeout, config.arm.can.link.fd);
      arm_link_ = std::make_unique<drivers::CanArmLink>(sim_world_->wire.a(), config.arm.can.link);
      break;
    }
    case ArmTransport::kCan:
    case ArmTransport::kSerial:
      arm_link_ = make_arm_link(config.arm, can_bus_);
      break;
  }
  arm_supervision_ = std::make_unique<control::ArmSupervision>(*arm_link_, safe_stop_,
                                                               config.safe_stop.arm == ArmSafeAction::kHome,
                                                               config.marking.home_timeout);
  if (sim_world_) sim_world_->valve = spray_valve_.get();

  // Vision and marking, when configured: the rig model, one tracker per panel type, the
  // frame source, and the buffers between the lanes.
  const auto has_task = [&](std::string_view name) {
    return std::any_of(config.executive.tasks.begin(), config.executive.tasks.end(),
                       [&](const control::TaskSpec& t) { return t.name == name; });
  };
  if (!config.calibration.base.empty()) X_Base_CamR_ = vision::load_pose(config.calibration.base, "X_Base_CamR");
  estimates_ = std::make_unique<TripleBuffer<control::MarkingEstimate>>();
  tracker_requests_ = std::make_unique<TripleBuffer<msg::TrackerRequest>>();
  if (has_task("vision")) {
    rig_ = std::make_unique<vision::StereoRig>(vision::load_stereo_calibration(config.calibration.stereo));
    vision_ = std::make_unique<VisionTask>();
    for (const auto& panel : config.panel_types) {
      panel_models_.push_back(vision::load_panel_type(panel.file));
      vision_->trackers.push_back(std::make_unique<vision::PanelTracker>(*rig_, panel_models_.back(), config.vision));
    }
    if (config.cameras.source == CameraSource::kRecording) {
      // In real time the loader stands in for the cameras' receive threads: at the vision
      // lane's priority, so that a real-time vision lane does not starve it.
      int loader_priority = 0;
      for (const auto& task : config.executive.tasks)
        if (task.name == "vision") loader_priority = config.executive.lanes[static_cast<std::size_t>(task.lane)].priority;
      frame_source_ = std::make_unique<vision::RecordingFrameSource>(config.cameras.recording, config.cameras.latency,
                                                                     clock == ClockKind::kSimulated, seconds(60),
                                                                     clock == ClockKind::kReal ? loader_priority : 0);
      // A recording of another size than the calibration would reach the tracker frame by
      // frame: refused here, naming both.
      const auto& m = static_cast<vision::RecordingFrameSource&>(*frame_source_).recording().manifest();
      if (m.image_width != rig_->width() || m.image_height != rig_->height())
        throw std::runtime_error(config.cameras.recording + ": the recording's images are " + std::to_string(m.image_width) +
                                 "x" + std::to_string(m.image_height) + ", the stereo calibration " +
                                 config.calibration.stereo + " is for " + std::to_string(rig_->width()) + "x" +
                                 std::to_string(rig_->height()));
    }
    else if (config.cameras.source == CameraSource::kAravis)
      frame_source_ = std::make_unique<CameraFrameSource>(
          std::make_unique<drivers::AravisCamera>(camera_settings(config.cameras, config.cameras.left)),
          std::make_unique<drivers::AravisCamera>(camera_settings(config.cameras, config.cameras.right)),
          config.cameras.width, config.cameras.height, config.cameras.fps,
          config.cameras.trigger == CameraTrigger::kSoftware, config.cameras.latency, config.cameras.lost_after);
    vision_->source = frame_source_.get();
    vision_->estimates = estimates_.get();
    vision_->requests = tracker_requests_.get();
    vision_->faults = &faults_;
  }
  if (has_task("marking")) {
    // The `marking:` section as configured, and what other sections and files give it;
    // the same for each panel type's recipe (the section with its recipe over it).
    const control::MarkingParams mp = assemble_marking(config, config.marking, config.spray.pulse, X_Base_CamR_);
    const std::vector<control::MarkingParams> per_type = recipes(config);
    if (vision_) vision_->limits = mp.intercalibration;  // its fits are the marking sequence's
    control::PlcLineMap lines;
    lines.busy = gpio_line(LineRole::kPlcBusy);
    lines.done = gpio_line(LineRole::kPlcDone);
    lines.fault = gpio_line(LineRole::kPlcFault);
    marking_ = std::make_unique<control::MarkingSequence>(mp, *arm_link_, *spray_valve_, *gpio_, lines, *plc_io_,
                                                          *estimates_, *tracker_requests_);
    if (config.line.panel_id_source != PanelIdSource::kNone)
      marking_->use_line_arrivals(&line_arrivals_, config.line.silent,
                                  config.line.panel_id_source == PanelIdSource::kBroker ? "broker_link" : "plc_link");
    if (!marking_->set_recipes(per_type))
      throw std::invalid_argument(config.file + ": " + std::to_string(per_type.size()) + " panel types, at most " +
                                  std::to_string(control::kMaxPanelTypes));
  }

  executive_ = std::make_unique<control::Executive>(config.executive, *clock_, safe_stop_);
  for (const auto& task : config.executive.tasks) {
    const auto entries = task_entries();
    const auto entry = std::find_if(entries.begin(), entries.end(), [&](const TaskEntry& e) { return e.decl.name == task.name; });
    if (entry == entries.end()) throw std::logic_error("task '" + task.name + "' passed validation but has no binding");
    entry->bind(*this, task.name);
  }
  if (config.watchdog.systemd) executive_->add_watchdog(notifier_);
  if (config.watchdog.device.enabled) {
    watchdog_device_ = std::make_unique<drivers::WatchdogDevice>(
        config.watchdog.device.config);
    watchdog_device_sink_ = std::make_unique<DeviceWatchdogSink>(*watchdog_device_);
    executive_->add_watchdog(*watchdog_device_sink_);
  }
}

void Cell::enable_command_log(std::size_t capacity) {
  if (!sim_world_ || started_) throw std::logic_error("the command log needs the simulated arm and must be enabled before start()");
  sim_world_->log.reserve(capacity);
  sim_world_->wire.set_tap(
      [](void* user, const drivers::CanFrame& frame, Nanos time) {
        static_cast<SimWorld*>(user)->log.frame(time, frame);
      },
      sim_world_.get());
}

void Cell::enable_pose_queue() {
  if (pose_queue_) return;
  if (!vision_ || started_) throw std::logic_error("the pose queue needs the vision task and must be enabled before start()");
  if (!pose_queue_) pose_queue_ = std::make_unique<PoseQueue>();
  vision_->poses = pose_queue_.get();
}

void Cell::enable_live_view() {
  if (live_view_) return;
  if (!vision_ || started_) throw std::logic_error("the live view needs the vision task and must be enabled before start()");
  live_view_ = std::make_unique<LiveViewChannel>();
  vision_->live = live_view_.get();
}

std::unique_ptr<vision::FrameSource> Cell::release_frame_source() {
  if (!vision_ || started_) throw std::logic_error("the frame source can be handed over only before start(), with the vision task");
  vision_->source = nullptr;
  return std::move(frame_source_);
}

void Cell::use_frame_source(std::unique_ptr<vision::FrameSource> source) {
  if (!vision_ || started_) throw std::logic_error("a frame source needs the vision task and must be set before start()");
  frame_source_ = std::move(source);
  vision_->source = frame_source_.get();
}

std::vector<control::MarkingParams> Cell::recipes(const CellConfig& config) const {
  std::vector<control::MarkingParams> per_type;
  for (const PanelTypeConfig& panel : config.panel_types) per_type.push_back(assemble_marking(config, panel.marking, panel.pulse, X_Base_CamR_));
  return per_type;
}

bool Cell::reload_recipes(const CellConfig& config) {
  return marking_ != nullptr && marking_->set_recipes(recipes(config));
}

sim::CommandLogText Cell::command_log_text() const {
  return sim_world_ ? sim_world_->log.text(0, config_.arm.can.interface) : sim::CommandLogText{};
}

Cell::~Cell() {
  if (started_ && !shut_down_) shutdown(control::FaultCode::kShutdown, "cell", "destroyed without shutdown");
}

void Cell::start() {
  gpio_->activate();
  if (sim_gpio_ != nullptr) {
    // The simulated PLC enables the cycle and keeps the e-stop released, as a line does
    // when it runs; scenarios script the rest.
    drive_sim_input(LineRole::kPlcCycleEnable, true);
    drive_sim_input(LineRole::kPlcEstop, false);
  }
  if (watchdog_device_) watchdog_device_->activate();
  if (sim_world_) sim_world_->arm->start(clock_->now(0));
  arm_link_->activate(clock_->now(0));
  if (frame_source_) frame_source_->start(clock_->now(0));
  executive_->start();
  started_ = true;
  if (config_.watchdog.systemd) notifier_.ready();
}

void Cell::shutdown(control::FaultCode code, std::string_view source, std::string_view detail) {
  if (shut_down_) return;
  shut_down_ = true;
  if (config_.watchdog.systemd) notifier_.stopping();
  safe_stop_.trigger(clock_->now(0), code, source, detail);
  executive_->stop();
  if (frame_source_) frame_source_->stop();
  arm_link_->deactivate();
  gpio_->deactivate();
  if (watchdog_device_) watchdog_device_->deactivate();
}

std::vector<std::string> Cell::privilege_warnings() const {
  std::vector<std::string> w;
  const auto& rt = executive_->rt_warnings();
  if (rt.mlock_failed)
    w.emplace_back(
#if defined(__SANITIZE_ADDRESS__)
        "memory not locked: mlockall is skipped in AddressSanitizer builds"
#else
        "memory not locked: mlockall failed (needs CAP_IPC_LOCK or a large enough RLIMIT_MEMLOCK); page faults may delay the lanes"
#endif
    );
  if (rt.sched_failed)
    w.emplace_back("lanes run without SCHED_FIFO: setting the real-time priority was refused (needs CAP_SYS_NICE or an RLIMIT_RTPRIO); wake-up latency is not bounded");
  if (rt.affinity_failed)
    w.emplace_back("lanes are not pinned: setting CPU affinity failed (is the configured core present and allowed?)");
  return w;
}

}  // namespace markcell::host
