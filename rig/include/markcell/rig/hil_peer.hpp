#pragma once
// The rig's far side of the cell's real devices, for a replay on them
// (`markcell replay RECORDING --gpio-sim DIR`). In simulated time the world lives inside
// the cell (its sim_world task); here it runs outside, behind the kernel's devices, and
// the cell runs unchanged on its real clock, its libgpiod lines and its arm link (SocketCAN
// or a serial line):
// - the simulated arm (drivers::SimCanArm: the same mechanics and CANopen node as in
//   simulated time) on a socket of its own on the cell's CAN interface; or, for an arm on
//   a serial line, drivers::SimSerialArm (the same mechanics) on the line's other end (a
//   second port with a null-modem cable, or a pty pair made by socat);
// - the PLC's inputs driven through the gpio-sim chip's `pull` attributes, the valve's
//   level read from its `value` attribute.
// A thread of its own at 1 kHz on CLOCK_MONOTONIC (the cell's real clock) moves the arm,
// records each valve opening with the arm's tool pose at that moment (as the simulated
// world does: the rig scores these) and keeps the command log.
#include <array>
#include <atomic>
#include <optional>
#include <span>
#include <string>
#include <thread>

#include "markcell/drivers/can_arm_link.hpp"
#include "markcell/drivers/can_bus.hpp"
#include "markcell/drivers/sim_arm.hpp"
#include "markcell/host/cell.hpp"
#include "markcell/sim/command_log.hpp"
#include "markcell/host/config.hpp"

namespace markcell::rig {

class HilPeer {
 public:
  // `offsets`: each line role's offset on the chip (as the cell's libgpiod driver found
  // them by name). `priority`: SCHED_FIFO priority of the peer's thread, 0 for normal.
  // `arm_serial_peer`: the serial line's far end when the arm's transport is serial.
  HilPeer(const host::CellConfig& config, std::string gpio_sim_dir, const std::array<unsigned, host::kLineRoleCount>& offsets,
          int priority, std::string arm_serial_peer = {});
  ~HilPeer();
  HilPeer(const HilPeer&) = delete;
  HilPeer& operator=(const HilPeer&) = delete;

  // The PLC's inputs at rest (cycle enabled, e-stop released, no panel), the arm powered
  // up, the thread started: before the cell starts. Throws naming the file or interface.
  void start();
  // Joins the thread and closes the socket (the arm goes silent). Idempotent.
  void stop() noexcept;
  // The PLC drives an input to a logical level (active_low applied). Throws naming the file.
  void drive(host::LineRole role, bool logical);

  // After stop(): each valve opening with the arm's tool pose then, ...
  const sim::NozzleWitness& nozzle() const { return nozzle_; }
  // ... the commands the controller sent and the valve's edges, times from `epoch`, ...
  sim::CommandLogText command_log_text(Nanos epoch, std::string_view interface) const { return log_.text(epoch, interface); }
  // ... ticks that began more than a period late, whether the priority was refused, and
  // what stopped the thread early (empty when nothing did).
  std::uint64_t late_ticks() const { return late_ticks_; }
  bool priority_refused() const { return priority_refused_; }
  const std::string& error() const { return error_; }

 private:
  // The peer's socket, every frame it receives (the controller's) kept in the log.
  class TappedBus final : public drivers::CanBus {
   public:
    TappedBus(drivers::SocketCanConfig config, sim::CommandLog& log) : bus_(std::move(config)), log_(log) {}
    void open() override { bus_.open(); }
    void close() noexcept override { bus_.close(); }
    bool is_open() const override { return bus_.is_open(); }
    drivers::CanStatus send(const drivers::CanFrame& frame) noexcept override { return bus_.send(frame); }
    int receive(std::span<drivers::CanFrame> out, Nanos timeout) noexcept override;

   private:
    drivers::SocketCanBus bus_;
    sim::CommandLog& log_;
  };
  std::string attribute(host::LineRole role, const char* name) const;
  void run() noexcept;
  static void tap_serial(void* peer, Nanos time, const drivers::serial::Frame& frame) noexcept {
    static_cast<HilPeer*>(peer)->log_.frame(time, frame);
  }

  const host::CellConfig& config_;
  const std::string dir_;
  const std::array<unsigned, host::kLineRoleCount> offsets_;
  const int priority_;
  const std::string serial_peer_;
  sim::CommandLog log_;
  // One arm, on the transport the cell is configured for.
  std::optional<TappedBus> bus_;
  std::optional<drivers::SimCanArm> can_arm_;
  std::optional<drivers::SimSerialArm> serial_arm_;
  int valve_fd_ = -1;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  sim::NozzleWitness nozzle_;
  std::uint64_t late_ticks_ = 0;
  bool priority_refused_ = false;
  std::string error_;
};

}  // namespace markcell::rig
