#include "markcell/control/faults.hpp"

#include "markcell/common/check.hpp"

namespace markcell::control {

std::string_view to_string(FaultCode code) {
  switch (code) {
    case FaultCode::kNone: return "none";
    case FaultCode::kTaskOverrun: return "task_overrun";
    case FaultCode::kTaskFault: return "task_fault";
    case FaultCode::kLaneStall: return "lane_stall";
    case FaultCode::kDeviceFault: return "device_fault";
    case FaultCode::kOperatorStop: return "operator_stop";
    case FaultCode::kShutdown: return "shutdown";
    case FaultCode::kFrameDropped: return "frame_dropped";
    case FaultCode::kInputGlitch: return "input_glitch";
    case FaultCode::kRearm: return "rearm";
  }
  return "unknown";
}

FaultLog::FaultLog() {
  for (std::size_t i = 0; i < kCapacity; ++i) cells_[i].sequence.store(i, std::memory_order_relaxed);
}

bool FaultLog::push(const Fault& fault) noexcept {
  std::size_t pos = enqueue_.load(std::memory_order_relaxed);
  for (std::size_t attempt = 0; attempt < kCapacity * 4; ++attempt) {
    Cell& cell = cells_[pos & (kCapacity - 1)];
    const std::size_t seq = cell.sequence.load(std::memory_order_acquire);
    const auto diff = static_cast<std::ptrdiff_t>(seq) - static_cast<std::ptrdiff_t>(pos);
    if (diff == 0) {
      if (enqueue_.compare_exchange_weak(pos, pos + 1, std::memory_order_relaxed)) {
        cell.fault = fault;
        cell.sequence.store(pos + 1, std::memory_order_release);
        recorded_.fetch_add(1, std::memory_order_relaxed);
        return true;
      }
    } else if (diff < 0) {
      break;  // full
    } else {
      pos = enqueue_.load(std::memory_order_relaxed);
    }
  }
  dropped_.fetch_add(1, std::memory_order_relaxed);
  return false;
}

bool FaultLog::pop(Fault& out) noexcept {
  const std::size_t pos = dequeue_.load(std::memory_order_relaxed);
  Cell& cell = cells_[pos & (kCapacity - 1)];
  const std::size_t seq = cell.sequence.load(std::memory_order_acquire);
  if (static_cast<std::ptrdiff_t>(seq) - static_cast<std::ptrdiff_t>(pos + 1) < 0) return false;
  out = cell.fault;
  cell.sequence.store(pos + kCapacity, std::memory_order_release);
  dequeue_.store(pos + 1, std::memory_order_relaxed);
  return true;
}

void SafeStop::add_output(SafeOutput& output) {
  MARKCELL_THROW_UNLESS(output_count_ < kMaxOutputs, "outputs=" << output_count_);
  MARKCELL_THROW_UNLESS(!active(), "cannot add output '" << output.name() << "' after a safe stop");
  outputs_[static_cast<std::size_t>(output_count_++)] = &output;
}

bool SafeStop::trigger(Nanos time, FaultCode code, std::string_view source,
                       std::string_view detail) noexcept {
  Fault fault;
  fault.time = time;
  fault.code = code;
  fault.source.assign(source);
  fault.detail.assign(detail);
  log_.push(fault);
  if (code != FaultCode::kOperatorStop && code != FaultCode::kShutdown) unrecoverable_.store(true, std::memory_order_release);
  int expected = kIdle;
  if (!state_.compare_exchange_strong(expected, kStopping, std::memory_order_acq_rel)) return false;
  reason_ = fault;
  for (int i = 0; i < output_count_; ++i) outputs_[static_cast<std::size_t>(i)]->enter_safe_state();
  stops_.fetch_add(1, std::memory_order_acq_rel);
  state_.store(kStopped, std::memory_order_release);
  return true;
}

void SafeStop::log_rearm(Nanos time, std::string_view detail) noexcept {
  Fault fault;
  fault.time = time;
  fault.code = FaultCode::kRearm;
  fault.source.assign("safe_stop");
  fault.detail.assign(detail);
  log_.push(fault);
}

void SafeStop::cancel_rearm(Nanos time, std::string_view detail) noexcept {
  if (rearm_requested_.exchange(false, std::memory_order_acq_rel)) log_rearm(time, detail);
}

bool SafeStop::rearm(Nanos time, std::string_view detail) noexcept {
  rearm_requested_.store(false, std::memory_order_release);
  if (!recoverable()) return false;
  int expected = kStopped;
  if (!state_.compare_exchange_strong(expected, kIdle, std::memory_order_acq_rel)) return false;
  log_rearm(time, detail);
  return true;
}

}  // namespace markcell::control
