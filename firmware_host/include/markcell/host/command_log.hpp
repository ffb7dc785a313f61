#pragma once
// The rig's command log: every CAN frame the controller sends to the arm and every valve
// opening and closing, with their times, one candump -L style line each. The simulated
// world keeps it in simulated time (the same recording and configuration give the same
// log, byte for byte); the real-device replay's peer keeps it on the real clock.
//
// Storage for a fixed number of entries is taken once (reserve); a full log counts what it
// could not keep, so recording an entry never allocates. A log never reserved keeps
// nothing and says nothing.
#include <cstdint>
#include <string>
#include <vector>

#include "markcell/common/time.hpp"
#include "markcell/drivers/can_bus.hpp"

namespace markcell::host {

class CommandLog {
 public:
  void reserve(std::size_t capacity) { entries_.reserve(capacity); }
  bool enabled() const { return entries_.capacity() > 0; }
  void frame(Nanos time, const drivers::CanFrame& frame) noexcept { record({time, -1, frame}); }
  void valve(Nanos time, bool open) noexcept { record({time, static_cast<std::int8_t>(open ? 1 : 0), {}}); }
  // One line per entry, times from `epoch`; a last comment line when entries were lost.
  std::string text(Nanos epoch = 0) const;

 private:
  struct Entry {
    Nanos time = 0;
    std::int8_t valve = -1;  // -1: a CAN frame; 0 closed, 1 opened
    drivers::CanFrame frame;
  };
  void record(const Entry& e) noexcept {
    if (entries_.size() < entries_.capacity()) entries_.push_back(e);
    else if (enabled()) ++dropped_;
  }
  std::vector<Entry> entries_;
  std::uint64_t dropped_ = 0;
};

}  // namespace markcell::host
