#include "markcell/sim/plc_script.hpp"

#include <cmath>
#include <sstream>
#include <stdexcept>

#include "markcell/common/bounded_file.hpp"

namespace markcell::sim {

std::vector<PlcEvent> load_plc_script(const std::string& path) {
  std::istringstream in(read_bounded_file(path, 1 << 20, "a PLC script"));
  std::vector<PlcEvent> events;
  std::string text;
  for (int number = 1; std::getline(in, text); ++number) {
    const auto fail = [&](const std::string& what) {
      throw std::runtime_error(path + ":" + std::to_string(number) + ": " + what);
    };
    if (const auto hash = text.find('#'); hash != std::string::npos) text.erase(hash);
    std::istringstream fields(text);
    std::string at_text, name, level_text, extra;
    if (!(fields >> at_text)) continue;  // blank or comment
    if (!(fields >> name >> level_text)) fail("expected 'SECONDS LINE LEVEL', got '" + text + "'");
    if (fields >> extra) fail("unexpected '" + extra + "' after the level");
    std::size_t used = 0;
    double at = -1;
    try {
      at = std::stod(at_text, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used != at_text.size() || !std::isfinite(at) || at < 0)
      fail("time '" + at_text + "' is not a number of seconds >= 0");
    // (1e10 s overflowed the nanosecond clock and fired at once.)
    if (at > 1e6) fail("time " + at_text + " s is past the longest script (1e6 s, 11.6 days)");
    PlcEvent ev;
    ev.at = static_cast<Nanos>(std::llround(at * 1e9));
    if (!events.empty() && ev.at < events.back().at)
      fail("time " + at_text + " s is before the previous event's; events go in time order");
    bool known = false;
    for (const LineRole role : {LineRole::kPlcPanelPresent, LineRole::kPlcCycleEnable, LineRole::kPlcEstop}) {
      if (name == to_string(role)) ev.line = role, known = true;
    }
    if (!known) fail("line '" + name + "' is not a PLC input; use plc_panel_present, plc_cycle_enable or plc_estop");
    if (level_text != "0" && level_text != "1") fail("level '" + level_text + "' must be 0 or 1");
    ev.level = level_text == "1";
    events.push_back(ev);
  }
  return events;
}

}  // namespace markcell::sim
