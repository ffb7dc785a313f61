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
  if (!safe_stop_.rearm_requested()) {
    rearm_home_sent_ = false;
    return TaskResult::kOk;
  }
  if (!rearm_home_sent_) {
    drivers::ArmCommand home;
    home.mode = drivers::ArmMode::kHome;
    home.target = link_.state().tool;
    home.time = now;
    link_.send(home, now);
    rearm_home_sent_ = true;
    rearm_home_at_ = now;
    return TaskResult::kOk;
  }
  const drivers::ArmState& s = link_.state();
  if ((s.flags & drivers::kHomed) != 0 && s.received > rearm_home_at_ && !drivers::is_fault(status_)) {
    if (safe_stop_.rearm(now, "e-stop released, reset by cycle enable, arm at home")) stop_sent_ = false;
    rearm_home_sent_ = false;
  } else if (now - rearm_home_at_ > rearm_timeout_) {
    FixedString<119> detail;
    detail.format("re-arm refused: the arm did not report home within %lld ms", static_cast<long long>(rearm_timeout_ / kNanosPerMilli));
    safe_stop_.cancel_rearm(now, detail.view());
    rearm_home_sent_ = false;
  }
  return TaskResult::kOk;
}

}  // namespace markcell::control
