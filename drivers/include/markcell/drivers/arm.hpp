#pragma once
// The robot arm as markcell sees it, whatever the transport (CAN or serial): tool-pose
// set-points with a mode and a timestamp go out; the arm's state (tool pose, in
// position, fault, heartbeat) comes back. Poses are X_Base_Tool: position in metres and
// orientation as a rotation vector (axis * angle, radians), both in the robot base frame.
#include <array>
#include <cstdint>
#include <string_view>

#include "markcell/common/time.hpp"

namespace markcell::drivers {

enum class ArmMode : std::uint8_t { kHold = 0, kMove = 1, kHome = 2, kStop = 3 };
std::string_view to_string(ArmMode mode);

struct ToolPose {
  std::array<double, 3> position{};  // m
  std::array<double, 3> rotation{};  // rotation vector, rad
};

struct ArmCommand {
  ArmMode mode = ArmMode::kHold;
  Nanos time = 0;        // when the target is meant for (executive clock)
  ToolPose target;
};

enum ArmFlags : std::uint8_t {
  kInPosition = 1 << 0,
  kMoving = 1 << 1,
  kHomed = 1 << 2,
  kFault = 1 << 3,
};

struct ArmState {
  ToolPose tool;
  ArmMode mode = ArmMode::kHold;
  std::uint8_t flags = 0;
  std::uint8_t fault_code = 0;   // the arm's own code, 0 = none
  std::uint8_t applied_seq = 0;  // sequence number of the last command the arm applied
  Nanos received = 0;            // when this state arrived (executive clock)
  bool in_position() const { return (flags & kInPosition) != 0; }
  bool fault() const { return (flags & kFault) != 0; }
};

// How long the arm has been silent, counted only while the controller listened. A poll
// later than kListeningGap after the previous one (its lane late: preempted, stalled, or
// the simulated arm on that same lane held with it) moves the timer on by the gap: the
// arm is not blamed for the controller's own absence, and whatever it sent meanwhile
// waits in the socket's queue for that very poll. An arm silent while the controller
// listens is lost within the timeout as before.
class SilenceTimer {
 public:
  static constexpr Nanos kListeningGap = millis(5);
  void start(Nanos now) { heard_ = last_poll_ = now; }
  void polled(Nanos now) {  // first thing in each poll
    const Nanos gap = now - last_poll_;
    if (gap > kListeningGap) heard_ = heard_ + gap < now ? heard_ + gap : now;
    last_poll_ = now;
  }
  void heard(Nanos now) { heard_ = now; }
  Nanos silent_for(Nanos now) const { return now - heard_; }

 private:
  Nanos heard_ = 0, last_poll_ = 0;
};

enum class ArmLinkStatus : std::uint8_t {
  kInactive,       // not activated
  kConnecting,     // activated, no state from the arm yet
  kOk,
  kHeartbeatLost,  // no state/heartbeat within the timeout
  kRefused,        // the arm refused the last command (unreachable, wrong mode)
  kArmFault,       // the arm reports a fault
  kNoAck,          // a command was not acknowledged after every retry (serial)
  kBusOff,         // the CAN controller went bus-off
  kIoError,
};
std::string_view to_string(ArmLinkStatus status);
// Whether the executive must safe-stop on this status.
inline bool is_fault(ArmLinkStatus s) {
  return s == ArmLinkStatus::kHeartbeatLost || s == ArmLinkStatus::kArmFault || s == ArmLinkStatus::kNoAck ||
         s == ArmLinkStatus::kBusOff || s == ArmLinkStatus::kIoError;
}

struct ArmLinkCounters {
  std::uint64_t commands_sent = 0;
  std::uint64_t states_received = 0;
  std::uint64_t retries = 0;
  std::uint64_t refusals = 0;
  std::uint64_t decode_errors = 0;  // CRC, length, malformed frames
  std::uint64_t bus_errors = 0;     // CAN error frames
  std::uint64_t restarts = 0;       // CAN bus restarts seen
};

// Lifecycle: configure (in the constructor of each link), activate (open, start the
// remote node), deactivate (hold the arm, close). send() and poll() are real-time
// safe: bounded, non-blocking, no allocation.
class ArmLink {
 public:
  virtual ~ArmLink() = default;
  virtual void activate(Nanos now) = 0;
  virtual void deactivate() noexcept = 0;
  // Queues a command; returns the sequence number it carries.
  virtual std::uint8_t send(const ArmCommand& command, Nanos now) noexcept = 0;
  // Reads what arrived, runs timeouts and retries; returns the link status.
  virtual ArmLinkStatus poll(Nanos now) noexcept = 0;
  virtual const ArmState& state() const = 0;
  virtual ArmLinkStatus status() const = 0;
  virtual const ArmLinkCounters& counters() const = 0;
};

}  // namespace markcell::drivers
