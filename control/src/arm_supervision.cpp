#include "markcell/control/arm_supervision.hpp"

namespace markcell::control {

TaskResult ArmSupervision::step(const TaskContext& ctx) noexcept {
  const Nanos now = ctx.now();
  status_ = link_.poll(now);
  if (drivers::is_fault(status_) && !safe_stop_.active()) {
    FixedString<119> detail;
    detail.format("arm link %s (arm fault code %u)", drivers::to_string(status_).data(),
                  static_cast<unsigned>(link_.state().fault_code));
    safe_stop_.trigger(now, FaultCode::kDeviceFault, "arm", detail.view());
  }
  if (safe_stop_.active() && !stop_sent_) {
    drivers::ArmCommand command;
    command.mode = home_on_stop_ ? drivers::ArmMode::kHome : drivers::ArmMode::kHold;
    command.target = link_.state().tool;
    command.time = now;
    link_.send(command, now);
    stop_sent_ = true;
  }
  return TaskResult::kOk;
}

}  // namespace markcell::control
