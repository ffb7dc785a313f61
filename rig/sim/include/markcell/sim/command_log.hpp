#pragma once
// The rig's command log: every frame the controller sends to the arm and every valve
// opening and closing, with their times, written as three files (docs/rig.md, "The
// command logs"):
//   can.log     candump -L, which can-utils' log2asc and python-can read:
//               (SECONDS.MICROS) IFACE 202#88130000...   (ID##FDATA for a CAN FD frame)
//   serial.log  the serial arm's frames: (SECONDS.MICROS) serial 01#05#02A0... (type#seq#payload)
//   valve.log   (SECONDS.MICROS) valve open | valve close
// Times are the run's own from its start (simulated time in the simulated world, the real
// clock in the real-device replay) on a fixed epoch, kEpochSeconds (2000-01-01 00:00:00
// UTC): the same recording and configuration give the same files, byte for byte, and a
// tool that prints dates prints that day.
//
// Storage for a fixed number of entries is taken once (reserve); a full log counts what it
// could not keep, so recording an entry never allocates. A log never reserved keeps
// nothing and says nothing.
#include <algorithm>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "markcell/common/time.hpp"
#include "markcell/drivers/can_bus.hpp"
#include "markcell/drivers/serial_protocol.hpp"

namespace markcell::sim {

struct CommandLogText {
  std::string can, serial, valve;
};

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
  // Simulated (or run) time 0 is written as this many seconds since 1970.
  static constexpr long long kEpochSeconds = 946684800;
  // The three files' text, times from `epoch` on kEpochSeconds, CAN frames on `interface`.
  // Entries lost to a full log are named on a last comment line of valve.log and of the
  // arm's file (candump -L readers skip lines that do not begin with a time).
  CommandLogText text(Nanos epoch, std::string_view interface) const;

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
