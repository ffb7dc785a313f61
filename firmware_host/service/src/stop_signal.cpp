#include "markcell/host/stop_signal.hpp"

#include <unistd.h>

#include <cstdlib>
#include <ctime>

namespace markcell::host {

StopSignalWatcher::StopSignalWatcher(const sigset_t& signals, std::chrono::milliseconds grace)
    : signals_(signals), grace_(grace) {
  thread_ = std::thread([this] {
    using Clock = std::chrono::steady_clock;
    Clock::time_point asked{};
    while (!quit_.load(std::memory_order_acquire)) {
      const timespec wait{0, 100'000'000};
      const int sig = sigtimedwait(&signals_, nullptr, &wait);
      // EAGAIN: the wait timed out; EINTR: another signal interrupted it. Either way the
      // loop looks at quit_ again.
      const int first = signal_.load(std::memory_order_acquire);
      if (sig > 0 && first == 0) {
        signal_.store(sig, std::memory_order_release);
        asked = Clock::now();
      } else if (first != 0 && (sig > 0 || Clock::now() - asked > grace_)) {
        const char msg[] = "markcell: not stopped in time after the signal (or signalled again): ended now\n";
        [[maybe_unused]] const auto n = write(STDERR_FILENO, msg, sizeof msg - 1);
        std::_Exit(128 + first);
      }
    }
  });
}

StopSignalWatcher::~StopSignalWatcher() {
  quit_.store(true, std::memory_order_release);
  if (thread_.joinable()) thread_.join();
}

std::string signal_name(int signal) {
  if (signal == SIGTERM) return "SIGTERM";
  if (signal == SIGINT) return "SIGINT";
  return "signal " + std::to_string(signal);
}

}  // namespace markcell::host
