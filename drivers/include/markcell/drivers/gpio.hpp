#pragma once
// GPIO lines of the cell: spray valve, camera trigger, PLC inputs and outputs.
//
// Lines are addressed by the index of their request. Values are *logical* (active or
// not); the active-low inversion is applied by the driver, once, from the request.
// Lifecycle as ros2_control's hardware interfaces: configure (check the requests),
// activate (take the lines; outputs start in their safe state), deactivate (outputs back
// to their safe state, lines released). After activate nothing allocates.
#include <array>
#include <atomic>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "markcell/common/fixed_string.hpp"
#include "markcell/common/time.hpp"

namespace markcell::drivers {

inline constexpr int kMaxGpioLines = 16;

struct LineRequest {
  std::string name;          // line name (or number) on the chip
  bool output = false;
  bool active_low = false;
  bool safe_active = false;  // the output's safe state (valve: inactive = closed)
};

struct LineEvent {
  int line = 0;       // request index
  bool active = false;  // logical level after the edge
  Nanos time = 0;     // kernel timestamp (real) or simulated time
};

enum class GpioStatus : std::uint8_t { kOk, kNotActive, kBadLine, kWrongDirection, kIoError };

class GpioLines {
 public:
  virtual ~GpioLines() = default;
  virtual void configure(const std::vector<LineRequest>& requests) = 0;  // throws with the line named
  virtual void activate() = 0;
  virtual void deactivate() = 0;
  virtual bool active() const = 0;

  virtual GpioStatus set(int line, bool active) noexcept = 0;
  virtual GpioStatus get(int line, bool& active) noexcept = 0;
  // Drains up to out.size() input edges seen since the last call, oldest first; waits at
  // most `timeout` for the first one (0: do not wait). Returns how many were written.
  virtual int read_events(std::span<LineEvent> out, Nanos timeout) noexcept = 0;
  // All outputs to their safe state (used by the safe stop; bounded, no allocation).
  virtual void outputs_to_safe_state() noexcept = 0;
};

// The simulated twin: the same contract, with the far side of every line reachable so
// the rig (and tests) can drive the PLC inputs and see what the cell drives. Physical
// levels are kept as on a wire: active-low lines read inverted, as on the real chip.
// Like the kernel's line handles, set/get may be called from any lane (a safe stop
// triggered by the supervisor drives the outputs from its own lane): levels are atomic
// and the output history is claimed slot by slot.
class SimGpioLines final : public GpioLines {
 public:
  static constexpr std::size_t kHistory = 4096;  // recorded output edges

  void configure(const std::vector<LineRequest>& requests) override;
  void activate() override;
  void deactivate() override;
  bool active() const override { return active_; }
  GpioStatus set(int line, bool active) noexcept override;
  GpioStatus get(int line, bool& active) noexcept override;
  int read_events(std::span<LineEvent> out, Nanos timeout) noexcept override;
  void outputs_to_safe_state() noexcept override;

  // --- the far side (rig, tests) ---
  // Time stamps for recorded edges come from here (the executive's clock in a rig run).
  void set_time_source(Nanos (*now)(void*), void* user) { now_ = now; now_user_ = user; }
  // Drives an input's physical level as a PLC would (true = high).
  void drive_physical(int line, bool high) noexcept;
  bool physical(int line) const { return physical_[static_cast<std::size_t>(line)].load(std::memory_order_acquire); }
  int find(const std::string& name) const;  // request index, -1 when unknown
  // Output edges (logical levels), oldest first; history beyond kHistory is counted.
  struct Edge { int line; bool active; Nanos time; };
  std::span<const Edge> output_history() const {
    const std::size_t n = history_count_.load(std::memory_order_acquire);
    return {history_.data(), n < kHistory ? n : kHistory};
  }
  std::size_t history_dropped() const {
    const std::size_t n = history_count_.load(std::memory_order_acquire);
    return n > kHistory ? n - kHistory : 0;
  }

 private:
  Nanos stamp() const { return now_ != nullptr ? now_(now_user_) : monotonic_now(); }
  void record_output(int line, bool active) noexcept;

  std::vector<LineRequest> requests_;
  std::array<std::atomic<bool>, kMaxGpioLines> physical_{};
  bool active_ = false;
  std::array<LineEvent, 256> pending_{};
  std::size_t pending_head_ = 0, pending_count_ = 0;
  std::array<Edge, kHistory> history_{};
  std::atomic<std::size_t> history_count_{0};
  Nanos (*now_)(void*) = nullptr;
  void* now_user_ = nullptr;
};

}  // namespace markcell::drivers
