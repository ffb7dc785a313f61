#include "markcell/sim/command_log.hpp"

#include <cstdio>

namespace markcell::sim {

CommandLogText CommandLog::text(Nanos epoch, std::string_view interface) const {
  CommandLogText out;
  const int iface_len = static_cast<int>(std::min<std::size_t>(interface.size(), 64));
  char line[220];
  for (const auto& e : entries_) {
    // A frame sent while the cell started can precede the epoch by a little: never by
    // the 30 years between 1970 and the log's epoch.
    const Nanos t = e.time - epoch + kEpochSeconds * kNanosPerSecond;
    const long long s = t / kNanosPerSecond, us = (t % kNanosPerSecond) / 1000;
    if (e.kind == Kind::kValveOpen || e.kind == Kind::kValveClose) {
      std::snprintf(line, sizeof line, "(%lld.%06lld) valve %s\n", s, us, e.kind == Kind::kValveOpen ? "open" : "close");
      out.valve += line;
      continue;
    }
    const unsigned id = static_cast<unsigned>(e.frame.id);
    const bool serial = e.kind == Kind::kSerial;
    int n = 0;
    if (serial)
      n = std::snprintf(line, sizeof line, "(%lld.%06lld) serial %02X#%02X#", s, us, id >> 8, id & 0xFFu);
    else  // candump: 3 hex digits for an 11-bit id, 8 for a 29-bit one; CAN FD: '##' and the flags nibble (0)
      n = std::snprintf(line, sizeof line, e.frame.extended ? "(%lld.%06lld) %.*s %08X#%s" : "(%lld.%06lld) %.*s %03X#%s", s, us,
                        iface_len, interface.data(), id, e.frame.fd ? "#0" : "");
    for (std::size_t i = 0; i < e.frame.len && n > 0 && n < 200; ++i)
      n += std::snprintf(line + n, sizeof line - static_cast<std::size_t>(n), "%02X", e.frame.data[i]);
    std::string& file = serial ? out.serial : out.can;
    file += line;
    file += '\n';
  }
  if (dropped_ > 0) {
    const std::string lost = "# " + std::to_string(dropped_) + " entries not kept: the log was full\n";
    (out.serial.empty() ? out.can : out.serial) += lost;
    out.valve += lost;
  }
  return out;
}

}  // namespace markcell::sim
