#include "markcell/drivers/gpio.hpp"

#include <stdexcept>

namespace markcell::drivers {

void SimGpioLines::configure(const std::vector<LineRequest>& requests) {
  if (active_) throw std::logic_error("gpio (simulated): configure while active");
  if (requests.empty() || requests.size() > static_cast<std::size_t>(kMaxGpioLines))
    throw std::invalid_argument("gpio (simulated): " + std::to_string(requests.size()) + " lines requested, 1.." +
                                std::to_string(kMaxGpioLines) + " supported");
  for (std::size_t i = 0; i < requests.size(); ++i) {
    if (requests[i].name.empty()) throw std::invalid_argument("gpio (simulated): line " + std::to_string(i) + " has no name");
    for (std::size_t j = 0; j < i; ++j)
      if (requests[j].name == requests[i].name)
        throw std::invalid_argument("gpio (simulated): line '" + requests[i].name + "' requested twice");
  }
  requests_ = requests;
  // Inputs rest at their inactive physical level until driven.
  for (std::size_t i = 0; i < requests_.size(); ++i) physical_[i].store(requests_[i].active_low);
}

void SimGpioLines::activate() {
  if (requests_.empty()) throw std::logic_error("gpio (simulated): activate before configure");
  active_ = true;
  pending_count_ = 0;
  outputs_to_safe_state();
}

void SimGpioLines::deactivate() {
  if (!active_) return;
  outputs_to_safe_state();
  active_ = false;
}

int SimGpioLines::find(const std::string& name) const {
  for (std::size_t i = 0; i < requests_.size(); ++i)
    if (requests_[i].name == name) return static_cast<int>(i);
  return -1;
}

void SimGpioLines::record_output(int line, bool active) noexcept {
  const std::size_t slot = history_count_.fetch_add(1, std::memory_order_acq_rel);
  if (slot < kHistory) history_[slot] = Edge{line, active, stamp()};
}

GpioStatus SimGpioLines::set(int line, bool active) noexcept {
  if (!active_) return GpioStatus::kNotActive;
  if (line < 0 || static_cast<std::size_t>(line) >= requests_.size()) return GpioStatus::kBadLine;
  const LineRequest& r = requests_[static_cast<std::size_t>(line)];
  if (!r.output) return GpioStatus::kWrongDirection;
  const bool high = active != r.active_low;
  if (physical_[static_cast<std::size_t>(line)].exchange(high, std::memory_order_acq_rel) != high) record_output(line, active);
  return GpioStatus::kOk;
}

GpioStatus SimGpioLines::get(int line, bool& active) noexcept {
  if (!active_) return GpioStatus::kNotActive;
  if (line < 0 || static_cast<std::size_t>(line) >= requests_.size()) return GpioStatus::kBadLine;
  active = physical_[static_cast<std::size_t>(line)].load(std::memory_order_acquire) != requests_[static_cast<std::size_t>(line)].active_low;
  return GpioStatus::kOk;
}

void SimGpioLines::drive_physical(int line, bool high) noexcept {
  if (line < 0 || static_cast<std::size_t>(line) >= requests_.size()) return;
  const LineRequest& r = requests_[static_cast<std::size_t>(line)];
  if (r.output || physical_[static_cast<std::size_t>(line)].exchange(high) == high) return;
  if (!active_) return;
  if (pending_count_ == pending_.size()) {  // overflow: the oldest edge goes, as a kernel FIFO does
    pending_head_ = (pending_head_ + 1) % pending_.size();
    --pending_count_;
  }
  pending_[(pending_head_ + pending_count_) % pending_.size()] = LineEvent{line, high != r.active_low, stamp()};
  ++pending_count_;
}

int SimGpioLines::read_events(std::span<LineEvent> out, Nanos) noexcept {
  // The simulated far side is driven between ticks, never concurrently: nothing to wait for.
  int n = 0;
  while (pending_count_ > 0 && static_cast<std::size_t>(n) < out.size()) {
    out[static_cast<std::size_t>(n++)] = pending_[pending_head_];
    pending_head_ = (pending_head_ + 1) % pending_.size();
    --pending_count_;
  }
  return n;
}

void SimGpioLines::outputs_to_safe_state() noexcept {
  for (std::size_t i = 0; i < requests_.size(); ++i)
    if (requests_[i].output) set(static_cast<int>(i), requests_[i].safe_active);
}

}  // namespace markcell::drivers
