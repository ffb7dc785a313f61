#pragma once
// The PLC handshake lines and the cell's safe outputs on GPIO.
//
// PlcIo runs as the `plc_io` task on the control lane: it reads the PLC inputs (edges
// with their timestamps, then levels), turns an e-stop into a safe stop, and drives the
// PLC outputs: ready while the cycle is enabled and no safe stop is active; fault from
// the first safe stop on. (Busy and done belong to the marking sequence.)
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

struct PlcInputs {
  bool panel_present = false;
  bool cycle_enable = false;
  bool estop = false;
  Nanos panel_present_since = 0;  // timestamp of the last rising edge
};

class PlcIo {
 public:
  PlcIo(drivers::GpioLines& lines, PlcLineMap map, SafeStop& safe_stop) : lines_(lines), map_(map), safe_stop_(safe_stop) {}
  TaskResult step(const TaskContext& ctx) noexcept;
  static TaskResult task(TaskContext& ctx, void* self) { return static_cast<PlcIo*>(self)->step(ctx); }
  const PlcInputs& inputs() const { return inputs_; }
  std::uint64_t io_errors() const { return io_errors_; }

 private:
  drivers::GpioLines& lines_;
  PlcLineMap map_;
  SafeStop& safe_stop_;
  PlcInputs inputs_;
  std::array<drivers::LineEvent, 32> events_{};
  std::uint64_t io_errors_ = 0;
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
