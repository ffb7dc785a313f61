#pragma once
// The arm link over CAN (protocol: can_protocol.hpp), on any CanBus: SocketCAN in the
// cell, the in-memory wire in the simulated cell, vcan in the real-kernel tests.
//
// NMT: activate() starts the arm node; a boot-up heartbeat (the arm restarted) or a bus
// restart starts it again. Heartbeats: markcell produces its own every
// heartbeat_period and consumes the arm's; none within heartbeat_timeout is
// kHeartbeatLost. Set-points: TARGET_POSITION, TARGET_ROTATION, TARGET_TIME, then SYNC.
// Error frames are counted; bus-off is reported until the controller restarts.
#include <array>
#include <string>

#include "markcell/common/param.hpp"

#include "markcell/drivers/arm.hpp"
#include "markcell/drivers/can_bus.hpp"
#include "markcell/drivers/can_protocol.hpp"
#include "markcell/drivers/sim_arm.hpp"

namespace markcell::drivers {

// `devices.arm.can` (with the bus's interface, host/config.hpp): declared here, once.
struct CanArmLinkConfig {
  std::uint8_t node_id = 2;
  std::uint8_t controller_node_id = 1;
  Nanos heartbeat_period = millis(50);
  Nanos heartbeat_timeout = millis(150);
  bool fd = false;  // set-points and states as single CAN FD frames (TARGET_FD, TOOL_FD)

  template <class V>
  void Visit(V& v) {
    v(Param{"node_id", Unit::kNone, 1, 127, "the arm's CANopen node id", true}, node_id);
    v(Param{"controller_node_id", Unit::kNone, 1, 127, "markcell's own node id", true}, controller_node_id);
    v(Param{"heartbeat_ms", Unit::kMillisecond, 1, 65'535, "markcell's heartbeat period", true}, heartbeat_period);
    v(Param{"heartbeat_timeout_ms", Unit::kMillisecond, 1, 65'535, "no heartbeat of the arm's this long: link lost", true},
      heartbeat_timeout);
    v(Param{"fd", Unit::kNone, 0, 0, "set-points and states as single CAN FD frames"}, fd);
  }
  template <class Report>
  void validate(Report&& report) const {
    if (node_id == controller_node_id)
      report("controller_node_id", "controller_node_id must differ from node_id " + std::to_string(node_id));
    if (heartbeat_timeout <= heartbeat_period)
      report("heartbeat_timeout_ms", "heartbeat_timeout_ms " + std::to_string(heartbeat_timeout / millis(1)) +
                                         " must exceed heartbeat_ms " + std::to_string(heartbeat_period / millis(1)));
  }
};

class CanArmLink final : public ArmLink {
 public:
  CanArmLink(CanBus& bus, CanArmLinkConfig config) : bus_(bus), config_(config) {}
  void activate(Nanos now) override;
  void deactivate() noexcept override;
  std::uint8_t send(const ArmCommand& command, Nanos now) noexcept override;
  ArmLinkStatus poll(Nanos now) noexcept override;
  const ArmState& state() const override { return state_; }
  ArmLinkStatus status() const override { return status_; }
  const ArmLinkCounters& counters() const override { return counters_; }
  canopen::NmtState arm_nmt_state() const { return arm_nmt_; }

 private:
  void send_frame(const CanFrame& f) noexcept;
  // One state from the arm, from its two classic frames or its one FD frame.
  void take_state(const std::array<double, 3>& position, const std::array<double, 3>& rotation, std::uint8_t status,
                  std::uint8_t fault_code, std::uint8_t seq, Nanos now) noexcept;
  CanBus& bus_;
  CanArmLinkConfig config_;
  ArmState state_;
  ArmLinkStatus status_ = ArmLinkStatus::kInactive;
  ArmLinkCounters counters_;
  std::uint8_t next_seq_ = 0;
  canopen::NmtState arm_nmt_ = canopen::NmtState::kBootUp;
  SilenceTimer heartbeat_silence_;
  Nanos next_own_heartbeat_ = 0;
  bool have_heartbeat_ = false;
  bool have_state_ = false;
  bool bus_off_ = false;
  bool refused_ = false;
  bool io_error_ = false;
  // TOOL_POSITION waiting for its TOOL_ROTATION (same seq).
  bool half_ = false;
  canopen::Message half_position_;
};

// The arm's end of the CAN bus: an NMT slave with heartbeat, RPDOs applied at SYNC, and
// TPDOs of its state. Like a real arm controller it consumes the master's heartbeat:
// when markcell's heartbeat stops for `master_timeout`, the arm holds where it is.
class SimCanArm {
 public:
  SimCanArm(CanBus& bus, std::uint8_t node, SimArmLimits limits, Nanos state_period = millis(10),
            Nanos heartbeat_period = millis(50), Nanos master_timeout = millis(200), bool fd = false);
  void start(Nanos now);  // power-up: boot-up heartbeat, pre-operational
  void poll(Nanos now);
  SimArmModel& model() { return model_; }
  canopen::NmtState nmt_state() const { return nmt_; }
  void set_silent(bool silent) { silent_ = silent; }  // no heartbeat, no TPDOs
  std::uint64_t set_points_applied() const { return applied_; }
  std::uint64_t master_losses() const { return master_losses_; }
  std::uint64_t decode_errors() const { return decode_errors_; }

 private:
  CanBus& bus_;
  std::uint8_t node_;
  SimArmModel model_;
  Nanos state_period_;
  Nanos heartbeat_period_;
  Nanos next_state_ = 0;
  Nanos next_heartbeat_ = 0;
  Nanos master_timeout_;
  bool fd_;
  Nanos last_master_ = 0;
  bool master_seen_ = false;
  bool master_lost_ = false;
  std::uint64_t master_losses_ = 0;
  canopen::NmtState nmt_ = canopen::NmtState::kBootUp;
  bool silent_ = false;
  struct Partial {
    bool position = false, rotation = false, time = false;
    std::uint8_t seq = 0;
    ArmCommand command;
  } partial_;
  std::uint8_t last_seq_ = 0;
  bool last_refused_ = false;
  std::uint64_t applied_ = 0;
  std::uint64_t decode_errors_ = 0;
};

}  // namespace markcell::drivers
