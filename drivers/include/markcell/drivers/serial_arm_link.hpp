#pragma once
// The arm link over a serial line (protocol: serial_protocol.hpp). One command is in
// flight at a time: a new set-point replaces an unacknowledged one (set-points are
// states, the newest is the one that matters); an unacknowledged command is resent
// after ack_timeout, up to `retries` times, then the link reports kNoAck. The arm's
// periodic STATE frame is its heartbeat.
#include <array>
#include <string>

#include "markcell/drivers/arm.hpp"
#include "markcell/drivers/serial_port.hpp"
#include "markcell/drivers/serial_protocol.hpp"

namespace markcell::drivers {

struct SerialArmLinkConfig {
  std::string device;
  int baud = 115200;
  Nanos ack_timeout = millis(20);
  int retries = 3;
  Nanos heartbeat_timeout = millis(150);
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
