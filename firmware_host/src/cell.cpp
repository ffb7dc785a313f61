#include "markcell/host/cell.hpp"

#include <stdexcept>

#include "markcell/drivers/gpiod_lines.hpp"

namespace markcell::host {

const std::vector<std::string>& task_catalog() {
  static const std::vector<std::string> kTasks = {
      "plc_io",  // PLC handshake lines, e-stop -> safe stop (control lane)
  };
  return kTasks;
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
    gpio_ = std::move(gpio);
  } else {
    gpio_ = std::make_unique<drivers::GpiodLines>(config.gpio.chip);
  }
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
  plc_io_ = std::make_unique<control::PlcIo>(*gpio_, map, safe_stop_);

  executive_ = std::make_unique<control::Executive>(config.executive, *clock_, safe_stop_);
  for (const auto& task : config.executive.tasks) {
    if (task.name == "plc_io") executive_->bind(task.name, &control::PlcIo::task, plc_io_.get());
    else throw std::logic_error("task '" + task.name + "' passed validation but has no binding");
  }
  if (config.watchdog.systemd) executive_->add_watchdog(notifier_);
  if (config.watchdog.device) {
    watchdog_device_ = std::make_unique<drivers::WatchdogDevice>(
        drivers::WatchdogDeviceConfig{config.watchdog.device_path, config.watchdog.device_timeout_s});
    watchdog_device_sink_ = std::make_unique<DeviceWatchdogSink>(*watchdog_device_);
    executive_->add_watchdog(*watchdog_device_sink_);
  }
}

Cell::~Cell() {
  if (started_ && !shut_down_) shutdown(control::FaultCode::kShutdown, "cell", "destroyed without shutdown");
}

void Cell::start() {
  gpio_->activate();
  if (sim_gpio_ != nullptr) {
    // The simulated PLC enables the cycle and keeps the e-stop released, as a line does
    // when it runs; scenarios script the rest.
    const int enable = gpio_line(LineRole::kPlcCycleEnable);
    const int estop = gpio_line(LineRole::kPlcEstop);
    sim_gpio_->drive_physical(enable, !config_.gpio.lines[static_cast<std::size_t>(enable)].active_low);
    sim_gpio_->drive_physical(estop, config_.gpio.lines[static_cast<std::size_t>(estop)].active_low);
  }
  if (watchdog_device_) watchdog_device_->activate();
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
