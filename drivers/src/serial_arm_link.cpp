#include "markcell/drivers/serial_arm_link.hpp"

namespace markcell::drivers {

void SerialArmLink::activate(Nanos now) {
  port_.open(config_.device, config_.baud);
  status_ = ArmLinkStatus::kConnecting;
  state_silence_.start(now);  // the heartbeat timeout runs from activation
  have_state_ = refused_ = no_ack_ = io_error_ = false;
  pending_.active = false;
}

void SerialArmLink::deactivate() noexcept {
  if (!port_.is_open()) return;
  ArmCommand hold;
  hold.mode = ArmMode::kHold;
  hold.target = state_.tool;
  send(hold, state_.received);  // best effort: the arm holds where it is
  port_.close();
  status_ = ArmLinkStatus::kInactive;
}

bool SerialArmLink::write_all(std::span<const std::uint8_t> bytes) noexcept {
  // A frame is at most 71 bytes: far below any tty buffer. A short write means the line
  // is wedged; that is an I/O error, not something to wait for on the real-time path.
  const long n = port_.write_some(bytes);
  if (n != static_cast<long>(bytes.size())) {
    io_error_ = true;
    return false;
  }
  return true;
}

std::uint8_t SerialArmLink::send(const ArmCommand& command, Nanos now) noexcept {
  const std::uint8_t seq = ++next_seq_;
  pending_.size = serial::encode_command(command, seq, pending_.frame);
  pending_.seq = seq;
  pending_.sent_at = now;
  pending_.tries = 1;
  pending_.active = true;
  ++counters_.commands_sent;
  write_all(std::span<const std::uint8_t>(pending_.frame.data(), pending_.size));
  return seq;
}

ArmLinkStatus SerialArmLink::poll(Nanos now) noexcept {
  if (!port_.is_open()) return status_ = ArmLinkStatus::kInactive;
  state_silence_.polled(now);
  std::array<std::uint8_t, 256> buf{};
  for (int reads = 0; reads < 8 && !io_error_; ++reads) {
    const long n = port_.read_some(buf, 0);
    if (n < 0) io_error_ = true;
    if (n <= 0) break;
    decoder_.consume(
        std::span<const std::uint8_t>(buf.data(), static_cast<std::size_t>(n)),
        [&](const serial::Frame& frame) {
          if (frame.type == serial::FrameType::kAck) {
            std::uint8_t acked = 0;
            serial::AckResult result{};
            if (serial::decode_ack(frame, acked, result) != serial::PayloadError::kOk) {
              ++counters_.decode_errors;
            } else if (pending_.active && acked == pending_.seq) {
              pending_.active = false;
              refused_ = result != serial::AckResult::kAccepted;
              if (refused_) ++counters_.refusals;
            }
          } else if (frame.type == serial::FrameType::kState) {
            Nanos arm_time = 0;
            if (serial::decode_state(frame, state_, arm_time) != serial::PayloadError::kOk) {
              ++counters_.decode_errors;
            } else {
              state_.received = now;
              state_silence_.heard(now);
              have_state_ = true;
              ++counters_.states_received;
            }
          } else {
            ++counters_.decode_errors;  // a COMMAND has no business arriving here
          }
        },
        [&] { ++counters_.decode_errors; });
  }
  if (pending_.active && now - pending_.sent_at > config_.ack_timeout) {
    if (pending_.tries > config_.retries) {
      no_ack_ = true;
      pending_.active = false;
    } else {
      ++pending_.tries;
      ++counters_.retries;
      pending_.sent_at = now;
      write_all(std::span<const std::uint8_t>(pending_.frame.data(), pending_.size));
    }
  }
  if (io_error_) status_ = ArmLinkStatus::kIoError;
  else if (no_ack_) status_ = ArmLinkStatus::kNoAck;
  else if (state_silence_.silent_for(now) > config_.state_timeout) status_ = ArmLinkStatus::kHeartbeatLost;
  else if (have_state_ && state_.fault()) status_ = ArmLinkStatus::kArmFault;
  else if (refused_) status_ = ArmLinkStatus::kRefused;
  else status_ = have_state_ ? ArmLinkStatus::kOk : ArmLinkStatus::kConnecting;
  return status_;
}

}  // namespace markcell::drivers
