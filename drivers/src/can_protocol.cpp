#include "markcell/drivers/can_protocol.hpp"

#include <cmath>

namespace markcell::drivers::canopen {

namespace {

void put_i16(CanFrame& f, int at, std::int16_t v) {
  const auto u = static_cast<std::uint16_t>(v);
  f.data[static_cast<std::size_t>(at)] = static_cast<std::uint8_t>(u & 0xFF);
  f.data[static_cast<std::size_t>(at) + 1] = static_cast<std::uint8_t>(u >> 8);
}

std::int16_t get_i16(const CanFrame& f, int at) {
  return static_cast<std::int16_t>(static_cast<std::uint16_t>(f.data[static_cast<std::size_t>(at)] |
                                                              (f.data[static_cast<std::size_t>(at) + 1] << 8)));
}

EncodeError quantise(const std::array<double, 3>& v, double unit, std::array<std::int16_t, 3>& out) {
  for (std::size_t i = 0; i < 3; ++i) {
    if (!std::isfinite(v[i])) return EncodeError::kNotFinite;
    const double counts = std::round(v[i] / unit);
    if (counts < -32768.0 || counts > 32767.0) return EncodeError::kOutOfRange;
    out[i] = static_cast<std::int16_t>(counts);
  }
  return EncodeError::kOk;
}

CanFrame frame(std::uint32_t id, std::uint8_t len) {
  CanFrame f;
  f.id = id;
  f.len = len;
  return f;
}

CanFrame vector_frame(std::uint32_t id, const std::array<std::int16_t, 3>& v, std::uint8_t b6, std::uint8_t b7) {
  CanFrame f = frame(id, 8);
  for (int i = 0; i < 3; ++i) put_i16(f, 2 * i, v[static_cast<std::size_t>(i)]);
  f.data[6] = b6;
  f.data[7] = b7;
  return f;
}

void read_vector(const CanFrame& f, double unit, std::array<double, 3>& out) {
  for (int i = 0; i < 3; ++i) out[static_cast<std::size_t>(i)] = get_i16(f, 2 * i) * unit;
}

void put_i32(CanFrame& f, int at, std::int32_t v) {
  const auto u = static_cast<std::uint32_t>(v);
  for (int i = 0; i < 4; ++i) f.data[static_cast<std::size_t>(at + i)] = static_cast<std::uint8_t>(u >> (8 * i));
}

std::int32_t get_i32(const CanFrame& f, int at) {
  std::uint32_t u = 0;
  for (int i = 0; i < 4; ++i) u |= static_cast<std::uint32_t>(f.data[static_cast<std::size_t>(at + i)]) << (8 * i);
  return static_cast<std::int32_t>(u);
}

EncodeError quantise32(const std::array<double, 3>& v, double unit, CanFrame& f, int at) {
  for (std::size_t i = 0; i < 3; ++i) {
    if (!std::isfinite(v[i])) return EncodeError::kNotFinite;
    const double counts = std::round(v[i] / unit);
    if (counts < -2147483648.0 || counts > 2147483647.0) return EncodeError::kOutOfRange;
    put_i32(f, at + 4 * static_cast<int>(i), static_cast<std::int32_t>(counts));
  }
  return EncodeError::kOk;
}

bool valid_nmt_state(std::uint8_t s) { return s == 0x00 || s == 0x04 || s == 0x05 || s == 0x7F; }
bool valid_nmt_command(std::uint8_t c) { return c == 0x01 || c == 0x02 || c == 0x80 || c == 0x81; }

}  // namespace

CanFrame nmt(NmtCommand command, std::uint8_t node) {
  CanFrame f = frame(kNmtId, 2);
  f.data[0] = static_cast<std::uint8_t>(command);
  f.data[1] = node;
  return f;
}

CanFrame sync() { return frame(kSyncId, 0); }

CanFrame heartbeat(std::uint8_t node, NmtState state) {
  CanFrame f = frame(kHeartbeatId + node, 1);
  f.data[0] = static_cast<std::uint8_t>(state);
  return f;
}

EncodeError encode_command(const ArmCommand& c, std::uint8_t seq, std::uint8_t node, std::array<CanFrame, 3>& out) {
  std::array<std::int16_t, 3> p{}, r{};
  if (const auto e = quantise(c.target.position, kPositionUnit, p); e != EncodeError::kOk) return e;
  if (const auto e = quantise(c.target.rotation, kRotationUnit, r); e != EncodeError::kOk) return e;
  out[0] = vector_frame(kTargetPositionId + node, p, static_cast<std::uint8_t>(c.mode), seq);
  out[1] = vector_frame(kTargetRotationId + node, r, seq, 0);
  CanFrame t = frame(kTargetTimeId + node, 8);
  const auto us = static_cast<std::uint32_t>(static_cast<std::uint64_t>(c.time / kNanosPerMicro) & 0xFFFFFFFFU);
  for (int i = 0; i < 4; ++i) t.data[static_cast<std::size_t>(i)] = static_cast<std::uint8_t>(us >> (8 * i));
  t.data[4] = seq;
  out[2] = t;
  return EncodeError::kOk;
}

EncodeError encode_state(const ArmState& s, std::uint8_t status, std::uint8_t seq, std::uint8_t node,
                         std::array<CanFrame, 2>& out) {
  std::array<std::int16_t, 3> p{}, r{};
  if (const auto e = quantise(s.tool.position, kPositionUnit, p); e != EncodeError::kOk) return e;
  if (const auto e = quantise(s.tool.rotation, kRotationUnit, r); e != EncodeError::kOk) return e;
  out[0] = vector_frame(kToolPositionId + node, p, status, seq);
  out[1] = vector_frame(kToolRotationId + node, r, s.fault_code, seq);
  return EncodeError::kOk;
}

EncodeError encode_command_fd(const ArmCommand& c, std::uint8_t seq, std::uint8_t node, CanFrame& out) {
  CanFrame f = frame(kTargetFdId + node, kFdLength);
  f.fd = true;
  if (const auto e = quantise32(c.target.position, kFdPositionUnit, f, 0); e != EncodeError::kOk) return e;
  if (const auto e = quantise32(c.target.rotation, kFdRotationUnit, f, 12); e != EncodeError::kOk) return e;
  f.data[24] = static_cast<std::uint8_t>(c.mode);
  f.data[25] = seq;
  put_i32(f, 26, static_cast<std::int32_t>(static_cast<std::uint32_t>(static_cast<std::uint64_t>(c.time / kNanosPerMicro) & 0xFFFFFFFFU)));
  out = f;
  return EncodeError::kOk;
}

EncodeError encode_state_fd(const ArmState& s, std::uint8_t status, std::uint8_t seq, std::uint8_t node, CanFrame& out) {
  CanFrame f = frame(kToolFdId + node, kFdLength);
  f.fd = true;
  if (const auto e = quantise32(s.tool.position, kFdPositionUnit, f, 0); e != EncodeError::kOk) return e;
  if (const auto e = quantise32(s.tool.rotation, kFdRotationUnit, f, 12); e != EncodeError::kOk) return e;
  f.data[24] = status;
  f.data[25] = seq;
  f.data[26] = s.fault_code;
  out = f;
  return EncodeError::kOk;
}

std::string_view to_string(DecodeError e) {
  switch (e) {
    case DecodeError::kOk: return "ok";
    case DecodeError::kUnknownId: return "id is not in the arm's message catalogue";
    case DecodeError::kWrongLength: return "data length does not match the message";
    case DecodeError::kBadMode: return "unknown arm mode";
    case DecodeError::kBadNmtCommand: return "unknown NMT command";
    case DecodeError::kBadNmtState: return "unknown NMT state";
    case DecodeError::kRemoteOrError: return "error frame, extended id or FD frame where a classic frame is expected";
    case DecodeError::kReservedNotZero: return "reserved bytes are not zero";
  }
  return "unknown";
}

DecodeError decode(const CanFrame& f, Message& out) {
  if (f.error || f.extended) return DecodeError::kRemoteOrError;
  if (f.fd) {  // only the two FD messages travel as FD frames
    const std::uint32_t function = f.id & 0x780, node = f.id & 0x7F;
    if ((function != kTargetFdId && function != kToolFdId) || node == 0) return DecodeError::kUnknownId;
    if (f.len != kFdLength) return DecodeError::kWrongLength;
    Message m;
    m.node = static_cast<std::uint8_t>(node);
    for (int i = 0; i < 3; ++i) {
      m.vector[static_cast<std::size_t>(i)] = get_i32(f, 4 * i) * kFdPositionUnit;
      m.vector2[static_cast<std::size_t>(i)] = get_i32(f, 12 + 4 * i) * kFdRotationUnit;
    }
    m.mode_or_status = f.data[24];
    m.seq = f.data[25];
    if (function == kTargetFdId) {
      if (f.data[24] > static_cast<std::uint8_t>(ArmMode::kStop)) return DecodeError::kBadMode;
      if (f.data[30] != 0 || f.data[31] != 0) return DecodeError::kReservedNotZero;
      m.kind = Kind::kTargetFd;
      m.time_us = static_cast<std::uint32_t>(get_i32(f, 26));
    } else {
      for (int i = 27; i < 32; ++i)
        if (f.data[static_cast<std::size_t>(i)] != 0) return DecodeError::kReservedNotZero;
      m.kind = Kind::kToolFd;
      m.fault_code = f.data[26];
    }
    out = m;
    return DecodeError::kOk;
  }
  const std::uint32_t id = f.id;
  Message m;
  auto need = [&](std::uint8_t len) { return f.len == len; };
  if (id == kNmtId) {
    if (!need(2)) return DecodeError::kWrongLength;
    if (!valid_nmt_command(f.data[0])) return DecodeError::kBadNmtCommand;
    m.kind = Kind::kNmt;
    m.nmt_command = static_cast<NmtCommand>(f.data[0]);
    m.node = f.data[1];
  } else if (id == kSyncId) {
    if (!need(0)) return DecodeError::kWrongLength;
    m.kind = Kind::kSync;
  } else {
    const std::uint32_t function = id & 0x780;
    const std::uint32_t node = id & 0x7F;
    if (node == 0) return DecodeError::kUnknownId;
    m.node = static_cast<std::uint8_t>(node);
    switch (function) {
      case kHeartbeatId:
        if (!need(1)) return DecodeError::kWrongLength;
        if (!valid_nmt_state(f.data[0])) return DecodeError::kBadNmtState;
        m.kind = Kind::kHeartbeat;
        m.nmt_state = static_cast<NmtState>(f.data[0]);
        break;
      case kTargetPositionId:
        if (!need(8)) return DecodeError::kWrongLength;
        if (f.data[6] > static_cast<std::uint8_t>(ArmMode::kStop)) return DecodeError::kBadMode;
        m.kind = Kind::kTargetPosition;
        read_vector(f, kPositionUnit, m.vector);
        m.mode_or_status = f.data[6];
        m.seq = f.data[7];
        break;
      case kTargetRotationId:
        if (!need(8)) return DecodeError::kWrongLength;
        if (f.data[7] != 0) return DecodeError::kReservedNotZero;
        m.kind = Kind::kTargetRotation;
        read_vector(f, kRotationUnit, m.vector);
        m.seq = f.data[6];
        break;
      case kTargetTimeId:
        if (!need(8)) return DecodeError::kWrongLength;
        if (f.data[5] != 0 || f.data[6] != 0 || f.data[7] != 0) return DecodeError::kReservedNotZero;
        m.kind = Kind::kTargetTime;
        m.time_us = static_cast<std::uint32_t>(f.data[0] | (f.data[1] << 8) | (f.data[2] << 16)) |
                    (static_cast<std::uint32_t>(f.data[3]) << 24);
        m.seq = f.data[4];
        break;
      case kToolPositionId:
        if (!need(8)) return DecodeError::kWrongLength;
        m.kind = Kind::kToolPosition;
        read_vector(f, kPositionUnit, m.vector);
        m.mode_or_status = f.data[6];
        m.seq = f.data[7];
        break;
      case kToolRotationId:
        if (!need(8)) return DecodeError::kWrongLength;
        m.kind = Kind::kToolRotation;
        read_vector(f, kRotationUnit, m.vector);
        m.fault_code = f.data[6];
        m.seq = f.data[7];
        break;
      default:
        return DecodeError::kUnknownId;
    }
  }
  out = m;
  return DecodeError::kOk;
}

}  // namespace markcell::drivers::canopen
