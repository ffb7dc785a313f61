#include "markcell/control/line_role.hpp"

#include <array>

namespace markcell::control {

std::string_view to_string(LineRole role) {
  static constexpr std::array<std::string_view, kLineRoleCount> kNames = {
      "spray_valve", "camera_trigger", "plc_panel_present", "plc_cycle_enable", "plc_estop",
      "plc_ready",   "plc_busy",       "plc_done",          "plc_fault"};
  return kNames[static_cast<std::size_t>(role)];
}

bool is_output(LineRole role) {
  return role != LineRole::kPlcPanelPresent && role != LineRole::kPlcCycleEnable && role != LineRole::kPlcEstop;
}

}  // namespace markcell::control
