#pragma once
// The arm link inside the executive: the `arm_link` task polls the link every tick,
// turns a link fault (heartbeat lost, no acknowledgement, bus-off, arm fault, I/O error)
// into the safe stop, and on every safe stop holds the arm (or sends it home) once.
//
// The hold is sent by this task, on the control lane, at its next tick after the stop:
// the link has one owner and is never written from two lanes. Should the control lane
// itself be the one that stalled, the arm's own supervision of markcell's heartbeat
// (CANopen heartbeat consumer) holds it.
#include "markcell/control/executive.hpp"
#include "markcell/control/faults.hpp"
#include "markcell/drivers/arm.hpp"

namespace markcell::control {

class ArmSupervision {
 public:
  ArmSupervision(drivers::ArmLink& link, SafeStop& safe_stop, bool home_on_stop)
      : link_(link), safe_stop_(safe_stop), home_on_stop_(home_on_stop) {}
  TaskResult step(const TaskContext& ctx) noexcept;
  static TaskResult task(TaskContext& ctx, void* self) { return static_cast<ArmSupervision*>(self)->step(ctx); }
  drivers::ArmLinkStatus status() const { return status_; }

 private:
  drivers::ArmLink& link_;
  SafeStop& safe_stop_;
  bool home_on_stop_;
  bool stop_sent_ = false;
  drivers::ArmLinkStatus status_ = drivers::ArmLinkStatus::kInactive;
};

}  // namespace markcell::control
