#pragma once
// The fixed-rate cyclic executive.
//
// One table declares every task: name, period and phase as multiples of the base tick,
// time budget, lane and overrun policy (from the cell configuration). A lane is one
// thread, pinned to a core at a SCHED_FIFO priority when permitted, that runs its due
// tasks in table order at each tick. Tasks exchange data across lanes only through
// wait-free buffers (markcell/common/triple_buffer.hpp); the lanes never take a lock.
// A supervisor lane checks that every lane keeps ticking and feeds the watchdogs (the
// systemd one, a hardware one) only while they all do.
//
// Storage is fixed at construction (kMaxLanes, kMaxTasks, histograms, trace); after
// start() nothing allocates.
#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "markcell/common/fixed_string.hpp"
#include "markcell/common/param.hpp"
#include "markcell/common/time.hpp"
#include "markcell/control/exec_clock.hpp"
#include "markcell/control/faults.hpp"
#include "markcell/control/histogram.hpp"

namespace markcell::control {

inline constexpr int kMaxTasks = 32;
// Task lanes; the supervisor takes one more clock lane (see clock_lanes()).
inline constexpr int kMaxTaskLanes = kMaxLanes - 1;
inline constexpr std::size_t kTraceCapacity = 1 << 14;

enum class OverrunPolicy : std::uint8_t {
  kLog,       // count it and record the fault
  kDegrade,   // also run the task at half rate until it is back within budget
  kSafeStop,  // also trigger the safe stop
};
std::string_view to_string(OverrunPolicy policy);

enum class TaskResult : std::uint8_t { kOk, kFault };

struct LaneSpec {
  std::string name;
  int core = -1;      // -1: any core
  int priority = 0;   // SCHED_FIFO priority 1..99; 0: the normal scheduler

  template <class V>
  void Visit(V& v) {
    v(Param{"core", Unit::kNone, -1, 1023, "the core the lane is pinned to; -1: any", true}, core);
    v(Param{"priority", Unit::kNone, 0, 99, "SCHED_FIFO priority 1..99; 0: the normal scheduler", true}, priority);
  }
};

struct TaskSpec {
  std::string name;
  int lane = 0;
  std::uint32_t period_ticks = 1;
  std::uint32_t phase_ticks = 0;
  Nanos budget = 0;
  OverrunPolicy overrun = OverrunPolicy::kLog;
};

struct ExecutiveSpec {
  Nanos tick = millis(1);
  std::vector<LaneSpec> lanes;
  std::vector<TaskSpec> tasks;
  Nanos lane_stall_limit = millis(100);
  Nanos supervisor_period = millis(10);
  int degrade_recovery_runs = 10;  // in-budget runs that end a degraded period
  bool lock_memory = true;         // mlockall when permitted
  bool trace = false;              // record every release and completion (tests, rig)

