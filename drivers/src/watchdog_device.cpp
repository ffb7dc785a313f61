#include "markcell/drivers/watchdog_device.hpp"

#include <fcntl.h>
#include <linux/watchdog.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include <cerrno>
#include <system_error>

namespace markcell::drivers {

WatchdogDevice::~WatchdogDevice() { deactivate(); }

void WatchdogDevice::activate() {
  if (fd_ >= 0) return;
  const int fd = ::open(config_.path.c_str(), O_WRONLY | O_CLOEXEC | O_NONBLOCK);
  if (fd < 0) throw std::system_error(errno, std::generic_category(), "watchdog device '" + config_.path + "': open");
  if (config_.timeout_s > 0) {
    int timeout = config_.timeout_s;
    if (::ioctl(fd, WDIOC_SETTIMEOUT, &timeout) != 0) {
      const int err = errno;
      // Disarm what we just armed before reporting: an opened watchdog is live.
      [[maybe_unused]] const auto n = ::write(fd, "V", 1);
      ::close(fd);
      throw std::system_error(err, std::generic_category(),
                              "watchdog device '" + config_.path + "': WDIOC_SETTIMEOUT " +
                                  std::to_string(config_.timeout_s) + " s (is it a watchdog device?)");
    }
    effective_timeout_s_ = timeout;  // the driver may round it
  }
  fd_ = fd;
}

bool WatchdogDevice::feed() noexcept {
  if (fd_ < 0) return false;
  // Any write feeds the watchdog; a zero byte is not the magic close character.
  return ::write(fd_, "\0", 1) == 1;
}

void WatchdogDevice::deactivate() {
  if (fd_ < 0) return;
  [[maybe_unused]] const auto n = ::write(fd_, "V", 1);  // magic close: disarm on purpose
  ::close(fd_);
  fd_ = -1;
}

}  // namespace markcell::drivers
