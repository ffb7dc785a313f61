#pragma once
// The cell assembled from its configuration: clock, fault log, safe stop, devices and the
// executive with every configured task bound to the code that provides it.
#include <algorithm>
#include <array>
#include <atomic>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "markcell/control/arm_supervision.hpp"
#include "markcell/control/exec_clock.hpp"
#include "markcell/control/executive.hpp"
#include "markcell/control/faults.hpp"
#include "markcell/control/marking.hpp"
#include "markcell/control/plc_io.hpp"
#include "markcell/control/spray_valve.hpp"
#include "markcell/drivers/camera.hpp"
#include "markcell/drivers/can_arm_link.hpp"
#include "markcell/drivers/gpio.hpp"
#include "markcell/drivers/gpio_mirror.hpp"
#include "markcell/drivers/serial_arm_link.hpp"
#include "markcell/drivers/watchdog_device.hpp"
#include "markcell/common/spsc_ring.hpp"
#include "markcell/sim/command_log.hpp"
#include "markcell/sim/nozzle_witness.hpp"
#include "markcell/host/config.hpp"
#include "markcell/host/live_view.hpp"
#include "markcell/host/sd_notify.hpp"
#include "markcell/vision/frame_source.hpp"
#include "markcell/vision/panel_tracker.hpp"
#include "markcell/vision/stereo_rig.hpp"

namespace markcell::host {

// Every task this build provides, as the loader sees it: the declarations of the cell's
// task table (Cell::task_entries), in its order.
TaskTable task_catalog();

enum class ClockKind { kReal, kSimulated };

// The arm link's pieces as configured, shared by the cell and calibrate-base.
drivers::SimArmLimits sim_arm_limits(const ArmConfig& arm);
// One camera's driver settings from the configuration's cameras section (the cell's
// camera frame source, record and calibrate-base).
drivers::CameraSettings camera_settings(const CameraConfig& cameras, const drivers::CameraUnitSettings& own);
// The planner's model of the arm (limits, reach, settle, pulse, defect timeout): the
// marking sequence's plans and `markcell capacity` use the same.
control::ArmTimingModel arm_timing_model(const CellConfig& config);
// ... with a panel type's recipe: its plan settle, defect timeout and pulse.
control::ArmTimingModel arm_timing_model(const CellConfig& config, const control::ArmTimingModel& marking, Nanos pulse);
// A real transport's link (can, serial); `bus` receives the SocketCAN bus a CAN link
// runs on. Throws std::logic_error for the simulated transport (the cell's own world).
std::unique_ptr<drivers::ArmLink> make_arm_link(const ArmConfig& arm, std::unique_ptr<drivers::SocketCanBus>& bus);

// The vision task: frames from the source, the tracker of the panel type the marking
// sequence asked for, poses out to the control lane.
// Counted by the vision lane, read live by the operator page's thread (relaxed: a reading
// may be a frame behind); a copy is a reading.
struct VisionStats {
  std::atomic<std::uint64_t> frames{0};
  std::atomic<std::uint64_t> dropped{0};   // pairs the source could not deliver (each reported)
  std::atomic<std::uint64_t> poses{0};
  std::atomic<std::uint64_t> stalls{0};
  VisionStats() = default;
  VisionStats(const VisionStats& o) { *this = o; }
  VisionStats& operator=(const VisionStats& o) {
    frames.store(o.frames.load(std::memory_order_relaxed), std::memory_order_relaxed);
    dropped.store(o.dropped.load(std::memory_order_relaxed), std::memory_order_relaxed);
    poses.store(o.poses.load(std::memory_order_relaxed), std::memory_order_relaxed);
    stalls.store(o.stalls.load(std::memory_order_relaxed), std::memory_order_relaxed);
    return *this;
  }
};

// The vision task's estimates on their way to the pose log (host/pose_log.hpp): 256 pairs,
// eight seconds at 30 fps, while the service loop empties it every 50 ms (100 ms of
// simulated time, one second in the rig's replay).
using PoseQueue = SpscRing<msg::PoseEstimate, 256>;

class Cell {
 public:
  // The task table (PX4's wq_configurations): every task this build provides, declared
  // once, with what the loader checks (TaskDecl) and how the cell binds it to the
  // executive. A task the configuration names is bound in the configuration's order.
  struct TaskEntry {
    TaskDecl decl;
    void (*bind)(Cell& cell, const std::string& name);
  };
  static std::span<const TaskEntry> task_entries();

