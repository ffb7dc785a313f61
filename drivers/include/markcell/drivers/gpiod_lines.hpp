#pragma once
// GPIO lines on a real GPIO chip through libgpiod 1.6 (the kernel's GPIO character
// device, v1 uAPI).
//
// libgpiod's C API is used throughout, not its C++ bindings: in 1.6 the bindings'
// line::set_value / get_value / event_wait build a std::vector-backed line_bulk on every
// call, and these run every tick. The C calls below allocate nothing after activate().
//
// Lines are found by name (gpioinfo shows them) or by offset (a decimal number). Outputs
// are requested already in their safe state, so there is no glitch at start; active-low
// is handled by the kernel (GPIOHANDLE_REQUEST_ACTIVE_LOW), so values here are logical.
// Input edges carry the kernel's CLOCK_MONOTONIC timestamps.
//
// What the kernel does with a line when its holder goes away (process killed, or
// deactivate): the request is released and the line keeps driving its last value until
// someone else requests it. It does NOT return to a safe level by itself, which is why
// the valve must be normally closed in hardware (README, "Safety note").
#include <array>
#include <string>
#include <vector>

#include <poll.h>

#include "markcell/drivers/gpio.hpp"

struct gpiod_chip;
struct gpiod_line;

namespace markcell::drivers {

class GpiodLines final : public GpioLines {
 public:
  // `chip`: name (gpiochip0), number, label or path, as gpiod_chip_open_lookup takes it.
  explicit GpiodLines(std::string chip, std::string consumer = "markcell");
  ~GpiodLines() override;

  void configure(const std::vector<LineRequest>& requests) override;
  void activate() override;
  void deactivate() override;
  bool active() const override { return active_; }
  GpioStatus set(int line, bool active) noexcept override;
  GpioStatus get(int line, bool& active) noexcept override;
  int read_events(std::span<LineEvent> out, Nanos timeout) noexcept override;
  void outputs_to_safe_state() noexcept override;

  const std::string& chip_name() const { return chip_name_; }
  unsigned offset(int line) const;

 private:
  void close_chip() noexcept;
  std::string chip_name_;
  std::string consumer_;
  std::vector<LineRequest> requests_;
  gpiod_chip* chip_ = nullptr;
  std::array<gpiod_line*, kMaxGpioLines> lines_{};
  std::array<pollfd, kMaxGpioLines> poll_{};       // input lines' event fds
  std::array<int, kMaxGpioLines> poll_line_{};     // request index of each poll entry
  int poll_count_ = 0;
  bool active_ = false;
};

}  // namespace markcell::drivers