  // The `executive` section's own keys (its lanes and tasks are read as tables by the
  // configuration loader, which checks them against the cell's task table).
  template <class V>
  void Visit(V& v) {
    v(Param{"base_tick_us", Unit::kMicrosecond, 50, 1'000'000, "the fixed tick every period is a multiple of", true}, tick);
    v(Param{"lane_stall_ms", Unit::kMillisecond, 1, 60'000, "a lane that has not ticked for this long is stalled", true},
      lane_stall_limit);
    v(Param{"supervisor_period_ms", Unit::kMillisecond, 1, 10'000, "how often the supervisor checks the lanes", true},
      supervisor_period);
    v(Param{"degrade_recovery_runs", Unit::kNone, 1, 1'000'000, "in-budget runs that end a degraded task's half rate"},
      degrade_recovery_runs);
    v(Param{"lock_memory", Unit::kNone, 0, 0, "mlockall at start-up (needs CAP_IPC_LOCK; warned when refused)"},
      lock_memory);
  }
  template <class Report>
  void validate(Report&& report) const {
    if (supervisor_period * 2 > lane_stall_limit)
      report("supervisor_period_ms", "supervisor_period_ms " + std::to_string(supervisor_period / millis(1)) +
                                         " must be at most half of lane_stall_ms " +
                                         std::to_string(lane_stall_limit / millis(1)) +
                                         ", or a stall could go unseen for too long");
  }
};
// Throws CheckFailed naming the field when the spec is inconsistent (the configuration
// loader reports the same conditions with file positions before it gets here).
void validate(const ExecutiveSpec& spec);

class TaskContext;
using TaskFn = TaskResult (*)(TaskContext& ctx, void* user);

// Fed by the supervisor only while every lane is alive.
class WatchdogSink {
 public:
  virtual ~WatchdogSink() = default;
  virtual std::string_view name() const = 0;
  virtual void feed(Nanos now) noexcept = 0;
};

struct TraceEvent {
  enum Kind : std::uint8_t { kRelease, kComplete, kOverrun, kSkipped, kStall, kSafeStop };
  Nanos time;
  std::int16_t lane;
  std::int16_t task;  // -1 for lane-level events
  Kind kind;
  friend bool operator==(const TraceEvent&, const TraceEvent&) = default;
};

struct TaskStats {
  Histogram exec;                      // execution time: the lane thread's CPU time in the task
  // The longest a run took from its start to its end on the monotonic clock: the
  // execution time plus whatever kept the thread off its core meanwhile (interrupts, a
  // higher priority, the hypervisor).
  std::atomic<Nanos> wall_max{0};
  std::atomic<std::uint64_t> overruns{0};
  std::atomic<std::uint64_t> deadline_misses{0};  // finished after its next release
  std::atomic<std::uint64_t> skipped{0};          // releases not run (degraded or late lane)
  std::atomic<std::uint64_t> faults{0};
};

struct LaneStats {
  Histogram wake_latency;              // actual wake-up minus scheduled release
  std::atomic<std::uint64_t> ticks{0};
  std::atomic<std::uint64_t> missed_ticks{0};     // releases skipped because the lane was late
};

// Privileges the real clock asks for; each missing one is warned about once.
struct RtWarnings {
  std::atomic<bool> mlock_failed{false};
  std::atomic<bool> sched_failed{false};
  std::atomic<bool> affinity_failed{false};
};

class Executive {
 public:
  Executive(ExecutiveSpec spec, ExecClock& clock, SafeStop& safe_stop);
  ~Executive();
  Executive(const Executive&) = delete;
  Executive& operator=(const Executive&) = delete;

  // Before start(): every task in the spec must be bound.
  void bind(std::string_view task, TaskFn fn, void* user);
  void add_watchdog(WatchdogSink& sink);

  // Creates the lane threads (the last allocations) and releases them at `epoch` (real
  // clock: now + 10 ms when 0; simulated clock: its start time).
  void start(Nanos epoch = 0);
  // Asks every lane to finish its current tick, then joins them. Bounded by one period
  // plus the longest task budget.
  void stop();
  bool running() const { return started_ && !joined_; }

  // How many lanes sleep on the clock: the task lanes plus the supervisor's. A SimClock
  // for this executive is made with this count.
  static int clock_lanes(const ExecutiveSpec& spec) { return static_cast<int>(spec.lanes.size()) + 1; }

  const ExecutiveSpec& spec() const { return spec_; }
  int task_index(std::string_view name) const;   // -1 when unknown
  const TaskStats& task_stats(int task) const { return task_[task].stats; }
  const LaneStats& lane_stats(int lane) const { return lane_[lane].stats; }
  bool lane_alive(int lane) const;
  bool all_lanes_alive() const { return all_alive_.load(std::memory_order_acquire); }
  std::uint64_t watchdog_feeds() const { return feeds_.load(std::memory_order_relaxed); }
  const RtWarnings& rt_warnings() const { return warnings_; }
  // Trace of a stopped executive, merged across lanes in (time, lane, order) order.
  std::vector<TraceEvent> trace() const;
  // Human-readable timing report (budget use per task, misses, latency per lane).
  std::string timing_report() const;

 private:
  friend class TaskContext;
  struct Task {
    TaskSpec spec;
    TaskFn fn = nullptr;
    void* user = nullptr;
    bool degraded = false;
    int in_budget_streak = 0;
    std::uint64_t skip_toggle = 0;
    TaskStats stats;
  };
  struct Lane {
    int index = 0;
    std::array<int, kMaxTasks> tasks{};
    int task_count = 0;
    std::atomic<Nanos> heartbeat{0};  // start of the last tick, on the executive clock
    LaneStats stats;
    std::vector<TraceEvent> trace;    // reserved at construction, never grows past it
    std::size_t trace_dropped = 0;
    std::thread thread;
  };

  void lane_main(int lane);
  void supervisor_main();
  void run_task(Lane& lane, int task_index, Nanos release, std::uint64_t tick);
  std::uint64_t next_due_tick(const Lane& lane, std::uint64_t after) const;
  void record(Lane& lane, Nanos time, int task, TraceEvent::Kind kind);
  void set_realtime(int lane);

  ExecutiveSpec spec_;
  ExecClock& clock_;
  SafeStop& safe_stop_;
  std::array<Task, kMaxTasks> task_{};
  int task_count_ = 0;
  std::array<Lane, kMaxLanes> lane_{};  // task lanes, then the supervisor's
  int lane_count_ = 0;
  std::array<WatchdogSink*, 4> watchdogs_{};
  int watchdog_count_ = 0;
  Nanos epoch_ = 0;
  std::atomic<bool> stop_{false};
  std::atomic<bool> all_alive_{true};
  std::atomic<std::uint64_t> feeds_{0};
  RtWarnings warnings_;
  bool started_ = false;
  bool joined_ = false;
};

// What a task sees while it runs.
class TaskContext {
 public:
  Nanos release() const { return release_; }
  std::uint64_t tick() const { return tick_; }
  Nanos now() const { return exec_.clock_.now(lane_); }
  // Simulated runs: model `d` of execution time. Real clock: nothing.
  void consume(Nanos d) const { exec_.clock_.consume(lane_, d); }
  bool degraded() const { return degraded_; }
  bool safe_stopped() const { return exec_.safe_stop_.active(); }
  SafeStop& safe_stop() const { return exec_.safe_stop_; }
  std::string_view task_name() const { return exec_.task_[task_].spec.name; }

 private:
  friend class Executive;
  TaskContext(Executive& e, int lane, int task, Nanos release, std::uint64_t tick, bool degraded)
      : exec_(e), lane_(lane), task_(task), release_(release), tick_(tick), degraded_(degraded) {}
  Executive& exec_;
  int lane_;
  int task_;
  Nanos release_;
  std::uint64_t tick_;
  bool degraded_;
};

}  // namespace markcell::control
