#pragma once
// The arm's serial protocol: pure code, no I/O.
//
// Frame:  A5 5A | len | seq | type | payload[len] | crc16
//   len      payload length, 0..kMaxPayload
//   seq      sequence number (commands: chosen by the controller; acks echo it)
//   type     1 COMMAND (controller -> arm), 2 ACK (arm -> controller), 3 STATE (arm -> controller)
//   crc16    CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) over len, seq, type and payload,
//            little-endian
// Payloads (little-endian; floats are IEEE-754 binary32):
//   COMMAND (33 bytes): mode u8 | time_ns i64 | x y z f32 (m) | rx ry rz f32 (rad)
//   ACK     (2 bytes):  acked seq u8 | result u8 (0 accepted, 1 unreachable, 2 arm in fault, 3 bad mode)
//   STATE   (36 bytes): applied seq u8 | mode u8 | flags u8 | fault code u8 | time_ns i64 |
//                       x y z f32 | rx ry rz f32
// STATE is sent periodically by the arm and is its heartbeat.
//
// The decoder resynchronises after line noise: a bad length, type or CRC drops the first
// byte of the candidate frame and scans on for the next A5 5A.
#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string_view>

#include "markcell/drivers/arm.hpp"

namespace markcell::drivers::serial {

inline constexpr std::uint8_t kSof0 = 0xA5;
inline constexpr std::uint8_t kSof1 = 0x5A;
inline constexpr std::size_t kMaxPayload = 64;
inline constexpr std::size_t kHeader = 5;  // SOF x2, len, seq, type
inline constexpr std::size_t kMaxFrame = kHeader + kMaxPayload + 2;

enum class FrameType : std::uint8_t { kCommand = 1, kAck = 2, kState = 3 };
enum class AckResult : std::uint8_t { kAccepted = 0, kUnreachable = 1, kArmFault = 2, kBadMode = 3 };

inline constexpr std::size_t kCommandSize = 33;
inline constexpr std::size_t kAckSize = 2;
inline constexpr std::size_t kStateSize = 36;

std::uint16_t crc16(std::span<const std::uint8_t> bytes, std::uint16_t crc = 0xFFFF);

struct Frame {
  FrameType type = FrameType::kCommand;
  std::uint8_t seq = 0;
  std::uint8_t length = 0;
  std::array<std::uint8_t, kMaxPayload> payload{};
  std::span<const std::uint8_t> bytes() const { return {payload.data(), length}; }
};

// Writes a whole frame into `out` (at least kMaxFrame bytes); returns its size.
std::size_t encode(FrameType type, std::uint8_t seq, std::span<const std::uint8_t> payload, std::span<std::uint8_t> out);
std::size_t encode_command(const ArmCommand& command, std::uint8_t seq, std::span<std::uint8_t> out);
std::size_t encode_ack(std::uint8_t seq, AckResult result, std::span<std::uint8_t> out);
std::size_t encode_state(const ArmState& state, Nanos time, std::uint8_t seq, std::span<std::uint8_t> out);

enum class PayloadError : std::uint8_t { kOk, kWrongSize, kBadMode, kNotFinite, kBadResult };
std::string_view to_string(PayloadError e);
PayloadError decode_command(const Frame& frame, ArmCommand& out);
PayloadError decode_ack(const Frame& frame, std::uint8_t& acked_seq, AckResult& result);
// `time` is the arm's own stamp; the caller sets ArmState::received.
PayloadError decode_state(const Frame& frame, ArmState& out, Nanos& time);

// Streaming decoder with a fixed buffer.
class Decoder {
 public:
  enum class Result : std::uint8_t { kFrame, kNeedMore, kBadLength, kBadType, kBadCrc };
  // Appends bytes; returns how many were taken (fewer when the buffer is full: call
  // next() until kNeedMore, then push the rest).
  std::size_t push(std::span<const std::uint8_t> bytes);
  // Extracts the next frame. On kBadLength/kBadType/kBadCrc the decoder has already
  // resynchronised; call again.
  Result next(Frame& out);
  std::uint64_t discarded_bytes() const { return discarded_; }

  // Feeds `bytes` through the decoder: on_frame(frame) for every complete frame,
  // on_error() for every malformed one. Bounded by the input's length.
  template <typename OnFrame, typename OnError>
  void consume(std::span<const std::uint8_t> bytes, OnFrame&& on_frame, OnError&& on_error) {
    Frame frame;
    // Each round takes at least one byte in, or there is nothing left to take.
    for (std::size_t round = 0; round <= bytes.size(); ++round) {
      bytes = bytes.subspan(push(bytes));
      for (std::size_t f = 0; f < 2 * kMaxFrame; ++f) {  // a full buffer holds at most this many results
        const Result r = next(frame);
        if (r == Result::kNeedMore) break;
        if (r == Result::kFrame) on_frame(frame);
        else on_error();
      }
      if (bytes.empty()) break;
    }
  }

 private:
  void drop(std::size_t n);
  std::array<std::uint8_t, 2 * kMaxFrame> buffer_{};
  std::size_t size_ = 0;
  std::uint64_t discarded_ = 0;
};

}  // namespace markcell::drivers::serial
