#include "markcell/drivers/sim_arm.hpp"

#include <algorithm>
#include <cmath>

namespace markcell::drivers {

namespace {
double norm(const std::array<double, 3>& v) { return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }
}  // namespace

SimArmModel::SimArmModel(SimArmLimits limits) : limits_(limits), tool_(limits.home), target_(limits.home) {}

serial::AckResult SimArmModel::submit(const ArmCommand& command, std::uint8_t seq, Nanos now) {
  if (fault_code_ != 0) return serial::AckResult::kArmFault;
  if (command.mode == ArmMode::kMove && norm(command.target.position) > limits_.reach)
    return serial::AckResult::kUnreachable;
  if (queued_ == queue_.size()) {  // the newest set-point wins: drop the oldest queued one
    std::move(queue_.begin() + 1, queue_.end(), queue_.begin());
    --queued_;
  }
  queue_[queued_++] = Queued{command, seq, now + limits_.command_latency};
  return serial::AckResult::kAccepted;
}

void SimArmModel::step(Nanos now) {
  if (last_ < 0) last_ = now;
  // Apply the commands whose latency has passed, in order.
  std::size_t applied = 0;
  while (applied < queued_ && queue_[applied].due <= now) {
    const Queued& q = queue_[applied++];
    mode_ = q.command.mode;
    applied_seq_ = q.seq;
    if (mode_ == ArmMode::kMove) target_ = q.command.target;
    if (mode_ == ArmMode::kHome) target_ = limits_.home;
    if (mode_ == ArmMode::kHold || mode_ == ArmMode::kStop) target_ = tool_;
  }
  std::move(queue_.begin() + static_cast<std::ptrdiff_t>(applied), queue_.begin() + static_cast<std::ptrdiff_t>(queued_), queue_.begin());
  queued_ -= applied;

  const double dt = to_seconds(now - last_);
  last_ = now;
  if (dt <= 0) return;
  if (fault_code_ != 0 || mode_ == ArmMode::kStop) {
    velocity_ = {};  // a faulted or stopped arm brakes at once
    return;
  }
  // Pursue the target: the desired speed is what still allows stopping on it, capped.
  std::array<double, 3> to{};
  for (int i = 0; i < 3; ++i) to[static_cast<std::size_t>(i)] = target_.position[static_cast<std::size_t>(i)] - tool_.position[static_cast<std::size_t>(i)];
  const double dist = norm(to);
  const double speed = std::min(limits_.max_speed, std::sqrt(2.0 * limits_.max_accel * dist));
  std::array<double, 3> dv{};
  for (int i = 0; i < 3; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const double want = dist > 1e-12 ? to[k] / dist * speed : 0.0;
    dv[k] = want - velocity_[k];
  }
  const double dv_norm = norm(dv);
  const double dv_max = limits_.max_accel * dt;
  const double scale = dv_norm > dv_max ? dv_max / dv_norm : 1.0;
  for (int i = 0; i < 3; ++i) {
    const auto k = static_cast<std::size_t>(i);
    velocity_[k] += dv[k] * scale;
    double step = velocity_[k] * dt;
    if (std::abs(step) > std::abs(to[k]) && dist < limits_.max_speed * dt) step = to[k];  // land on it
    tool_.position[k] += step;
  }
  for (int i = 0; i < 3; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const double d = target_.rotation[k] - tool_.rotation[k];
    const double max_step = limits_.max_angular_speed * dt;
    tool_.rotation[k] += std::clamp(d, -max_step, max_step);
  }
  if (mode_ == ArmMode::kHome) homed_ = dist < limits_.in_position_tolerance;
  else if (dist > limits_.in_position_tolerance) homed_ = false;
}

ArmState SimArmModel::state() const {
  ArmState s;
  s.tool = tool_;
  s.mode = mode_;
  s.applied_seq = applied_seq_;
  s.fault_code = fault_code_;
  std::array<double, 3> to{};
  for (int i = 0; i < 3; ++i) to[static_cast<std::size_t>(i)] = target_.position[static_cast<std::size_t>(i)] - tool_.position[static_cast<std::size_t>(i)];
  const bool arrived = norm(to) <= limits_.in_position_tolerance;
  s.flags = static_cast<std::uint8_t>((arrived ? kInPosition : 0) | (norm(velocity_) > 1e-6 ? kMoving : 0) |
                                      (homed_ ? kHomed : 0) | (fault_code_ != 0 ? kFault : 0));
  return s;
}

void SimSerialArm::poll(Nanos now) {
  std::array<std::uint8_t, 256> buf{};
  for (int reads = 0; reads < 8; ++reads) {
    const long n = port_.read_some(buf, 0);
    if (n <= 0) break;
    decoder_.consume(
        std::span<const std::uint8_t>(buf.data(), static_cast<std::size_t>(n)),
        [&](const serial::Frame& frame) {
          if (tap_ != nullptr) tap_(tap_context_, now, frame);
          ArmCommand command;
          if (serial::decode_command(frame, command) != serial::PayloadError::kOk) {
            ++decode_errors_;
            return;
          }
          ++commands_;
          const auto result = model_.submit(command, frame.seq, now);
          if (!drop_acks_) {
            std::array<std::uint8_t, serial::kMaxFrame> out{};
            const std::size_t size = serial::encode_ack(frame.seq, result, out);
            port_.write_some(std::span<const std::uint8_t>(out.data(), size));
          }
        },
        [&] { ++decode_errors_; });
  }
  model_.step(now);
  if (!silent_ && now >= next_state_) {
    std::array<std::uint8_t, serial::kMaxFrame> out{};
    const std::size_t size = serial::encode_state(model_.state(), now, 0, out);
    port_.write_some(std::span<const std::uint8_t>(out.data(), size));
    next_state_ = now + state_period_;
  }
}

}  // namespace markcell::drivers
