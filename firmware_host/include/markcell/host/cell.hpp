#pragma once
// The cell assembled from its configuration: clock, fault log, safe stop, devices and the
// executive with every configured task bound to the code that provides it.
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "markcell/control/exec_clock.hpp"
#include "markcell/control/executive.hpp"
#include "markcell/control/faults.hpp"
#include "markcell/control/arm_supervision.hpp"
#include "markcell/control/plc_io.hpp"
#include "markcell/control/spray_valve.hpp"
#include "markcell/drivers/can_arm_link.hpp"
#include "markcell/drivers/serial_arm_link.hpp"
#include "markcell/drivers/gpio.hpp"
#include "markcell/drivers/watchdog_device.hpp"
#include "markcell/host/config.hpp"
#include "markcell/host/sd_notify.hpp"

namespace markcell::host {

// Every task this build provides, in the order they are documented.
const std::vector<std::string>& task_catalog();

enum class ClockKind { kReal, kSimulated };

class Cell {
 public:
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
  drivers::GpioLines& gpio() { return *gpio_; }
  int gpio_line(LineRole role) const { return static_cast<int>(role); }
  SystemdNotifier& notifier() { return notifier_; }
  control::SprayValve& spray_valve() { return *spray_valve_; }
  drivers::ArmLink& arm_link() { return *arm_link_; }
  control::ArmSupervision& arm_supervision() { return *arm_supervision_; }
  // The simulated arm (null unless devices.arm.transport is simulated).
  drivers::SimCanArm* sim_arm() { return sim_world_ ? sim_world_->arm.get() : nullptr; }
  // One line per privilege the real clock could not get (empty when all were granted).
  std::vector<std::string> privilege_warnings() const;

 private:
  const CellConfig& config_;
  std::unique_ptr<control::ExecClock> clock_;
  control::SimClock* sim_clock_ = nullptr;
  control::FaultLog faults_;
  control::SafeStop safe_stop_{faults_};
  std::unique_ptr<drivers::GpioLines> gpio_;
  drivers::SimGpioLines* sim_gpio_ = nullptr;
  std::unique_ptr<control::GpioSafeOutputs> gpio_safe_;
  std::unique_ptr<control::PlcIo> plc_io_;
  std::unique_ptr<control::SprayValve> spray_valve_;
  struct SimWorld {
    drivers::SimCanWire wire;
    std::unique_ptr<drivers::SimCanArm> arm;
    static control::TaskResult task(control::TaskContext& ctx, void* self);
  };
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