  Cell(const CellConfig& config, ClockKind clock);
  ~Cell();

  // Devices up, executive started, READY=1. Throws naming the device that failed.
  void start();
  // Safe stop with `reason` (outputs safe), executive stopped, devices released,
  // STOPPING=1. Idempotent.
  void shutdown(control::FaultCode code, std::string_view source, std::string_view detail);

  control::ExecClock& clock() { return *clock_; }
  control::SimClock* sim_clock() { return sim_clock_; }
  control::Executive& executive() { return *executive_; }
  control::SafeStop& safe_stop() { return safe_stop_; }
  control::FaultLog& faults() { return faults_; }
  drivers::SimGpioLines* sim_gpio() { return sim_gpio_; }
  // The lines every task drives (the device, mirrored: gpio_mirror()); the device itself.
  drivers::GpioLines& gpio() { return *gpio_; }
  drivers::GpioLines& gpio_device() { return *gpio_device_; }
  const drivers::MirroredGpioLines& gpio_mirror() const { return *gpio_; }
  // The line's announcements for the marking task (pairing by panel id, `line:`); the
  // panel-id source (host/plc_link.hpp) is their one writer.
  TripleBuffer<msg::LineArrival>& line_arrivals() { return line_arrivals_; }
  int gpio_line(LineRole role) const { return static_cast<int>(role); }
  // Simulated GPIO only: the PLC drives an input to a logical level (active_low applied).
  void drive_sim_input(LineRole role, bool logical) {
    sim_gpio_->drive_physical(gpio_line(role), logical != config_.gpio.lines[static_cast<std::size_t>(role)].active_low);
  }
  SystemdNotifier& notifier() { return notifier_; }
  control::SprayValve& spray_valve() { return *spray_valve_; }
  drivers::ArmLink& arm_link() { return *arm_link_; }
  control::ArmSupervision& arm_supervision() { return *arm_supervision_; }
  // The simulated arm (null unless devices.arm.transport is simulated).
  drivers::SimCanArm* sim_arm() { return sim_world_ ? sim_world_->arm.get() : nullptr; }
  // Valve openings seen by the simulated world (null unless the arm is simulated).
  const sim::NozzleWitness* sim_nozzle() const { return sim_world_ ? &sim_world_->nozzle : nullptr; }
  // The rig's command logs: every CAN frame the controller sends to the simulated arm
  // (candump -L, on the configured interface's name) and every valve opening and closing,
  // with simulated times (sim/command_log.hpp).
  // Storage for `capacity` entries is taken here, before start(); a full log counts
  // what it could not keep. Simulated arm only.
  void enable_command_log(std::size_t capacity);
  // Every estimate of the vision task into a queue for the pose log, taken here before
  // start() (again later: nothing to do); null until then, or without a vision task.
  void enable_pose_queue();
  PoseQueue* pose_queue() { return pose_queue_.get(); }
  // The operator page's live view (host/live_view.hpp), taken here before start() (again
  // later: nothing to do); null until then, or without a vision task.
  void enable_live_view();
  LiveViewChannel* live_view() { return live_view_.get(); }
  // Replaces the configured frame source (before start()): tests, benchmarks, and the
  // rig, which puts its own in front of the configured one (rig/arm_view.hpp).
  void use_frame_source(std::unique_ptr<vision::FrameSource> source);
  // Hands the configured frame source over (before start()), leaving the vision task
  // without one until use_frame_source.
  std::unique_ptr<vision::FrameSource> release_frame_source();
  // The simulated arm's true tool pose, published by the simulated world every tick
  // (null unless the arm is simulated). One reader: whoever watches the world from the
  // vision lane (the rig drawing the arm into the frames).
  TripleBuffer<drivers::ToolPose>* sim_tool_poses() { return sim_world_ ? &sim_world_->tool_poses : nullptr; }
  sim::CommandLogText command_log_text() const;
  // The marking sequence and the vision task (null when not in the task table).
  control::MarkingSequence* marking() { return marking_.get(); }
  // Each panel type's marking parameters: `config`'s marking section with the type's
  // recipe over it, completed as the cell completes its own (X_Base_CamR, the arm's
  // timing, the result acknowledgement).
  std::vector<control::MarkingParams> recipes(const CellConfig& config) const;
  // On a reload (the service's thread): `config`'s panel types' recipes, for panels whose
  // record is taken from now on (the same panel types, in the same order, as the
  // running configuration's). False: no marking task, or too many panel types.
  bool reload_recipes(const CellConfig& config);
  vision::FrameSource* frame_source() { return frame_source_.get(); }
  const VisionStats* vision_stats() const { return vision_ ? &vision_->stats : nullptr; }
  const vision::StereoRig* stereo_rig() const { return rig_.get(); }
  const Eigen::Isometry3d& X_Base_CamR() const { return X_Base_CamR_; }
  // One line per privilege the real clock could not get (empty when all were granted).
  std::vector<std::string> privilege_warnings() const;

