#pragma once
// The arm link inside the executive: the `arm_link` task polls the link every tick,
// turns a link fault (heartbeat lost, no acknowledgement, bus-off, arm fault, I/O error)
// into the safe stop, and on every safe stop holds the arm (or sends it home) once.
//
// The hold is sent by this task, on the control lane, at its next tick after the stop:
// the link has one owner and is never written from two lanes. Should the control lane
// itself be the one that stalled, the arm's own supervision of markcell's heartbeat
// (CANopen heartbeat consumer) holds it.
//
// Re-arm (SafeStop): asked for by the PLC, the task sends the arm home and re-arms the
// cell once the arm reports itself home in a state sent after the command; an arm not
// home within `rearm_timeout` leaves the cell stopped (the request is dropped with a
// fault-log entry; the PLC's next reset edge tries again).
#include "markcell/control/executive.hpp"
#include "markcell/control/faults.hpp"
#include "markcell/drivers/arm.hpp"

namespace markcell::control {

class ArmSupervision {
 public:
  ArmSupervision(drivers::ArmLink& link, SafeStop& safe_stop, bool home_on_stop, Nanos rearm_timeout = seconds(10))
      : link_(link), safe_stop_(safe_stop), home_on_stop_(home_on_stop), rearm_timeout_(rearm_timeout) {}
  TaskResult step(const TaskContext& ctx) noexcept;
  static TaskResult task(TaskContext& ctx, void* self) { return static_cast<ArmSupervision*>(self)->step(ctx); }
  drivers::ArmLinkStatus status() const { return status_; }

 private:
  drivers::ArmLink& link_;
  SafeStop& safe_stop_;
  bool home_on_stop_;
  Nanos rearm_timeout_;
  bool stop_sent_ = false;
  bool rearm_home_sent_ = false;
  Nanos rearm_home_at_ = 0;
  drivers::ArmLinkStatus status_ = drivers::ArmLinkStatus::kInactive;
};

}  // namespace markcell::control
