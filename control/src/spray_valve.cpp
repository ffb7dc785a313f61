#include "markcell/control/spray_valve.hpp"

namespace markcell::control {

PulseRequest SprayValve::request(Nanos start, Nanos length, bool safe_stopped) noexcept {
  if (safe_stopped) return PulseRequest::kSafeStopped;
  if (pending_ || open_) return PulseRequest::kBusy;
  if (length < min_ || length > max_) return PulseRequest::kBadLength;
  if (permit_ != nullptr && !*permit_) return PulseRequest::kNotPermitted;
  current_ = SprayPulse{start, length, -1, -1, false};
  pending_ = true;
  return PulseRequest::kAccepted;
}

void SprayValve::set(bool value) noexcept {
  if (lines_.set(line_, value) != drivers::GpioStatus::kOk) ++io_errors_;
  open_ = value;
}

void SprayValve::finish() noexcept {
  history_[static_cast<std::size_t>(count_++ % kHistory)] = current_;
  pending_ = false;
}

void SprayValve::cancel(Nanos now) noexcept {
  if (!open_ && !pending_) return;
  if (open_) {
    set(false);
    current_.closed = now;
  }
  current_.cut_short = true;
  finish();
}

TaskResult SprayValve::step(const TaskContext& ctx) noexcept {
  const Nanos now = ctx.now();
  if (permit_ != nullptr && !*permit_ && (open_ || pending_)) {
    cancel(now);  // no panel in front of the nozzle (or an e-stop): closed on this tick
    return io_errors_ > 0 ? TaskResult::kFault : TaskResult::kOk;
  }
  if (ctx.safe_stopped()) {
    // The safe stop has already driven the line; keep the books straight.
    if (open_ || pending_) {
      if (open_) current_.closed = now;
      current_.cut_short = true;
      open_ = false;
      finish();
    }
    return TaskResult::kOk;
  }
  if (pending_ && !open_ && now >= current_.requested_start) {
    set(true);
    current_.opened = now;
  }
  // The length is guaranteed from the moment the valve really opened: a late tick
  // shifts the pulse, it does not shorten it (the paint laid down depends on it).
  if (open_ && now >= current_.opened + current_.requested_length) {
    set(false);
    current_.closed = now;
    finish();
  }
  return io_errors_ > 0 ? TaskResult::kFault : TaskResult::kOk;
}

}  // namespace markcell::control
