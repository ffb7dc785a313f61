#pragma once
// The spray valve, timed by the executive: a pulse is requested for a start time and a
// length, and the `spray_valve` task (control lane, every tick) opens the valve at the
// first tick at or after the start and closes it at the first tick at least `length`
// after it opened. The timing resolution is one base tick, and a late tick delays a
// pulse without shortening it. A safe stop closes it at once and
// refuses new pulses. Every pulse is recorded with its requested and actual times.
//
// Interlocks (docs/safety.md): the valve is open only while its permit holds (the PLC's
// panel present, unfiltered: PlcInputs::spray_permitted) and nobody cancelled the pulse
// (the marking sequence does when its panel fails). Either closes it at its next run,
// within one control tick, and the pulse is recorded as cut short.
#include <array>
#include <cstdint>

#include "markcell/control/executive.hpp"
#include "markcell/drivers/gpio.hpp"

namespace markcell::control {

struct SprayPulse {
  Nanos requested_start = 0;
  Nanos requested_length = 0;
  Nanos opened = -1;  // -1: not (yet) opened
  Nanos closed = -1;
  bool cut_short = false;  // closed early (safe stop, panel present dropped, cancelled) or never opened
};

enum class PulseRequest : std::uint8_t { kAccepted, kBusy, kBadLength, kSafeStopped, kNotPermitted };

class SprayValve {
 public:
  static constexpr std::size_t kHistory = 256;
  SprayValve(drivers::GpioLines& lines, int line, Nanos min_length, Nanos max_length)
      : lines_(lines), line_(line), min_(min_length), max_(max_length) {}
  // From any task on the control lane (not thread-safe across lanes by design: the
  // marking sequence that asks for pulses runs on the same lane).
  PulseRequest request(Nanos start, Nanos length, bool safe_stopped) noexcept;
  // The permit read at every run (before start(): the PLC's spray_permitted); null: none.
  void set_permit(const bool* permit) { permit_ = permit; }
  // Closes the valve now and drops a pending pulse (recorded as cut short).
  void cancel(Nanos now) noexcept;
  TaskResult step(const TaskContext& ctx) noexcept;
  static TaskResult task(TaskContext& ctx, void* self) { return static_cast<SprayValve*>(self)->step(ctx); }
  bool open() const { return open_; }
  // Pulses finished so far, numbered from 0; the newest kHistory are kept (a ring: a
  // cell sprays for years), so pulse(i) is valid for pulse_count() - kHistory <= i <
  // pulse_count().
  std::uint64_t pulse_count() const { return count_; }
  const SprayPulse& pulse(std::uint64_t i) const { return history_[static_cast<std::size_t>(i % kHistory)]; }
  std::uint64_t io_errors() const { return io_errors_; }

 private:
  void set(bool open) noexcept;
  void finish() noexcept;
  drivers::GpioLines& lines_;
  int line_;
  Nanos min_, max_;
  const bool* permit_ = nullptr;
  bool pending_ = false;
  bool open_ = false;
  std::array<SprayPulse, kHistory> history_{};
  std::uint64_t count_ = 0;
  std::uint64_t io_errors_ = 0;
  SprayPulse current_;
};

}  // namespace markcell::control
