#pragma once
// The arm link over a serial line (protocol: serial_protocol.hpp). One command is in
// flight at a time: a new set-point replaces an unacknowledged one (set-points are
// states, the newest is the one that matters); an unacknowledged command is resent
// after ack_timeout, up to `retries` times, then the link reports kNoAck. The arm's
// periodic STATE frame is its heartbeat.
#include <algorithm>
#include <array>
#include <string>

#include "markcell/common/param.hpp"

#include "markcell/drivers/arm.hpp"
#include "markcell/drivers/serial_port.hpp"
#include "markcell/drivers/serial_protocol.hpp"

namespace markcell::drivers {

// `devices.arm.serial`: declared here, once.
struct SerialArmLinkConfig {
  std::string device;
  int baud = 115200;
  Nanos ack_timeout = millis(20);
  int retries = 3;
  Nanos state_timeout = millis(150);  // the arm's STATE (its heartbeat) silent this long: link lost

  // The rates termios has a constant for (serial_port.cpp).
  static constexpr std::array<int, 10> kBauds = {9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 921600, 1000000};

  template <class V>
  void Visit(V& v) {
    v(Param{"device", Unit::kNone, 1, 255, "the serial line's device", true}, device);
    v(Param{"baud", Unit::kNone, 1, 4'000'000, "a termios rate", true}, baud);
    v(Param{"ack_timeout_ms", Unit::kMillisecond, 1, 10'000, "an unacknowledged command is resent after this", true},
      ack_timeout);
    v(Param{"retries", Unit::kNone, 0, 100, "resends before the link reports no acknowledgement", true}, retries);
    v(Param{"state_timeout_ms", Unit::kMillisecond, 1, 65'535, "the arm's STATE frames silent this long: link lost"},
      state_timeout);
  }
  template <class Report>
  void validate(Report&& report) const {
    if (std::find(kBauds.begin(), kBauds.end(), baud) == kBauds.end())
      report("baud", "baud " + std::to_string(baud) +
                         " is not a termios rate (9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 921600, 1000000)");
  }
};

class SerialArmLink final : public ArmLink {
 public:
  explicit SerialArmLink(SerialArmLinkConfig config) : config_(std::move(config)) {}
  void activate(Nanos now) override;
  void deactivate() noexcept override;
  std::uint8_t send(const ArmCommand& command, Nanos now) noexcept override;
  ArmLinkStatus poll(Nanos now) noexcept override;
  const ArmState& state() const override { return state_; }
  ArmLinkStatus status() const override { return status_; }
  const ArmLinkCounters& counters() const override { return counters_; }
  const serial::Decoder& decoder() const { return decoder_; }

 private:
  bool write_all(std::span<const std::uint8_t> bytes) noexcept;
  SerialArmLinkConfig config_;
  SerialPort port_;
  serial::Decoder decoder_;
  ArmState state_;
  ArmLinkStatus status_ = ArmLinkStatus::kInactive;
  ArmLinkCounters counters_;
  std::uint8_t next_seq_ = 0;
  struct Pending {
    bool active = false;
    std::uint8_t seq = 0;
    std::array<std::uint8_t, serial::kMaxFrame> frame{};
    std::size_t size = 0;
    Nanos sent_at = 0;
    int tries = 0;
  } pending_;
  SilenceTimer state_silence_;
  bool have_state_ = false;
  bool refused_ = false;
  bool no_ack_ = false;
  bool io_error_ = false;
};

}  // namespace markcell::drivers
