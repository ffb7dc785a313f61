#include "markcell/host/sd_notify.hpp"

#include <systemd/sd-daemon.h>

#include <cstdlib>
#include <string>

namespace markcell::host {

SystemdNotifier::SystemdNotifier(Nanos fallback_interval) : interval_(fallback_interval) {
  under_systemd_ = std::getenv("NOTIFY_SOCKET") != nullptr;
  std::uint64_t usec = 0;
  if (sd_watchdog_enabled(0, &usec) > 0 && usec > 0) {
    watchdog_requested_ = true;
    interval_ = static_cast<Nanos>(usec) * kNanosPerMicro / 2;
  }
}

void SystemdNotifier::ready() { sd_notify(0, "READY=1"); }
void SystemdNotifier::stopping() { sd_notify(0, "STOPPING=1"); }
void SystemdNotifier::reloading() { sd_notify(0, "RELOADING=1"); }
void SystemdNotifier::status(std::string_view text) {
  const std::string msg = "STATUS=" + std::string(text);
  sd_notify(0, msg.c_str());
}

void SystemdNotifier::feed(Nanos now) noexcept {
  if (fed_once_ && now - last_feed_ < interval_) return;
  sd_notify(0, "WATCHDOG=1");
  last_feed_ = now;
  fed_once_ = true;
}

}  // namespace markcell::host
