#include "markcell/drivers/serial_port.hpp"
#include "markcell/common/wait.hpp"

#include <fcntl.h>
#include <poll.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <stdexcept>
#include <system_error>

namespace markcell::drivers {

namespace {
speed_t to_speed(int baud) {
  switch (baud) {
    case 9600: return B9600;
    case 19200: return B19200;
    case 38400: return B38400;
    case 57600: return B57600;
    case 115200: return B115200;
    case 230400: return B230400;
    case 460800: return B460800;
    case 500000: return B500000;
    case 921600: return B921600;
    case 1000000: return B1000000;
    default: throw std::invalid_argument("serial: baud " + std::to_string(baud) + " is not a termios rate");
  }
}
}  // namespace

void SerialPort::open(const std::string& device, int baud) {
  close();
  const speed_t speed = to_speed(baud);
  const int fd = ::open(device.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) throw std::system_error(errno, std::generic_category(), "serial device '" + device + "': open");
  termios tio{};
  if (tcgetattr(fd, &tio) != 0) {
    const int err = errno;
    ::close(fd);
    throw std::system_error(err, std::generic_category(), "serial device '" + device + "': not a terminal (tcgetattr)");
  }
  cfmakeraw(&tio);
  tio.c_cflag |= CLOCAL | CREAD;
  tio.c_cflag &= ~static_cast<tcflag_t>(CSTOPB | CRTSCTS);
  tio.c_iflag &= ~static_cast<tcflag_t>(IXON | IXOFF | IXANY);
  tio.c_cc[VMIN] = 0;
  tio.c_cc[VTIME] = 0;
  cfsetispeed(&tio, speed);
  cfsetospeed(&tio, speed);
  if (tcsetattr(fd, TCSANOW, &tio) != 0) {
    const int err = errno;
    ::close(fd);
    throw std::system_error(err, std::generic_category(), "serial device '" + device + "': tcsetattr");
  }
  tcflush(fd, TCIOFLUSH);
  fd_ = fd;
}

void SerialPort::close() noexcept {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

long SerialPort::write_some(std::span<const std::uint8_t> bytes) noexcept {
  if (fd_ < 0) return -1;
  const ssize_t n = ::write(fd_, bytes.data(), bytes.size());
  if (n < 0) return errno == EAGAIN ? 0 : -1;
  return n;
}

long SerialPort::read_some(std::span<std::uint8_t> out, Nanos timeout) noexcept {
  if (fd_ < 0) return -1;
  const WaitResult w = wait_readable(fd_, timeout);
  if (w == WaitResult::kTimeout) return 0;
  if (w != WaitResult::kReadable) return -1;  // the peer hung up, or the descriptor failed
  const ssize_t n = ::read(fd_, out.data(), out.size());
  if (n < 0) return errno == EAGAIN ? 0 : -1;
  return n;
}

}  // namespace markcell::drivers
