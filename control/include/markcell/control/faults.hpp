#pragma once
// Faults: what went wrong, where and when, recorded without allocating from any lane.
// The fault log is a bounded multi-producer queue (Vyukov): producers never block; when
// it is full the fault is counted as dropped, never silently lost. One consumer (the
// service's logger, or a report) drains it off the real-time path.
#include <array>
#include <atomic>
#include <cstdint>
#include <string_view>

#include "markcell/common/fixed_string.hpp"
#include "markcell/common/time.hpp"

namespace markcell::control {

enum class FaultCode : std::uint8_t {
  kNone = 0,
  kTaskOverrun,      // a task ran longer than its budget
  kTaskFault,        // a task reported a fault
  kLaneStall,        // a lane stopped ticking
  kDeviceFault,      // a device reported a fault or went silent
  kOperatorStop,     // e-stop, line stop, PLC fault request
  kShutdown,         // SIGTERM / SIGINT: the orderly stop also goes through safe stop
  kFrameDropped,     // a camera pair could not be used (the detail names the frame)
  kInputGlitch,      // a PLC input pulsed shorter than its filter (ignored, reported)
  kRearm,            // the cell re-armed after a safe stop the PLC caused (or was refused)
};
std::string_view to_string(FaultCode code);

struct Fault {
  Nanos time = 0;                 // on the executive's clock
  FaultCode code = FaultCode::kNone;
  FixedString<31> source;         // task, lane or device name
  FixedString<119> detail;        // what happened, with the values involved
};

class FaultLog {
 public:
  static constexpr std::size_t kCapacity = 1024;  // power of two
  FaultLog();
  bool push(const Fault& fault) noexcept;         // false (and counted) when full
  bool pop(Fault& out) noexcept;                  // single consumer
  std::uint64_t recorded() const { return recorded_.load(std::memory_order_relaxed); }
  std::uint64_t dropped() const { return dropped_.load(std::memory_order_relaxed); }

 private:
  struct Cell {
    std::atomic<std::size_t> sequence;
    Fault fault;
  };
  std::array<Cell, kCapacity> cells_;
  alignas(64) std::atomic<std::size_t> enqueue_{0};
  alignas(64) std::atomic<std::size_t> dequeue_{0};
  std::atomic<std::uint64_t> recorded_{0};
  std::atomic<std::uint64_t> dropped_{0};
};

// A device output that has a safe state: valve closed, arm held, PLC fault line set.
// enter_safe_state() is called from whichever lane triggers the stop: it must be bounded,
// non-blocking and allocation-free.
class SafeOutput {
 public:
  virtual ~SafeOutput() = default;
  virtual std::string_view name() const = 0;
  virtual void enter_safe_state() noexcept = 0;
};

// The one safe-stop path used by every fault. The first trigger wins: it records the
// reason, puts every registered output in its safe state (in registration order) and
// latches. Later triggers are still recorded in the fault log.
//
// Re-arming (docs/safety.md): only a stop the PLC caused (kOperatorStop) and during
// which nothing else went wrong is recoverable. The PLC asks (request_rearm, from the
// plc_io task: e-stop released, then its reset edge); the arm link's task sends the arm
// home and, once it reports home, re-arms (rearm). Any other stop stays latched until
// the process restarts: the service exits non-zero and systemd restarts it.
class SafeStop {
 public:
  static constexpr int kMaxOutputs = 16;
  explicit SafeStop(FaultLog& log) : log_(log) {}

  void add_output(SafeOutput& output);  // start-up only
  // Returns true when this call performed the stop.
  bool trigger(Nanos time, FaultCode code, std::string_view source, std::string_view detail) noexcept;
  // True from the first trigger on (outputs may still be being driven).
  bool active() const { return state_.load(std::memory_order_acquire) != kIdle; }
  // True once every output is in its safe state; reason() is valid from then on.
  bool done() const { return state_.load(std::memory_order_acquire) == kStopped; }
  const Fault& reason() const { return reason_; }
  FaultLog& log() { return log_; }
  // Stops performed since start (a new one after each re-arm).
  std::uint64_t stops() const { return stops_.load(std::memory_order_acquire); }
  // The stop in force can be re-armed: the PLC caused it and no other trigger came since.
  bool recoverable() const {
    return done() && reason_.code == FaultCode::kOperatorStop && !unrecoverable_.load(std::memory_order_acquire);
  }
  // A trigger other than the PLC's or the shutdown's came since start: the process must restart.
  bool internal_fault() const { return unrecoverable_.load(std::memory_order_acquire); }
  void request_rearm() noexcept {
    if (recoverable()) rearm_requested_.store(true, std::memory_order_release);
  }
  bool rearm_requested() const { return rearm_requested_.load(std::memory_order_acquire); }
  void cancel_rearm(Nanos time, std::string_view detail) noexcept;
  // Back to running (the outputs stay in their safe state until their tasks drive them):
  // true when re-armed; false when the stop is not recoverable (any more).
  bool rearm(Nanos time, std::string_view detail) noexcept;

 private:
  enum : int { kIdle = 0, kStopping = 1, kStopped = 2 };
  void log_rearm(Nanos time, std::string_view detail) noexcept;
  FaultLog& log_;
  std::array<SafeOutput*, kMaxOutputs> outputs_{};
  int output_count_ = 0;
  std::atomic<int> state_{kIdle};
  std::atomic<std::uint64_t> stops_{0};
  std::atomic<bool> unrecoverable_{false};
  std::atomic<bool> rearm_requested_{false};
  Fault reason_;
};

}  // namespace markcell::control