 private:
  const CellConfig& config_;
  std::unique_ptr<control::ExecClock> clock_;
  control::SimClock* sim_clock_ = nullptr;
  control::FaultLog faults_;
  control::SafeStop safe_stop_{faults_};
  std::unique_ptr<drivers::GpioLines> gpio_device_;
  std::unique_ptr<drivers::MirroredGpioLines> gpio_;  // gpio_device_ with its levels mirrored
  drivers::SimGpioLines* sim_gpio_ = nullptr;
  TripleBuffer<msg::LineArrival> line_arrivals_;
  std::unique_ptr<control::GpioSafeOutputs> gpio_safe_;
  std::unique_ptr<control::PlcIo> plc_io_;
  std::unique_ptr<control::SprayValve> spray_valve_;
  struct SimWorld {
    drivers::SimCanWire wire;
    std::unique_ptr<drivers::SimCanArm> arm;
    control::SprayValve* valve = nullptr;
    TripleBuffer<drivers::ToolPose> tool_poses;  // the arm's true tool pose, every tick
    sim::NozzleWitness nozzle;
    sim::CommandLog log;  // capacity reserved once, by enable_command_log
    static control::TaskResult task(control::TaskContext& ctx, void* self);
  };
  struct VisionTask {
    vision::FrameSource* source = nullptr;
    std::vector<std::unique_ptr<vision::PanelTracker>> trackers;  // one per panel type
    TripleBuffer<control::MarkingEstimate>* estimates = nullptr;
    TripleBuffer<msg::TrackerRequest>* requests = nullptr;
    control::FaultLog* faults = nullptr;
    PoseQueue* poses = nullptr;  // every estimate, for the pose log (null: none kept)
    LiveViewChannel* live = nullptr;  // the operator page's view (null: none)
    // The panel's record (from the last request) and the limits its fits are made with.
    msg::TrackerRequest job;
    control::IntercalibrationLimits limits;
    int active = 0;
    std::uint32_t reset_seen = 0;
    std::uint32_t hint_seen = 0;
    VisionStats stats;
    static control::TaskResult task(control::TaskContext& ctx, void* self);
  };
  struct CameraTriggerTask {
    drivers::GpioLines* gpio = nullptr;
    int line = -1;
    bool high = false;
    static control::TaskResult task(control::TaskContext& ctx, void* self);
  };
  std::unique_ptr<CameraTriggerTask> camera_trigger_;
  std::unique_ptr<vision::StereoRig> rig_;
  Eigen::Isometry3d X_Base_CamR_ = Eigen::Isometry3d::Identity();
  std::vector<vision::PanelTypeModel> panel_models_;
  std::unique_ptr<vision::FrameSource> frame_source_;
  std::unique_ptr<TripleBuffer<control::MarkingEstimate>> estimates_;
  std::unique_ptr<TripleBuffer<msg::TrackerRequest>> tracker_requests_;
  std::unique_ptr<VisionTask> vision_;
  std::unique_ptr<PoseQueue> pose_queue_;
  std::unique_ptr<LiveViewChannel> live_view_;
  std::unique_ptr<control::MarkingSequence> marking_;
  std::unique_ptr<SimWorld> sim_world_;
  std::unique_ptr<drivers::SocketCanBus> can_bus_;
  std::unique_ptr<drivers::ArmLink> arm_link_;
  std::unique_ptr<control::ArmSupervision> arm_supervision_;
  SystemdNotifier notifier_;
  std::unique_ptr<drivers::WatchdogDevice> watchdog_device_;
  struct DeviceWatchdogSink;
  std::unique_ptr<DeviceWatchdogSink> watchdog_device_sink_;
  std::unique_ptr<control::Executive> executive_;
  bool started_ = false;
  bool shut_down_ = false;
};

}  // namespace markcell::host
