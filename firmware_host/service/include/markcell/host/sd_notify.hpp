#pragma once
// systemd's notify protocol through libsystemd's sd_notify: READY=1 once start-up is
// done, WATCHDOG=1 from the executive's supervisor only while every lane is alive,
// STOPPING=1 at shutdown. Outside systemd (no NOTIFY_SOCKET) every call is a no-op.
#include <string_view>

#include "markcell/common/time.hpp"
#include "markcell/control/executive.hpp"

namespace markcell::host {

class SystemdNotifier final : public control::WatchdogSink {
 public:
  // The feed interval is half of systemd's WatchdogSec (WATCHDOG_USEC) when systemd
  // asks for a watchdog, else `fallback_interval`.
  explicit SystemdNotifier(Nanos fallback_interval);
  bool under_systemd() const { return under_systemd_; }
  bool watchdog_requested() const { return watchdog_requested_; }
  Nanos interval() const { return interval_; }

  void ready();
  void stopping();
  void reloading();  // RELOADING=1: READY=1 follows when the reload is done (or refused)
  void status(std::string_view text);

  std::string_view name() const override { return "systemd"; }
  void feed(Nanos now) noexcept override;

 private:
  bool under_systemd_ = false;
  bool watchdog_requested_ = false;
  Nanos interval_;
  Nanos last_feed_ = 0;
  bool fed_once_ = false;
};

}  // namespace markcell::host
