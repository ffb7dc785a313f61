#pragma once
// The simulated arm: a 6-axis arm's reach and tool-centre-point speed and acceleration
// limits, with configurable command latency and faults. SimArmModel is the mechanics;
// SimSerialArm (and the CAN twin) put it behind the same wire protocol as the real arm,
// so the controller's real codec and link state machine run against it.
#include <array>
#include <cstdint>
#include <string>

#include "markcell/drivers/arm.hpp"
#include "markcell/drivers/serial_port.hpp"
#include "markcell/drivers/serial_protocol.hpp"

namespace markcell::drivers {

struct SimArmLimits {
  double reach = 1.6;               // m, from the base origin
  double max_speed = 1.0;           // m/s, tool centre point
  double max_accel = 4.0;           // m/s^2
  double max_angular_speed = 2.0;   // rad/s
  double in_position_tolerance = 0.0005;  // m
  ToolPose home{{0.3, 0.0, 0.6}, {0.0, 0.0, 0.0}};
  Nanos command_latency = millis(4);      // from receipt to the arm acting on it
};

class SimArmModel {
 public:
  explicit SimArmModel(SimArmLimits limits = {});
  // Accepts (with the reason when not) a command; it takes effect after the latency.
  serial::AckResult submit(const ArmCommand& command, std::uint8_t seq, Nanos now);
  // Advances the mechanics to `now`.
  void step(Nanos now);
  ArmState state() const;
  const ToolPose& tool() const { return tool_; }
  const std::array<double, 3>& velocity() const { return velocity_; }
  void inject_fault(std::uint8_t code) { fault_code_ = code; }
  void clear_fault() { fault_code_ = 0; }
  const SimArmLimits& limits() const { return limits_; }

 private:
  SimArmLimits limits_;
  ToolPose tool_;
  std::array<double, 3> velocity_{};
  ArmMode mode_ = ArmMode::kHold;
  ToolPose target_;
  std::uint8_t applied_seq_ = 0;
  std::uint8_t fault_code_ = 0;
  bool homed_ = true;
  Nanos last_ = -1;
  struct Queued {
    ArmCommand command;
    std::uint8_t seq;
    Nanos due;
  };
  std::array<Queued, 8> queue_{};
  std::size_t queued_ = 0;
};

// The arm's end of the serial line.
class SimSerialArm {
 public:
  SimSerialArm(SimArmLimits limits, Nanos state_period = millis(10)) : model_(limits), state_period_(state_period) {}
  void open(const std::string& device, int baud) { port_.open(device, baud); }
  void close() { port_.close(); }
  // Reads commands, acknowledges them, moves, and sends STATE every state_period.
  void poll(Nanos now);

  SimArmModel& model() { return model_; }
  // Every well-formed frame the controller sends, as the arm decodes it (a rig's command
  // log): called from poll(), so it must not block. Null: none.
  using FrameTap = void (*)(void* context, Nanos time, const serial::Frame& frame);
  void set_tap(FrameTap tap, void* context) { tap_ = tap, tap_context_ = context; }
  // Faults to exercise the controller with.
  void set_silent(bool silent) { silent_ = silent; }          // stops the heartbeat (STATE)
  void set_drop_acks(bool drop) { drop_acks_ = drop; }        // never acknowledges
  void send_raw(std::span<const std::uint8_t> bytes) { port_.write_some(bytes); }  // line noise
  std::uint64_t commands_received() const { return commands_; }
  std::uint64_t decode_errors() const { return decode_errors_; }

 private:
  SimArmModel model_;
  SerialPort port_;
  serial::Decoder decoder_;
  Nanos state_period_;
  Nanos next_state_ = 0;
  FrameTap tap_ = nullptr;
  void* tap_context_ = nullptr;
  bool silent_ = false;
  bool drop_acks_ = false;
  std::uint64_t commands_ = 0;
  std::uint64_t decode_errors_ = 0;
};

}  // namespace markcell::drivers
