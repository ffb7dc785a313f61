#include "markcell/sim/command_log.hpp"

#include <cstdio>

namespace markcell::sim {

std::string CommandLog::text(Nanos epoch) const {
  std::string out;
  char line[200];
  for (const auto& e : entries_) {
    const Nanos t = e.time - epoch;  // before the epoch: a frame sent while the cell started
    const Nanos a = t < 0 ? -t : t;
    const long long s = a / kNanosPerSecond, ns = a % kNanosPerSecond;
    const char* sign = t < 0 ? "-" : "";
    if (e.kind == Kind::kValveOpen || e.kind == Kind::kValveClose) {
      std::snprintf(line, sizeof line, "(%s%lld.%09lld) valve %s\n", sign, s, ns, e.kind == Kind::kValveOpen ? "open" : "close");
      out += line;
      continue;
    }
    const unsigned id = static_cast<unsigned>(e.frame.id);
    int n = e.kind == Kind::kSerial
                ? std::snprintf(line, sizeof line, "(%s%lld.%09lld) serial %02X#%02X#", sign, s, ns, id >> 8, id & 0xFFu)
                : std::snprintf(line, sizeof line, "(%s%lld.%09lld) can %03X#%s", sign, s, ns, id, e.frame.fd ? "#0" : "");
    for (std::size_t i = 0; i < e.frame.len && n < 190; ++i)
      n += std::snprintf(line + n, sizeof line - static_cast<std::size_t>(n), "%02X", e.frame.data[i]);
    out += line;
    out += '\n';
  }
  if (dropped_ > 0) out += "# " + std::to_string(dropped_) + " entries not kept: the log was full\n";
  return out;
}

}  // namespace markcell::sim
