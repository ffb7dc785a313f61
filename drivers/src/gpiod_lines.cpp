#include "markcell/drivers/gpiod_lines.hpp"

#include <gpiod.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>
#include <system_error>

namespace markcell::drivers {

namespace {
bool is_offset(const std::string& s) {
  if (s.empty() || s.size() > 6) return false;
  for (char c : s)
    if (c < '0' || c > '9') return false;
  return true;
}
}  // namespace

GpiodLines::GpiodLines(std::string chip, std::string consumer)
    : chip_name_(std::move(chip)), consumer_(std::move(consumer)) {}

GpiodLines::~GpiodLines() {
  deactivate();
  close_chip();
}

void GpiodLines::close_chip() noexcept {
  if (chip_ != nullptr) gpiod_chip_close(chip_);
  chip_ = nullptr;
  lines_.fill(nullptr);
}

unsigned GpiodLines::offset(int line) const { return gpiod_line_offset(lines_[static_cast<std::size_t>(line)]); }

void GpiodLines::configure(const std::vector<LineRequest>& requests) {
  if (active_) throw std::logic_error("gpio chip '" + chip_name_ + "': configure while active");
  if (requests.empty() || requests.size() > static_cast<std::size_t>(kMaxGpioLines))
    throw std::invalid_argument("gpio chip '" + chip_name_ + "': " + std::to_string(requests.size()) +
                                " lines requested, 1.." + std::to_string(kMaxGpioLines) + " supported");
  close_chip();
  chip_ = gpiod_chip_open_lookup(chip_name_.c_str());
  if (chip_ == nullptr)
    throw std::system_error(errno, std::generic_category(), "gpio chip '" + chip_name_ + "': cannot open");
  for (std::size_t i = 0; i < requests.size(); ++i) {
    const std::string& name = requests[i].name;
    gpiod_line* line = is_offset(name) ? gpiod_chip_get_line(chip_, static_cast<unsigned>(std::stoul(name)))
                                       : gpiod_chip_find_line(chip_, name.c_str());
    if (line == nullptr) {
      const std::string chip = chip_name_;
      close_chip();
      throw std::invalid_argument("gpio chip '" + chip + "': no line " + (is_offset(name) ? "at offset " : "named '") +
                                  name + (is_offset(name) ? "" : "'") + " (gpioinfo " + chip + " lists its lines)");
    }
    for (std::size_t j = 0; j < i; ++j)
      if (lines_[j] == line) {
        close_chip();
        throw std::invalid_argument("gpio chip '" + chip_name_ + "': line '" + name + "' requested twice");
      }
    if (gpiod_line_is_used(line)) {
      const char* holder = gpiod_line_consumer(line);
      const std::string msg = "gpio chip '" + chip_name_ + "': line '" + name + "' is already used by '" +
                              (holder != nullptr ? holder : "the kernel") + "'";
      close_chip();
      throw std::runtime_error(msg);
    }
    lines_[i] = line;
  }
  requests_ = requests;
}

void GpiodLines::activate() {
  if (active_) return;
  if (chip_ == nullptr) throw std::logic_error("gpio chip '" + chip_name_ + "': activate before configure");
  poll_count_ = 0;
  for (std::size_t i = 0; i < requests_.size(); ++i) {
    const LineRequest& r = requests_[i];
    const int flags = r.active_low ? GPIOD_LINE_REQUEST_FLAG_ACTIVE_LOW : 0;
    const int rc = r.output
                       ? gpiod_line_request_output_flags(lines_[i], consumer_.c_str(), flags, r.safe_active ? 1 : 0)
                       : gpiod_line_request_both_edges_events_flags(lines_[i], consumer_.c_str(), flags);
    if (rc != 0) {
      const int err = errno;
      for (std::size_t j = 0; j < i; ++j) gpiod_line_release(lines_[j]);
      throw std::system_error(err, std::generic_category(),
                              "gpio chip '" + chip_name_ + "': request of line '" + r.name + "' as " +
                                  (r.output ? "output" : "edge-event input"));
    }
    if (!r.output) {
      poll_[static_cast<std::size_t>(poll_count_)] = pollfd{gpiod_line_event_get_fd(lines_[i]), POLLIN | POLLPRI, 0};
      poll_line_[static_cast<std::size_t>(poll_count_)] = static_cast<int>(i);
      ++poll_count_;
    }
  }
  active_ = true;
}

void GpiodLines::deactivate() {
  if (!active_) return;
  outputs_to_safe_state();
  for (std::size_t i = 0; i < requests_.size(); ++i) gpiod_line_release(lines_[i]);
  active_ = false;
  poll_count_ = 0;
}

GpioStatus GpiodLines::set(int line, bool value) noexcept {
  if (!active_) return GpioStatus::kNotActive;
  if (line < 0 || static_cast<std::size_t>(line) >= requests_.size()) return GpioStatus::kBadLine;
  if (!requests_[static_cast<std::size_t>(line)].output) return GpioStatus::kWrongDirection;
  return gpiod_line_set_value(lines_[static_cast<std::size_t>(line)], value ? 1 : 0) == 0 ? GpioStatus::kOk
                                                                                           : GpioStatus::kIoError;
}

GpioStatus GpiodLines::get(int line, bool& value) noexcept {
  if (!active_) return GpioStatus::kNotActive;
  if (line < 0 || static_cast<std::size_t>(line) >= requests_.size()) return GpioStatus::kBadLine;
  const int v = gpiod_line_get_value(lines_[static_cast<std::size_t>(line)]);
  if (v < 0) return GpioStatus::kIoError;
  value = v == 1;
  return GpioStatus::kOk;
}

int GpiodLines::read_events(std::span<LineEvent> out, Nanos timeout) noexcept {
  if (!active_ || poll_count_ == 0 || out.empty()) return 0;
  int n = 0;
  timespec ts = to_timespec(timeout > 0 ? timeout : 0);
  // Bounded: each pass reads at most one event per line, and there are at most
  // out.size() passes; only the first pass may wait.
  for (std::size_t pass = 0; pass < out.size() && static_cast<std::size_t>(n) < out.size(); ++pass) {
    const int ready = ppoll(poll_.data(), static_cast<nfds_t>(poll_count_), &ts, nullptr);
    ts = timespec{0, 0};
    if (ready <= 0) break;
    for (int p = 0; p < poll_count_ && static_cast<std::size_t>(n) < out.size(); ++p) {
      if ((poll_[static_cast<std::size_t>(p)].revents & (POLLIN | POLLPRI)) == 0) continue;
      gpiod_line_event ev{};
      if (gpiod_line_event_read_fd(poll_[static_cast<std::size_t>(p)].fd, &ev) != 0) continue;
      // With an active-low request the kernel reports edges of the logical value.
      out[static_cast<std::size_t>(n++)] =
          LineEvent{poll_line_[static_cast<std::size_t>(p)], ev.event_type == GPIOD_LINE_EVENT_RISING_EDGE,
                    from_timespec(ev.ts)};
    }
  }
  return n;
}

void GpiodLines::outputs_to_safe_state() noexcept {
  if (!active_) return;
  for (std::size_t i = 0; i < requests_.size(); ++i)
    if (requests_[i].output) gpiod_line_set_value(lines_[i], requests_[i].safe_active ? 1 : 0);
}

}  // namespace markcell::drivers
