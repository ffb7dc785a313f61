#pragma once
// CAN frames and the bus they travel on.
//
// CanBus is the seam between the arm link and the wire: SocketCanBus is the real
// SocketCAN raw socket (can0, vcan0, ...); SimCanWire joins two in-memory endpoints so
// the simulated arm and the link exchange the very same frames without a kernel.
#include <array>
#include <cstdint>
#include <span>
#include <string>

#include "markcell/common/time.hpp"

namespace markcell::drivers {

struct CanFrame {
  std::uint32_t id = 0;    // 11-bit, or 29-bit when extended
  std::uint8_t len = 0;    // 0..8 classic, 0..64 CAN FD
  bool extended = false;
  bool fd = false;
  bool error = false;      // an error frame (id holds the CAN_ERR_* class bits)
  std::array<std::uint8_t, 64> data{};
  Nanos time = 0;          // reception time (kernel timestamp or simulated)
};

enum class CanStatus : std::uint8_t { kOk, kWouldBlock, kNotOpen, kTooLong, kIoError };

class CanBus {
 public:
  virtual ~CanBus() = default;
  virtual void open() = 0;            // throws naming the interface
  virtual void close() noexcept = 0;
  virtual bool is_open() const = 0;
  virtual CanStatus send(const CanFrame& frame) noexcept = 0;
  // Waits at most `timeout` for the first frame, then drains what is there, up to
  // out.size(). Returns how many frames were written, or -1 on error.
  virtual int receive(std::span<CanFrame> out, Nanos timeout) noexcept = 0;
};

// Error classes carried in an error frame's id (linux/can/error.h values).
inline constexpr std::uint32_t kCanErrBusOff = 0x00000040U;
inline constexpr std::uint32_t kCanErrRestarted = 0x00000100U;
inline constexpr std::uint32_t kCanErrController = 0x00000004U;

struct SocketCanConfig {
  std::string interface = "can0";
  bool fd = false;
  // Accept only these ids (plus error frames); empty: everything.
  std::array<std::uint32_t, 16> filter_ids{};
  int filter_count = 0;
};

class SocketCanBus final : public CanBus {
 public:
  explicit SocketCanBus(SocketCanConfig config) : config_(std::move(config)) {}
  ~SocketCanBus() override { close(); }
  void open() override;
  void close() noexcept override;
  bool is_open() const override { return fd_ >= 0; }
  CanStatus send(const CanFrame& frame) noexcept override;
  int receive(std::span<CanFrame> out, Nanos timeout) noexcept override;
  std::uint64_t dropped() const { return dropped_; }
  std::uint64_t down_events() const { return down_events_; }  // the interface went down

 private:
  SocketCanConfig config_;
  int fd_ = -1;
  std::uint64_t dropped_ = 0;
  std::uint64_t down_events_ = 0;
};

// Two endpoints joined by an in-memory wire: what one sends, the other receives, in
// order. Single-threaded use (the simulated cell), bounded queues.
class SimCanWire {
 public:
  class End final : public CanBus {
   public:
    void open() override { open_ = true; }
    void close() noexcept override { open_ = false; }
    bool is_open() const override { return open_; }
    CanStatus send(const CanFrame& frame) noexcept override;
    int receive(std::span<CanFrame> out, Nanos timeout) noexcept override;
    // Puts a frame on this end's receive queue as if the bus delivered it (error
    // frames from the controller, for instance).
    void inject(const CanFrame& frame) noexcept;

   private:
    friend class SimCanWire;
    static constexpr std::size_t kQueue = 256;
    End* peer_ = nullptr;
    bool open_ = false;
    std::array<CanFrame, kQueue> queue_{};
    std::size_t head_ = 0, count_ = 0;
    std::uint64_t dropped_ = 0;
    Nanos (*now_)(void*) = nullptr;
    void* now_user_ = nullptr;
    void (*tap_)(void*, const CanFrame&, Nanos) = nullptr;
    void* tap_user_ = nullptr;
  };
  SimCanWire();
  End& a() { return a_; }
  End& b() { return b_; }
  // Reception timestamps come from here (default: CLOCK_MONOTONIC).
  void set_time_source(Nanos (*now)(void*), void* user);
  // Every frame sent from end a (the controller's), with the time it was sent: how the
  // rig keeps its command log. The tap must not allocate (it runs on the control lane).
  void set_tap(void (*tap)(void* user, const CanFrame& frame, Nanos time), void* user);

 private:
  End a_, b_;
};

}  // namespace markcell::drivers
