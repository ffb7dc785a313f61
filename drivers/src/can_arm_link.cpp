#include "markcell/drivers/can_arm_link.hpp"

namespace markcell::drivers {

using canopen::Kind;
using canopen::NmtCommand;
using canopen::NmtState;

void CanArmLink::send_frame(const CanFrame& f) noexcept {
  const CanStatus s = bus_.send(f);
  if (s == CanStatus::kIoError || s == CanStatus::kNotOpen || s == CanStatus::kTooLong) io_error_ = true;
  // kWouldBlock: the TX queue is full (bus-off, or nobody acknowledging); the heartbeat
  // supervision reports it, a single lost frame is not an error of its own.
}

void CanArmLink::activate(Nanos now) {
  if (!bus_.is_open()) bus_.open();
  status_ = ArmLinkStatus::kConnecting;
  have_heartbeat_ = have_state_ = bus_off_ = refused_ = io_error_ = half_ = false;
  heartbeat_silence_.start(now);  // the heartbeat timeout runs from activation
  next_own_heartbeat_ = now;
  send_frame(canopen::nmt(NmtCommand::kStart, config_.node_id));
}

void CanArmLink::deactivate() noexcept {
  if (status_ == ArmLinkStatus::kInactive) return;
  ArmCommand hold;
  hold.mode = ArmMode::kHold;
  hold.target = state_.tool;
  send(hold, state_.received);  // best effort: the arm holds where it is
  send_frame(canopen::heartbeat(config_.controller_node_id, NmtState::kStopped));
  status_ = ArmLinkStatus::kInactive;
}

std::uint8_t CanArmLink::send(const ArmCommand& command, Nanos) noexcept {
  const std::uint8_t seq = ++next_seq_;
  if (config_.fd) {
    CanFrame frame;
    if (canopen::encode_command_fd(command, seq, config_.node_id, frame) != canopen::EncodeError::kOk) {
      refused_ = true;
      ++counters_.refusals;
      return seq;
    }
    send_frame(frame);
    send_frame(canopen::sync());
    ++counters_.commands_sent;
    return seq;
  }
  std::array<CanFrame, 3> frames;
  if (canopen::encode_command(command, seq, config_.node_id, frames) != canopen::EncodeError::kOk) {
    // Outside what the wire can carry (or not finite): refused here, nothing is sent.
    refused_ = true;
    ++counters_.refusals;
    return seq;
  }
  for (const auto& f : frames) send_frame(f);
  send_frame(canopen::sync());
  ++counters_.commands_sent;
  return seq;
}

void CanArmLink::take_state(const std::array<double, 3>& position, const std::array<double, 3>& rotation,
                            std::uint8_t status, std::uint8_t fault_code, std::uint8_t seq, Nanos now) noexcept {
  state_.tool.position = position;
  state_.tool.rotation = rotation;
  state_.flags = static_cast<std::uint8_t>(status & 0x0F);
  state_.fault_code = fault_code;
  state_.applied_seq = seq;
  state_.received = now;
  refused_ = (status & canopen::kStatusRefused) != 0;
  have_state_ = true;
  ++counters_.states_received;
}

ArmLinkStatus CanArmLink::poll(Nanos now) noexcept {
  if (status_ == ArmLinkStatus::kInactive) return status_;
  heartbeat_silence_.polled(now);
  std::array<CanFrame, 32> frames;
  for (int batch = 0; batch < 4; ++batch) {
    const int n = bus_.receive(frames, 0);
    if (n < 0) io_error_ = true;
    if (n <= 0) break;
    for (int i = 0; i < n; ++i) {
      const CanFrame& f = frames[static_cast<std::size_t>(i)];
      if (f.error) {
        ++counters_.bus_errors;
        if ((f.id & kCanErrBusOff) != 0) bus_off_ = true;
        if ((f.id & kCanErrRestarted) != 0) {
          bus_off_ = false;
          ++counters_.restarts;
          send_frame(canopen::nmt(NmtCommand::kStart, config_.node_id));
        }
        continue;
      }
      canopen::Message m;
      if (canopen::decode(f, m) != canopen::DecodeError::kOk) {
        ++counters_.decode_errors;
        continue;
      }
      if (m.node != config_.node_id) continue;  // our own frames echoed, other nodes
      switch (m.kind) {
        case Kind::kHeartbeat:
          have_heartbeat_ = true;
          heartbeat_silence_.heard(now);
          arm_nmt_ = m.nmt_state;
          if (m.nmt_state == NmtState::kBootUp || m.nmt_state == NmtState::kPreOperational)
            send_frame(canopen::nmt(NmtCommand::kStart, config_.node_id));  // it restarted: start it again
          break;
        case Kind::kToolPosition:
          half_position_ = m;
          half_ = true;
          break;
        case Kind::kToolFd:
          take_state(m.vector, m.vector2, m.mode_or_status, m.fault_code, m.seq, now);
          break;
        case Kind::kToolRotation:
          if (half_ && half_position_.seq == m.seq) {
            take_state(half_position_.vector, m.vector, half_position_.mode_or_status, m.fault_code, m.seq, now);
          } else {
            ++counters_.decode_errors;  // a rotation without its position: a lost frame
          }
          half_ = false;
          break;
        default:
          break;  // commands from another master are not ours to act on
      }
    }
  }
  if (now >= next_own_heartbeat_) {
    send_frame(canopen::heartbeat(config_.controller_node_id, NmtState::kOperational));
    next_own_heartbeat_ = now + config_.heartbeat_period;
  }
  if (io_error_) status_ = ArmLinkStatus::kIoError;
  else if (bus_off_) status_ = ArmLinkStatus::kBusOff;
  else if (heartbeat_silence_.silent_for(now) > config_.heartbeat_timeout) status_ = ArmLinkStatus::kHeartbeatLost;
  else if (have_state_ && state_.fault()) status_ = ArmLinkStatus::kArmFault;
  else if (refused_) status_ = ArmLinkStatus::kRefused;
  else if (have_heartbeat_ && have_state_ && arm_nmt_ == NmtState::kOperational) status_ = ArmLinkStatus::kOk;
  else status_ = ArmLinkStatus::kConnecting;
  return status_;
}

SimCanArm::SimCanArm(CanBus& bus, std::uint8_t node, SimArmLimits limits, Nanos state_period, Nanos heartbeat_period,
                     Nanos master_timeout, bool fd)
    : bus_(bus),
      node_(node),
      model_(limits),
      state_period_(state_period),
      heartbeat_period_(heartbeat_period),
      master_timeout_(master_timeout),
      fd_(fd) {}

void SimCanArm::start(Nanos now) {
  if (!bus_.is_open()) bus_.open();
  nmt_ = NmtState::kBootUp;
  bus_.send(canopen::heartbeat(node_, NmtState::kBootUp));
  nmt_ = NmtState::kPreOperational;
  next_heartbeat_ = now + heartbeat_period_;
  next_state_ = now;
}

void SimCanArm::poll(Nanos now) {
  std::array<CanFrame, 32> frames;
  for (int batch = 0; batch < 4; ++batch) {
    const int n = bus_.receive(frames, 0);
    if (n <= 0) break;
    for (int i = 0; i < n; ++i) {
      canopen::Message m;
      if (frames[static_cast<std::size_t>(i)].error) continue;
      if (canopen::decode(frames[static_cast<std::size_t>(i)], m) != canopen::DecodeError::kOk) {
        ++decode_errors_;
        continue;
      }
      // The parts of a set-point: ours only; a new seq (or an FD frame, which is whole)
      // starts a new set-point.
      if (m.kind == Kind::kTargetPosition || m.kind == Kind::kTargetRotation || m.kind == Kind::kTargetTime ||
          m.kind == Kind::kTargetFd) {
        if (m.node != node_) continue;
        if (m.seq != partial_.seq || m.kind == Kind::kTargetFd) partial_ = Partial{};
        partial_.seq = m.seq;
      }
      switch (m.kind) {
        case Kind::kNmt:
          if (m.node != node_ && m.node != 0) break;
          if (m.nmt_command == NmtCommand::kStart) nmt_ = NmtState::kOperational;
          if (m.nmt_command == NmtCommand::kStop) nmt_ = NmtState::kStopped;
          if (m.nmt_command == NmtCommand::kPreOperational) nmt_ = NmtState::kPreOperational;
          break;
        case Kind::kTargetPosition:
          partial_.position = true;
          partial_.command.mode = static_cast<ArmMode>(m.mode_or_status);
          partial_.command.target.position = m.vector;
          break;
        case Kind::kTargetRotation:
          partial_.rotation = true;
          partial_.command.target.rotation = m.vector;
          break;
        case Kind::kTargetTime:
          partial_.time = true;
          partial_.command.time = static_cast<Nanos>(m.time_us) * kNanosPerMicro;
          break;
        case Kind::kTargetFd:  // the whole set-point in one frame
          partial_.position = partial_.rotation = partial_.time = true;
          partial_.command.mode = static_cast<ArmMode>(m.mode_or_status);
          partial_.command.target.position = m.vector;
          partial_.command.target.rotation = m.vector2;
          partial_.command.time = static_cast<Nanos>(m.time_us) * kNanosPerMicro;
          break;
        case Kind::kHeartbeat:
          if (m.node != node_ && m.nmt_state == NmtState::kOperational) {
            master_seen_ = true;
            master_lost_ = false;
            last_master_ = now;
          }
          break;
        case Kind::kSync:
          if (nmt_ == NmtState::kOperational && partial_.position && partial_.rotation && partial_.time) {
            const auto result = model_.submit(partial_.command, partial_.seq, now);
            last_seq_ = partial_.seq;
            last_refused_ = result != serial::AckResult::kAccepted;
            ++applied_;
            partial_ = Partial{};
          }
          break;
        default:
          break;
      }
    }
  }
  if (master_seen_ && !master_lost_ && now - last_master_ > master_timeout_) {
    // The master went quiet: hold where we are until it speaks again.
    ArmCommand hold;
    hold.mode = ArmMode::kHold;
    hold.target = model_.tool();
    model_.submit(hold, last_seq_, now);
    master_lost_ = true;
    ++master_losses_;
  }
  model_.step(now);
  if (silent_) return;
  if (now >= next_heartbeat_) {
    bus_.send(canopen::heartbeat(node_, nmt_));
    next_heartbeat_ = now + heartbeat_period_;
  }
  if (nmt_ == NmtState::kOperational && now >= next_state_) {
    const ArmState s = model_.state();
    const auto status = static_cast<std::uint8_t>(s.flags | (last_refused_ ? canopen::kStatusRefused : 0));
    if (fd_) {
      CanFrame f;
      if (canopen::encode_state_fd(s, status, last_seq_, node_, f) == canopen::EncodeError::kOk) bus_.send(f);
    } else {
      std::array<CanFrame, 2> out;
      if (canopen::encode_state(s, status, last_seq_, node_, out) == canopen::EncodeError::kOk)
        for (const auto& f : out) bus_.send(f);
    }
    next_state_ = now + state_period_;
  }
}

}  // namespace markcell::drivers
