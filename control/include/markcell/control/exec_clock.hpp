#pragma once
// The executive's injected clock. Lanes ask it for the time and sleep on it; nothing else
// in the executive reads a clock, which is what makes a simulated run deterministic.
//
//  - RealClock: CLOCK_MONOTONIC and clock_nanosleep(TIMER_ABSTIME).
//  - SimClock:  a discrete-event turnstile. Simulated time advances only when every lane
//    is waiting; then the lane with the earliest wake-up (ties: the lowest lane index)
//    runs alone. Each lane has its own busy cursor (`consume`), so an overrunning lane
//    delays itself and not the others, as on separate cores. Same inputs, same order of
//    execution, same trace, faster than real time.
#include <array>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <mutex>

#include "markcell/common/time.hpp"

namespace markcell::control {

inline constexpr int kMaxLanes = 8;

enum class WakeResult : std::uint8_t { kReleased, kStopped };

class ExecClock {
 public:
  virtual ~ExecClock() = default;
  virtual bool simulated() const = 0;
  // Time as seen by `lane` (in a simulated run, including the time it has consumed).
  virtual Nanos now(int lane) const = 0;
  // The calling thread's own CPU time (a task's execution time: what it computed, not
  // the time the kernel or the hypervisor kept it off its core, which the lane's wake
  // latency and deadline misses measure). Simulated: the same as now().
  virtual Nanos cpu_now(int lane) const { return now(lane); }
  // Blocks `lane` until `t`. Returns kStopped, early, once stop() was called.
  virtual WakeResult sleep_until(int lane, Nanos t) = 0;
  // Models execution time in a simulated run; nothing on the real clock (real work takes
  // real time by itself).
  virtual void consume(int lane, Nanos duration) = 0;
  virtual void stop() = 0;
};

class RealClock final : public ExecClock {
 public:
  bool simulated() const override { return false; }
  Nanos now(int) const override { return monotonic_now(); }
  Nanos cpu_now(int) const override;
  WakeResult sleep_until(int lane, Nanos t) override;
  void consume(int, Nanos) override {}
  void stop() override { stopped_.store(true, std::memory_order_release); }

 private:
  std::atomic<bool> stopped_{false};
};

class SimClock final : public ExecClock {
 public:
  // `lanes`: how many lanes will sleep on this clock (all must, before time advances).
  // `wedge_timeout`: real (wall) time a running lane may take before the run is declared
  // wedged - the one guard against a task that blocks forever in a simulated run.
  SimClock(int lanes, Nanos start = 0, Nanos wedge_timeout = seconds(10));

  bool simulated() const override { return true; }
  Nanos now(int lane) const override;
  WakeResult sleep_until(int lane, Nanos t) override;
  void consume(int lane, Nanos duration) override;
  void stop() override;

  enum class RunResult : std::uint8_t { kReached, kStopped, kWedged };
  // Lets simulated time run up to and including `t_end`, then pauses. Returns when every
  // lane waits beyond t_end (kReached), the clock was stopped, or a lane held the
  // turnstile for longer than the wedge timeout in real time (kWedged).
  RunResult run_until(Nanos t_end);
  Nanos global_now() const;

 private:
  enum class LaneState : std::uint8_t { kNotArrived, kRunning, kWaiting };
  struct Lane {
    LaneState state = LaneState::kNotArrived;
    Nanos wake = 0;
    Nanos busy = 0;
    bool granted = false;
    std::condition_variable cv;
  };
  void dispatch_locked();  // grants the next lane, or pauses

  const int lanes_;
  const Nanos wedge_timeout_;
  mutable std::mutex mutex_;
  std::condition_variable controller_cv_;
  std::array<Lane, kMaxLanes> lane_{};
  Nanos now_;
  Nanos end_;
  int running_ = -1;
  bool paused_ = true;
  bool stopped_ = false;
  std::uint64_t grants_ = 0;
};

}  // namespace markcell::control
