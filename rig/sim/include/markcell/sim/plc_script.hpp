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
#include <algorithm>
#include <functional>
#include <string>
#include <vector>

#include "markcell/common/time.hpp"
#include "markcell/control/line_role.hpp"

namespace markcell::sim {

using control::LineRole;

struct PlcEvent {
  Nanos at = 0;  // from the cell's start
  LineRole line = LineRole::kPlcPanelPresent;
  bool level = false;  // logical
};

// Throws std::runtime_error "FILE:LINE: what is wrong".
std::vector<PlcEvent> load_plc_script(const std::string& path);

// A loaded script played against a clock: `run` and the rig (`sim`, `replay`) step their
// time to each event and apply it.
class PlcScript {
 public:
  PlcScript() = default;
  explicit PlcScript(std::vector<PlcEvent> events) : events_(std::move(events)) {}
  // Every event due by `elapsed` (from the start) not applied yet, in order.
  void apply_due(Nanos elapsed, const std::function<void(const PlcEvent&)>& apply) {
    for (; next_ < events_.size() && events_[next_].at <= elapsed; ++next_) apply(events_[next_]);
  }
  // From `elapsed` to the next event (0 if it is due; `none` when none is left).
  Nanos until_next(Nanos elapsed, Nanos none) const {
    return next_ < events_.size() ? std::max<Nanos>(0, events_[next_].at - elapsed) : none;
  }

 private:
  std::vector<PlcEvent> events_;
  std::size_t next_ = 0;
};

}  // namespace markcell::sim
