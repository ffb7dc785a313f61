#pragma once
// The rig's command log: every frame the controller sends to the arm and every valve
// opening and closing, with their times, one candump -L style line each:
//   (S.NNNNNNNNN) can 202#88130000...        a CAN frame: id#data (id##0data for CAN FD)
//   (S.NNNNNNNNN) serial 01#05#02A0...       a serial frame: type#seq#payload (serial_protocol.hpp)
//   (S.NNNNNNNNN) valve open | valve close
// The simulated world keeps it in simulated time (the same recording and configuration
// give the same log, byte for byte); the real-device replay's peer keeps it on the real
// clock.
//
// Storage for a fixed number of entries is taken once (reserve); a full log counts what it
// could not keep, so recording an entry never allocates. A log never reserved keeps
// nothing and says nothing.
#include <algorithm>
#include <cstdint>
#include <string>
#include <vector>

#include "markcell/common/time.hpp"
#include "markcell/drivers/can_bus.hpp"
#include "markcell/drivers/serial_protocol.hpp"

namespace markcell::sim {

class CommandLog {
 public:
  void reserve(std::size_t capacity) { entries_.reserve(capacity); }
  bool enabled() const { return entries_.capacity() > 0; }
  void frame(Nanos time, const drivers::CanFrame& frame) noexcept { record({time, Kind::kCan, frame}); }
  void frame(Nanos time, const drivers::serial::Frame& frame) noexcept {
    drivers::CanFrame bytes;  // the payload (at most 64 bytes, as a CAN FD frame's), type and seq in the id
    bytes.id = static_cast<std::uint32_t>(frame.type) << 8 | frame.seq;
    bytes.len = frame.length;
    std::copy_n(frame.payload.begin(), frame.length, bytes.data.begin());
    record({time, Kind::kSerial, bytes});
  }
  void valve(Nanos time, bool open) noexcept { record({time, open ? Kind::kValveOpen : Kind::kValveClose, {}}); }
  // One line per entry, times from `epoch`; a last comment line when entries were lost.
  std::string text(Nanos epoch = 0) const;

 private:
  enum class Kind : std::uint8_t { kCan, kSerial, kValveOpen, kValveClose };
  struct Entry {
    Nanos time = 0;
    Kind kind = Kind::kCan;
    drivers::CanFrame frame;
  };
  void record(const Entry& e) noexcept {
    if (entries_.size() < entries_.capacity()) entries_.push_back(e);
    else if (enabled()) ++dropped_;
  }
  std::vector<Entry> entries_;
  std::uint64_t dropped_ = 0;
};

}  // namespace markcell::sim
