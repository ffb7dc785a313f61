#pragma once
// The PLC handshake lines and the cell's safe outputs on GPIO.
//
// PlcIo runs as the `plc_io` task on the control lane: it reads the PLC inputs (edges
// with their kernel timestamps, then levels), turns an e-stop into a safe stop, re-arms
// the cell after an e-stop when the PLC asks for it, and drives the PLC outputs: ready
// while the cycle is enabled and no safe stop is active; fault while a safe stop is.
// (Busy and done belong to the marking sequence.)
//
// Input filter (docs/safety.md): panel present and cycle enable are debounced on their
// edges' timestamps, not on the levels the task happens to sample, so nothing aliases
// with the task's period: a level becomes the filtered value once it has lasted
// `filter` without an edge, whenever that was; a pulse shorter than the filter is a
// glitch (ignored, counted); a drop at least as long always counts, even one that ended
// between two runs of the task (panel_present_drops counts every filtered fall).
// The valve's interlock (spray_permitted) is asymmetric: it permits only once panel
// present has been high without an edge for the filter, and any fall, glitch or not,
// withdraws it on the same tick. The e-stop is edge-latched and not filtered: a pulse of
// any length stops the cell.
#include <array>
#include <cstdint>

#include "markcell/control/executive.hpp"
#include "markcell/control/faults.hpp"
#include "markcell/drivers/gpio.hpp"

namespace markcell::control {

// Indices of the PLC lines in the GpioLines request; -1: not wired.
struct PlcLineMap {
  int panel_present = -1;
  int cycle_enable = -1;
  int estop = -1;
  int ready = -1;
  int busy = -1;
  int done = -1;
  int fault = -1;
};

// One input debounced on its edges' times (see the header comment).
class InputFilter {
 public:
  explicit InputFilter(Nanos filter = 0) : filter_(filter) {}
  void start(bool level, Nanos now) noexcept;
  // An edge to `level` at `time` (kernel time stamp; clamped into [last edge, now]).
  void edge(bool level, Nanos time, Nanos now) noexcept;
  // After the step's edges: the line's level read now (a level that disagrees with the
  // edges, an edge lost to an overflowing queue, counts as an edge now).
  void settle(bool level, Nanos now) noexcept;
  bool value() const { return value_; }
  bool raw() const { return raw_; }
  // High, and not one edge for at least the filter up to `now`: slow to permit, quick
  // to forbid (the valve's interlock).
  bool steady_high(Nanos now) const { return raw_ && now - raw_since_ >= filter_; }
  Nanos value_since() const { return value_since_; }  // when the filtered value's level began
  std::uint64_t falls() const { return falls_; }
  std::uint64_t rises() const { return rises_; }
  std::uint64_t glitches() const { return glitches_; }

 private:
  void take(bool level, Nanos began) noexcept;
  Nanos filter_;
  bool raw_ = false, value_ = false;
  Nanos raw_since_ = 0, value_since_ = 0;
  std::uint64_t falls_ = 0, rises_ = 0, glitches_ = 0;
};

struct PlcInputs {
  bool panel_present = false;  // filtered
  bool cycle_enable = false;   // filtered
  bool estop = false;          // active at any moment since the last step (edge-latched)
  Nanos panel_present_since = 0;  // when the filtered panel-present's high level began
  // The valve's interlock: panel present high without an edge for at least the filter,
  // and no e-stop. A glitch withdraws it at once (and for the filter after).
  bool spray_permitted = false;
  std::uint64_t panel_present_drops = 0;  // filtered falls since start
  std::uint64_t glitches = 0;             // pulses shorter than the filter, both inputs
};

// What re-arms the cell after a safe stop the PLC caused (the e-stop): `kCycleEnable`,
// the e-stop released, then a rising edge of cycle enable (the PLC's reset); `kNever`,
// only a restart of the service. Faults of the cell itself never re-arm: the service
// exits non-zero and systemd restarts it.
enum class RearmPolicy : std::uint8_t { kCycleEnable, kNever };

class PlcIo {
 public:
  PlcIo(drivers::GpioLines& lines, PlcLineMap map, SafeStop& safe_stop, Nanos input_filter = millis(3),
        RearmPolicy rearm = RearmPolicy::kCycleEnable)
      : lines_(lines), map_(map), safe_stop_(safe_stop), panel_(input_filter), cycle_(input_filter), rearm_(rearm) {}
  TaskResult step(const TaskContext& ctx) noexcept;
  static TaskResult task(TaskContext& ctx, void* self) { return static_cast<PlcIo*>(self)->step(ctx); }
  const PlcInputs& inputs() const { return inputs_; }
  std::uint64_t io_errors() const { return io_errors_; }

 private:
  void rearm_if_asked() noexcept;
  drivers::GpioLines& lines_;
  PlcLineMap map_;
  SafeStop& safe_stop_;
  InputFilter panel_, cycle_;
  RearmPolicy rearm_;
  bool started_ = false;
  PlcInputs inputs_;
  std::array<drivers::LineEvent, 32> events_{};
  std::uint64_t io_errors_ = 0;
  // Re-arm: the stop (SafeStop::stops()) this task last saw, whether the e-stop has been
  // released since it, and the cycle-enable rises counted at the release.
  std::uint64_t stop_seen_ = 0;
  bool estop_released_ = false;
  std::uint64_t rises_at_release_ = 0;
  Nanos glitch_report_at_ = -seconds(1);  // the first glitch is reported at once
  std::uint64_t glitches_reported_ = 0;
};

// The cell's GPIO outputs as a SafeOutput: every output to its safe state (valve
// closed, trigger low, ready/busy/done off), then the PLC fault line raised if asked.
class GpioSafeOutputs final : public SafeOutput {
 public:
  GpioSafeOutputs(drivers::GpioLines& lines, int fault_line) : lines_(lines), fault_line_(fault_line) {}
  std::string_view name() const override { return "gpio"; }
  void enter_safe_state() noexcept override {
    lines_.outputs_to_safe_state();
    if (fault_line_ >= 0) lines_.set(fault_line_, true);
  }

 private:
  drivers::GpioLines& lines_;
  int fault_line_;
};

}  // namespace markcell::control
