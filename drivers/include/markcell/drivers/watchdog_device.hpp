#pragma once
// The Linux watchdog device (/dev/watchdog, or a configured path): once opened, the
// kernel (or the watchdog chip) resets the machine unless it is fed within its timeout.
// The executive's supervisor feeds it only while every lane is alive. A clean shutdown
// writes the magic 'V' before closing, so an orderly stop does not reset the machine;
// a crash or a hang does.
#include <string>
#include <string_view>

#include "markcell/common/param.hpp"
#include "markcell/common/time.hpp"

namespace markcell::drivers {

struct WatchdogDeviceConfig {
  std::string path = "/dev/watchdog";
  int timeout_s = 0;  // 0: keep the device's own timeout; else WDIOC_SETTIMEOUT

  template <class V>
  void Visit(V& v) {
    v(Param{"path", Unit::kNone, 1, 255, "the watchdog device", true}, path);
    v(Param{"timeout_s", Unit::kNone, 0, 3600, "the device's timeout in seconds; 0 keeps its own", true}, timeout_s);
  }
};

class WatchdogDevice {
 public:
  explicit WatchdogDevice(WatchdogDeviceConfig config) : config_(std::move(config)) {}
  ~WatchdogDevice();
  WatchdogDevice(const WatchdogDevice&) = delete;
  WatchdogDevice& operator=(const WatchdogDevice&) = delete;

  // Lifecycle: activate() opens and arms it (throws std::system_error naming the path);
  // deactivate() disarms it with the magic close.
  void activate();
  void deactivate();
  bool active() const { return fd_ >= 0; }

  // Real-time safe: one write(2) of one byte, no allocation. Returns false on error.
  bool feed() noexcept;
  int timeout_s() const { return effective_timeout_s_; }
  const std::string& path() const { return config_.path; }

 private:
  WatchdogDeviceConfig config_;
  int fd_ = -1;
  int effective_timeout_s_ = 0;
};

}  // namespace markcell::drivers
