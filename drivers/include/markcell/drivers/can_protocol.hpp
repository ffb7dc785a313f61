#pragma once
// The arm's CAN protocol, CANopen-style, classic 8-byte frames: pure code, no I/O.
// config/markcell_arm.dbc describes the same frames for standard CAN tools.
//
//   id           from        frame            bytes
//   0x000        controller  NMT              command u8 (1 start, 2 stop, 0x80 pre-op, 0x81 reset), node u8
//   0x080        controller  SYNC             (none): the arm applies the set-point it has
//   0x200+node   controller  TARGET_POSITION  x y z i16 (0.1 mm) | mode u8 | seq u8
//   0x300+node   controller  TARGET_ROTATION  rx ry rz i16 (1e-4 rad) | seq u8 | 0
//   0x400+node   controller  TARGET_TIME      time u32 (us, low 32 bits of the executive clock) | seq u8 | 0 0 0
//   0x180+node   arm         TOOL_POSITION    x y z i16 (0.1 mm) | status u8 | seq u8
//   0x280+node   arm         TOOL_ROTATION    rx ry rz i16 (1e-4 rad) | fault code u8 | seq u8
//   0x700+node   both        HEARTBEAT        NMT state u8 (0 boot-up, 4 stopped, 5 operational, 0x7F pre-op)
// With CAN FD (devices.arm.can.fd), a set-point and a state each travel in one 32-byte
// FD frame instead of three and two classic ones:
//   0x500+node   controller  TARGET_FD        x y z i32 (um) | rx ry rz i32 (urad) | mode u8 | seq u8 |
//                                             time u32 (us) | 0 0
//   0x480+node   arm         TOOL_FD          x y z i32 (um) | rx ry rz i32 (urad) | status u8 | seq u8 |
//                                             fault code u8 | 0 0 0 0 0
// Integers are little-endian. status: ArmFlags bits 0-3 (in position, moving, homed,
// fault), bit 4 = the command `seq` was refused. The three TARGET frames of one
// set-point share its seq; the arm applies a complete set at the next SYNC. Positions
// span +-3.2767 m and rotations +-3.2767 rad.
#include <array>
#include <cstdint>
#include <string_view>

#include "markcell/drivers/arm.hpp"
#include "markcell/drivers/can_bus.hpp"

namespace markcell::drivers::canopen {

inline constexpr std::uint32_t kNmtId = 0x000;
inline constexpr std::uint32_t kSyncId = 0x080;
inline constexpr std::uint32_t kToolPositionId = 0x180;
inline constexpr std::uint32_t kTargetPositionId = 0x200;
inline constexpr std::uint32_t kToolRotationId = 0x280;
inline constexpr std::uint32_t kTargetRotationId = 0x300;
inline constexpr std::uint32_t kTargetTimeId = 0x400;
inline constexpr std::uint32_t kHeartbeatId = 0x700;
inline constexpr std::uint32_t kToolFdId = 0x480;
inline constexpr std::uint32_t kTargetFdId = 0x500;
inline constexpr std::uint8_t kFdLength = 32;
inline constexpr double kFdPositionUnit = 1e-6;  // m per count
inline constexpr double kFdRotationUnit = 1e-6;  // rad per count
inline constexpr double kPositionUnit = 1e-4;  // m per count
inline constexpr double kRotationUnit = 1e-4;  // rad per count
inline constexpr std::uint8_t kStatusRefused = 0x10;

enum class NmtCommand : std::uint8_t { kStart = 0x01, kStop = 0x02, kPreOperational = 0x80, kResetNode = 0x81 };
enum class NmtState : std::uint8_t { kBootUp = 0x00, kStopped = 0x04, kOperational = 0x05, kPreOperational = 0x7F };

CanFrame nmt(NmtCommand command, std::uint8_t node);
CanFrame sync();
CanFrame heartbeat(std::uint8_t node, NmtState state);

enum class EncodeError : std::uint8_t { kOk, kOutOfRange, kNotFinite };
EncodeError encode_command(const ArmCommand& command, std::uint8_t seq, std::uint8_t node, std::array<CanFrame, 3>& out);
EncodeError encode_command_fd(const ArmCommand& command, std::uint8_t seq, std::uint8_t node, CanFrame& out);
EncodeError encode_state_fd(const ArmState& state, std::uint8_t status, std::uint8_t seq, std::uint8_t node, CanFrame& out);
// The arm's side (the simulated arm): its state as TOOL_POSITION and TOOL_ROTATION.
EncodeError encode_state(const ArmState& state, std::uint8_t status, std::uint8_t seq, std::uint8_t node,
                         std::array<CanFrame, 2>& out);

enum class Kind : std::uint8_t {
  kNmt, kSync, kHeartbeat, kTargetPosition, kTargetRotation, kTargetTime, kToolPosition, kToolRotation,
  kTargetFd, kToolFd  // vector: position, vector2: rotation
};

struct Message {
  Kind kind = Kind::kSync;
  std::uint8_t node = 0;           // the node the frame is from (arm frames, heartbeat) or for
  std::uint8_t seq = 0;
  NmtCommand nmt_command = NmtCommand::kStart;
  NmtState nmt_state = NmtState::kBootUp;
  std::array<double, 3> vector{};  // position (m) or rotation (rad)
  std::array<double, 3> vector2{}; // FD frames: the rotation (rad)
  std::uint8_t mode_or_status = 0; // TARGET_POSITION: mode; TOOL_POSITION: status
  std::uint8_t fault_code = 0;
  std::uint32_t time_us = 0;
};

enum class DecodeError : std::uint8_t {
  kOk, kUnknownId, kWrongLength, kBadMode, kBadNmtCommand, kBadNmtState, kRemoteOrError, kReservedNotZero
};
std::string_view to_string(DecodeError e);
DecodeError decode(const CanFrame& frame, Message& out);

}  // namespace markcell::drivers::canopen
