#pragma once
// One bounded wait for a file descriptor to become readable, shared by the transports.
#include <poll.h>

#include <cerrno>

#include "markcell/common/time.hpp"

namespace markcell {

enum class WaitResult : std::uint8_t { kReadable, kTimeout, kHangup, kError };

// Waits at most `timeout` (0: just looks). A signal counts as a time-out: the caller
// comes back on its next cycle anyway.
inline WaitResult wait_readable(int fd, Nanos timeout) noexcept {
  pollfd p{fd, POLLIN, 0};
  const timespec ts = to_timespec(timeout > 0 ? timeout : 0);
  const int ready = ppoll(&p, 1, &ts, nullptr);
  if (ready < 0) return errno == EINTR ? WaitResult::kTimeout : WaitResult::kError;
  if (ready == 0) return WaitResult::kTimeout;
  if ((p.revents & POLLIN) == 0 && (p.revents & (POLLHUP | POLLERR)) != 0) return WaitResult::kHangup;
  return WaitResult::kReadable;
}

}  // namespace markcell
