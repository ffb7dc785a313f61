#pragma once
// A scripted PLC for `markcell run` on simulated GPIO: when the line brings a panel,
// enables the cycle, presses the e-stop. One event per line of a text file:
//
//   # seconds  line               level (logical: 1 = asserted, active_low applied)
//   1.0        plc_panel_present  1
//   40.0       plc_panel_present  0
//
// Times are seconds from the cell's start, not decreasing; lines are the PLC inputs by
// their config role (plc_panel_present, plc_cycle_enable, plc_estop); '#' starts a
// comment. A bad line is an error naming file, line and what is wrong.
#include <string>
#include <vector>

#include "markcell/common/time.hpp"
#include "markcell/host/config.hpp"

namespace markcell::host {

struct PlcEvent {
  Nanos at = 0;  // from the cell's start
  LineRole line = LineRole::kPlcPanelPresent;
  bool level = false;  // logical
};

// Throws std::runtime_error "FILE:LINE: what is wrong".
std::vector<PlcEvent> load_plc_script(const std::string& path);

}  // namespace markcell::host
