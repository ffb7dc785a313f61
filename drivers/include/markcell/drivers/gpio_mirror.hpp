#pragma once
// Any GpioLines with each line's last known logical level kept in one atomic word, for a
// reader off the lanes: the PLC's Modbus status word mirrors the cell's I/O lines
// (docs/line.md). A level is known once set or read (a get, an input edge); a safe stop's
// outputs_to_safe_state sets the outputs' bits to their safe levels. Bounded, no
// allocation after configure, callable from any lane as the lines it wraps.
#include <atomic>
#include <cstdint>

#include "markcell/drivers/gpio.hpp"

namespace markcell::drivers {

class MirroredGpioLines final : public GpioLines {
 public:
  explicit MirroredGpioLines(GpioLines& inner) : inner_(inner) {}

  void configure(const std::vector<LineRequest>& requests) override {
    inner_.configure(requests);
    std::uint32_t outputs = 0, safe = 0;
    for (std::size_t i = 0; i < requests.size() && i < 32; ++i) {
      if (!requests[i].output) continue;
      outputs |= 1u << i;
      if (requests[i].safe_active) safe |= 1u << i;
    }
    outputs_ = outputs;
    safe_ = safe;
  }
  void activate() override {
    inner_.activate();
    levels_.store(safe_, std::memory_order_relaxed);  // outputs start in their safe state
  }
  void deactivate() override { inner_.deactivate(); }
  bool active() const override { return inner_.active(); }
  GpioStatus set(int line, bool active) noexcept override {
    const GpioStatus s = inner_.set(line, active);
    if (s == GpioStatus::kOk) note(line, active);
    return s;
  }
  GpioStatus get(int line, bool& active) noexcept override {
    const GpioStatus s = inner_.get(line, active);
    if (s == GpioStatus::kOk) note(line, active);
    return s;
  }
  int read_events(std::span<LineEvent> out, Nanos timeout) noexcept override {
    const int n = inner_.read_events(out, timeout);
    for (int i = 0; i < n; ++i) note(out[static_cast<std::size_t>(i)].line, out[static_cast<std::size_t>(i)].active);
    return n;
  }
  void outputs_to_safe_state() noexcept override {
    inner_.outputs_to_safe_state();
    std::uint32_t cur = levels_.load(std::memory_order_relaxed);
    while (!levels_.compare_exchange_weak(cur, (cur & ~outputs_) | safe_, std::memory_order_relaxed)) {
    }
  }
  // Bit i: line i's last known logical level (request order).
  std::uint32_t levels() const { return levels_.load(std::memory_order_relaxed); }

 private:
  void note(int line, bool active) noexcept {
    if (line < 0 || line >= 32) return;
    const std::uint32_t bit = 1u << line;
    if (active) levels_.fetch_or(bit, std::memory_order_relaxed);
    else levels_.fetch_and(~bit, std::memory_order_relaxed);
  }
  GpioLines& inner_;
  std::uint32_t outputs_ = 0, safe_ = 0;
  std::atomic<std::uint32_t> levels_{0};
};

}  // namespace markcell::drivers
