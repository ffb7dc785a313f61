#pragma once
// The cell's clock in UTC, for the lines people and plant systems read beside the cell's
// own seconds (the results file, the fault lines, the operator page; docs/operation.md
// "Time"). Nothing decides anything by it: the cell runs on CLOCK_MONOTONIC (or the
// simulated clock), which a wall-clock step cannot move.
#include <cstdint>
#include <string>

#include "markcell/common/file_history.hpp"
#include "markcell/common/time.hpp"

namespace markcell::host {

struct UtcClock {
  // Simulated: the simulated clock's 0 is 1970-01-01T00:00:00Z, so that a simulated run
  // writes the same bytes every time (and no one takes its times for the plant's).
  bool simulated = false;

  // UTC minus the cell's clock, in nanoseconds. Real: CLOCK_REALTIME's offset to
  // CLOCK_MONOTONIC read now (a line's times take one reading, so they keep their
  // monotonic differences even across a step of the wall clock).
  std::int64_t offset() const { return simulated ? 0 : realtime_now() - monotonic_now(); }
  // The cell-clock time `t` in UTC to the millisecond.
  std::string at(Nanos t) const { return utc_iso8601_ms(t + offset()); }
  static std::string at(Nanos t, std::int64_t offset) { return utc_iso8601_ms(t + offset); }
};

}  // namespace markcell::host
