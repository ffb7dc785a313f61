#pragma once
// A serial line through termios: raw mode (no echo, no line discipline, no flow
// control, 8N1), the configured baud, non-blocking; reads wait at most a given timeout.
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>

#include "markcell/common/time.hpp"

namespace markcell::drivers {

class SerialPort {
 public:
  SerialPort() = default;
  ~SerialPort() { close(); }
  SerialPort(const SerialPort&) = delete;
  SerialPort& operator=(const SerialPort&) = delete;

  // Throws std::system_error naming the device; std::invalid_argument for a baud rate
  // termios does not have.
  void open(const std::string& device, int baud);
  void close() noexcept;
  bool is_open() const { return fd_ >= 0; }
  int fd() const { return fd_; }

  // Writes what the kernel takes now; returns bytes written, -1 on error.
  long write_some(std::span<const std::uint8_t> bytes) noexcept;
  // Waits at most `timeout` for data, then reads what is there; returns bytes read,
  // 0 on timeout, -1 on error or hang-up (the peer went away).
  long read_some(std::span<std::uint8_t> out, Nanos timeout) noexcept;

 private:
  int fd_ = -1;
};

}  // namespace markcell::drivers
