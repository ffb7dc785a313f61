#pragma once
// The cell's digital lines by role: the valve and camera trigger it drives, the PLC's
// inputs it reads and the PLC outputs it answers on. The order is the configuration's
// (devices.gpio.lines) and the simulated chip's line numbers.
#include <cstddef>
#include <cstdint>
#include <string_view>

namespace markcell::control {

enum class LineRole : std::uint8_t {
  kSprayValve, kCameraTrigger,                              // outputs to the cell
  kPlcPanelPresent, kPlcCycleEnable, kPlcEstop,             // inputs from the PLC
  kPlcReady, kPlcBusy, kPlcDone, kPlcFault,                 // outputs to the PLC
};
inline constexpr std::size_t kLineRoleCount = 9;
// The role's name in the configuration (spray_valve, plc_estop, ...).
std::string_view to_string(LineRole role);
bool is_output(LineRole role);

}  // namespace markcell::control
