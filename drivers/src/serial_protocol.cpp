#include "markcell/drivers/serial_protocol.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>

namespace markcell::drivers::serial {

namespace {

struct Writer {
  std::span<std::uint8_t> out;
  std::size_t at = 0;
  void u8(std::uint8_t v) { out[at++] = v; }
  void u16(std::uint16_t v) {
    u8(static_cast<std::uint8_t>(v & 0xFF));
    u8(static_cast<std::uint8_t>(v >> 8));
  }
  void u64(std::uint64_t v) {
    for (int i = 0; i < 8; ++i) u8(static_cast<std::uint8_t>(v >> (8 * i)));
  }
  void f32(double v) {
    const auto bits = std::bit_cast<std::uint32_t>(static_cast<float>(v));
    for (int i = 0; i < 4; ++i) u8(static_cast<std::uint8_t>(bits >> (8 * i)));
  }
};

struct Reader {
  std::span<const std::uint8_t> in;
  std::size_t at = 0;
  std::uint8_t u8() { return in[at++]; }
  std::uint64_t u64() {
    std::uint64_t v = 0;
    for (int i = 0; i < 8; ++i) v |= static_cast<std::uint64_t>(in[at++]) << (8 * i);
    return v;
  }
  double f32() {
    std::uint32_t bits = 0;
    for (int i = 0; i < 4; ++i) bits |= static_cast<std::uint32_t>(in[at++]) << (8 * i);
    return static_cast<double>(std::bit_cast<float>(bits));
  }
};

void write_pose(Writer& w, const ToolPose& p) {
  for (double v : p.position) w.f32(v);
  for (double v : p.rotation) w.f32(v);
}

bool read_pose(Reader& r, ToolPose& p) {
  for (double& v : p.position) v = r.f32();
  for (double& v : p.rotation) v = r.f32();
  for (double v : p.position)
    if (!std::isfinite(v)) return false;
  for (double v : p.rotation)
    if (!std::isfinite(v)) return false;
  return true;
}

bool valid_mode(std::uint8_t m) { return m <= static_cast<std::uint8_t>(ArmMode::kStop); }

}  // namespace

std::uint16_t crc16(std::span<const std::uint8_t> bytes, std::uint16_t crc) {
  for (std::uint8_t b : bytes) {
    crc = static_cast<std::uint16_t>(crc ^ (static_cast<std::uint16_t>(b) << 8));
    for (int i = 0; i < 8; ++i)
      crc = (crc & 0x8000) != 0 ? static_cast<std::uint16_t>((crc << 1) ^ 0x1021) : static_cast<std::uint16_t>(crc << 1);
  }
  return crc;
}

std::size_t encode(FrameType type, std::uint8_t seq, std::span<const std::uint8_t> payload, std::span<std::uint8_t> out) {
  if (payload.size() > kMaxPayload || out.size() < kHeader + payload.size() + 2) return 0;
  Writer w{out};
  w.u8(kSof0);
  w.u8(kSof1);
  w.u8(static_cast<std::uint8_t>(payload.size()));
  w.u8(seq);
  w.u8(static_cast<std::uint8_t>(type));
  for (std::uint8_t b : payload) w.u8(b);
  w.u16(crc16(out.subspan(2, 3 + payload.size())));
  return w.at;
}

std::size_t encode_command(const ArmCommand& c, std::uint8_t seq, std::span<std::uint8_t> out) {
  std::array<std::uint8_t, kCommandSize> p{};
  Writer w{p};
  w.u8(static_cast<std::uint8_t>(c.mode));
  w.u64(static_cast<std::uint64_t>(c.time));
  write_pose(w, c.target);
  return encode(FrameType::kCommand, seq, p, out);
}

std::size_t encode_ack(std::uint8_t seq, AckResult result, std::span<std::uint8_t> out) {
  const std::array<std::uint8_t, kAckSize> p{seq, static_cast<std::uint8_t>(result)};
  return encode(FrameType::kAck, seq, p, out);
}

std::size_t encode_state(const ArmState& s, Nanos time, std::uint8_t seq, std::span<std::uint8_t> out) {
  std::array<std::uint8_t, kStateSize> p{};
  Writer w{p};
  w.u8(s.applied_seq);
  w.u8(static_cast<std::uint8_t>(s.mode));
  w.u8(s.flags);
  w.u8(s.fault_code);
  w.u64(static_cast<std::uint64_t>(time));
  write_pose(w, s.tool);
  return encode(FrameType::kState, seq, p, out);
}

std::string_view to_string(PayloadError e) {
  switch (e) {
    case PayloadError::kOk: return "ok";
    case PayloadError::kWrongSize: return "payload has the wrong size for its type";
    case PayloadError::kBadMode: return "unknown arm mode";
    case PayloadError::kNotFinite: return "pose value is not finite";
    case PayloadError::kBadResult: return "unknown ack result";
  }
  return "unknown";
}

PayloadError decode_command(const Frame& f, ArmCommand& out) {
  if (f.type != FrameType::kCommand || f.length != kCommandSize) return PayloadError::kWrongSize;
  Reader r{f.bytes()};
  const std::uint8_t mode = r.u8();
  if (!valid_mode(mode)) return PayloadError::kBadMode;
  ArmCommand c;
  c.mode = static_cast<ArmMode>(mode);
  c.time = static_cast<Nanos>(r.u64());
  if (!read_pose(r, c.target)) return PayloadError::kNotFinite;
  out = c;
  return PayloadError::kOk;
}

PayloadError decode_ack(const Frame& f, std::uint8_t& acked_seq, AckResult& result) {
  if (f.type != FrameType::kAck || f.length != kAckSize) return PayloadError::kWrongSize;
  if (f.payload[1] > static_cast<std::uint8_t>(AckResult::kBadMode)) return PayloadError::kBadResult;
  acked_seq = f.payload[0];
  result = static_cast<AckResult>(f.payload[1]);
  return PayloadError::kOk;
}

PayloadError decode_state(const Frame& f, ArmState& out, Nanos& time) {
  if (f.type != FrameType::kState || f.length != kStateSize) return PayloadError::kWrongSize;
  Reader r{f.bytes()};
  ArmState s;
  s.applied_seq = r.u8();
  const std::uint8_t mode = r.u8();
  if (!valid_mode(mode)) return PayloadError::kBadMode;
  s.mode = static_cast<ArmMode>(mode);
  s.flags = r.u8();
  s.fault_code = r.u8();
  const auto t = static_cast<Nanos>(r.u64());
  if (!read_pose(r, s.tool)) return PayloadError::kNotFinite;
  s.received = out.received;
  out = s;
  time = t;
  return PayloadError::kOk;
}

std::size_t Decoder::push(std::span<const std::uint8_t> bytes) {
  const std::size_t n = std::min(bytes.size(), buffer_.size() - size_);
  std::memcpy(buffer_.data() + size_, bytes.data(), n);
  size_ += n;
  return n;
}

void Decoder::drop(std::size_t n) {
  std::memmove(buffer_.data(), buffer_.data() + n, size_ - n);
  size_ -= n;
}

Decoder::Result Decoder::next(Frame& out) {
  // Find the start of a frame; bytes before it are noise.
  std::size_t start = 0;
  while (start + 1 < size_ && !(buffer_[start] == kSof0 && buffer_[start + 1] == kSof1)) ++start;
  if (start + 1 >= size_ && size_ > 0 && buffer_[size_ - 1] != kSof0) start = size_;  // no SOF0 pending at the end
  if (start > 0) {
    discarded_ += start;
    drop(std::min(start, size_));
  }
  if (size_ < kHeader) return Result::kNeedMore;
  const std::uint8_t len = buffer_[2];
  const std::uint8_t type = buffer_[4];
  if (len > kMaxPayload) {
    discarded_ += 1;
    drop(1);
    return Result::kBadLength;
  }
  if (type < static_cast<std::uint8_t>(FrameType::kCommand) || type > static_cast<std::uint8_t>(FrameType::kState)) {
    discarded_ += 1;
    drop(1);
    return Result::kBadType;
  }
  const std::size_t total = kHeader + len + 2;
  if (size_ < total) return Result::kNeedMore;
  const std::uint16_t want = crc16(std::span<const std::uint8_t>(buffer_.data() + 2, 3 + len));
  const std::uint16_t got = static_cast<std::uint16_t>(buffer_[kHeader + len] | (buffer_[kHeader + len + 1] << 8));
  if (want != got) {
    discarded_ += 1;
    drop(1);
    return Result::kBadCrc;
  }
  out.type = static_cast<FrameType>(type);
  out.seq = buffer_[3];
  out.length = len;
  std::memcpy(out.payload.data(), buffer_.data() + kHeader, len);
  drop(total);
  return Result::kFrame;
}

}  // namespace markcell::drivers::serial
