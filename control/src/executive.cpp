#include "markcell/control/executive.hpp"

#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <sstream>

#include "markcell/common/check.hpp"

namespace markcell::control {

namespace {
#if defined(__SANITIZE_ADDRESS__)
constexpr bool kAddressSanitizer = true;  // mlockall would try to pin ASan's shadow
#else
constexpr bool kAddressSanitizer = false;
#endif

// Touches the lane's stack once so its pages are resident before the first tick.
void prefault_stack() {
  constexpr std::size_t kBytes = 64 * 1024;
  unsigned char stack[kBytes];
  for (std::size_t i = 0; i < kBytes; i += 4096) stack[i] = 0;
  asm volatile("" : : "r"(stack) : "memory");  // keep the writes
}

// Shortest task period of each lane, in ticks: the longest gap between two ticks.
std::uint32_t lane_gap_ticks(const ExecutiveSpec& spec, int lane) {
  std::uint32_t gap = 0;
  for (const auto& t : spec.tasks)
    if (t.lane == lane && (gap == 0 || t.period_ticks < gap)) gap = t.period_ticks;
  return gap;
}
}  // namespace

std::string_view to_string(OverrunPolicy policy) {
  switch (policy) {
    case OverrunPolicy::kLog: return "log";
    case OverrunPolicy::kDegrade: return "degrade";
    case OverrunPolicy::kSafeStop: return "safe_stop";
  }
  return "unknown";
}

void validate(const ExecutiveSpec& spec) {
  MARKCELL_THROW_UNLESS(spec.tick > 0, "tick=" << spec.tick << " ns");
  MARKCELL_THROW_UNLESS(!spec.lanes.empty() && spec.lanes.size() <= static_cast<std::size_t>(kMaxTaskLanes),
                        "lanes=" << spec.lanes.size() << " max=" << kMaxTaskLanes);
  MARKCELL_THROW_UNLESS(!spec.tasks.empty() && spec.tasks.size() <= static_cast<std::size_t>(kMaxTasks),
                        "tasks=" << spec.tasks.size() << " max=" << kMaxTasks);
  MARKCELL_THROW_UNLESS(spec.supervisor_period > 0, "supervisor_period=" << spec.supervisor_period);
  for (std::size_t i = 0; i < spec.tasks.size(); ++i) {
    const TaskSpec& t = spec.tasks[i];
    MARKCELL_THROW_UNLESS(t.lane >= 0 && t.lane < static_cast<int>(spec.lanes.size()),
                          "task '" << t.name << "' lane=" << t.lane);
    MARKCELL_THROW_UNLESS(t.period_ticks >= 1, "task '" << t.name << "' period_ticks=" << t.period_ticks);
    MARKCELL_THROW_UNLESS(t.phase_ticks < t.period_ticks,
                          "task '" << t.name << "' phase_ticks=" << t.phase_ticks << " period_ticks=" << t.period_ticks);
    MARKCELL_THROW_UNLESS(t.budget > 0 && t.budget <= static_cast<Nanos>(t.period_ticks) * spec.tick,
                          "task '" << t.name << "' budget=" << t.budget << " ns period=" << t.period_ticks * spec.tick << " ns");
    for (std::size_t j = 0; j < i; ++j)
      MARKCELL_THROW_UNLESS(spec.tasks[j].name != t.name, "task '" << t.name << "' declared twice");
  }
  for (int l = 0; l < static_cast<int>(spec.lanes.size()); ++l) {
    const std::uint32_t gap = lane_gap_ticks(spec, l);
    MARKCELL_THROW_UNLESS(gap > 0, "lane '" << spec.lanes[static_cast<std::size_t>(l)].name << "' has no task");
    MARKCELL_THROW_UNLESS(spec.lane_stall_limit > 2 * static_cast<Nanos>(gap) * spec.tick,
                          "lane_stall_limit=" << spec.lane_stall_limit << " ns must exceed twice lane '"
                          << spec.lanes[static_cast<std::size_t>(l)].name << "' period " << gap * spec.tick << " ns");
  }
}

Executive::Executive(ExecutiveSpec spec, ExecClock& clock, SafeStop& safe_stop)
    : spec_(std::move(spec)), clock_(clock), safe_stop_(safe_stop) {
  validate(spec_);
  lane_count_ = static_cast<int>(spec_.lanes.size());
  task_count_ = static_cast<int>(spec_.tasks.size());
  for (int l = 0; l <= lane_count_; ++l) {
    lane_[static_cast<std::size_t>(l)].index = l;
    if (spec_.trace) lane_[static_cast<std::size_t>(l)].trace.reserve(kTraceCapacity);
  }
  for (int i = 0; i < task_count_; ++i) {
    Task& t = task_[static_cast<std::size_t>(i)];
    t.spec = spec_.tasks[static_cast<std::size_t>(i)];
    Lane& lane = lane_[static_cast<std::size_t>(t.spec.lane)];
    lane.tasks[static_cast<std::size_t>(lane.task_count++)] = i;
  }
}

Executive::~Executive() {
  if (started_ && !joined_) stop();
}

int Executive::task_index(std::string_view name) const {
  for (int i = 0; i < task_count_; ++i)
    if (task_[static_cast<std::size_t>(i)].spec.name == name) return i;
  return -1;
}

void Executive::bind(std::string_view task, TaskFn fn, void* user) {
  MARKCELL_THROW_UNLESS(!started_, "bind('" << task << "') after start");
  const int i = task_index(task);
  MARKCELL_THROW_UNLESS(i >= 0, "task '" << task << "' is not in the task table");
  MARKCELL_THROW_UNLESS(fn != nullptr, "task '" << task << "' bound to no function");
  task_[static_cast<std::size_t>(i)].fn = fn;
  task_[static_cast<std::size_t>(i)].user = user;
}

void Executive::add_watchdog(WatchdogSink& sink) {
  MARKCELL_THROW_UNLESS(!started_, "add_watchdog('" << sink.name() << "') after start");
  MARKCELL_THROW_UNLESS(watchdog_count_ < static_cast<int>(watchdogs_.size()), "too many watchdogs");
  watchdogs_[static_cast<std::size_t>(watchdog_count_++)] = &sink;
}

void Executive::start(Nanos epoch) {
  MARKCELL_THROW_UNLESS(!started_, "start() called twice");
  for (int i = 0; i < task_count_; ++i)
    MARKCELL_THROW_UNLESS(task_[static_cast<std::size_t>(i)].fn != nullptr,
                          "task '" << task_[static_cast<std::size_t>(i)].spec.name << "' has no function bound");
  if (!clock_.simulated() && spec_.lock_memory) {
    if (kAddressSanitizer || mlockall(MCL_CURRENT | MCL_FUTURE) != 0) warnings_.mlock_failed = true;
  }
  if (epoch == 0) epoch = clock_.simulated() ? clock_.now(0) : clock_.now(0) + millis(10);
  epoch_ = epoch;
  for (int l = 0; l <= lane_count_; ++l) lane_[static_cast<std::size_t>(l)].heartbeat.store(epoch_);
  started_ = true;
  for (int l = 0; l < lane_count_; ++l)
    lane_[static_cast<std::size_t>(l)].thread = std::thread([this, l] { lane_main(l); });
  lane_[static_cast<std::size_t>(lane_count_)].thread = std::thread([this] { supervisor_main(); });
}

void Executive::stop() {
  if (!started_ || joined_) return;
  stop_.store(true, std::memory_order_release);
  clock_.stop();
  for (int l = 0; l <= lane_count_; ++l) {
    auto& th = lane_[static_cast<std::size_t>(l)].thread;
    if (th.joinable()) th.join();
  }
  joined_ = true;
}

void Executive::set_realtime(int lane) {
  if (clock_.simulated()) return;
  const LaneSpec& ls = spec_.lanes[static_cast<std::size_t>(lane)];
  if (ls.core >= 0) {
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(static_cast<unsigned>(ls.core), &set);
    if (pthread_setaffinity_np(pthread_self(), sizeof(set), &set) != 0) warnings_.affinity_failed = true;
  }
  if (ls.priority > 0) {
    sched_param param{};
    param.sched_priority = ls.priority;
    if (pthread_setschedparam(pthread_self(), SCHED_FIFO, &param) != 0) warnings_.sched_failed = true;
  }
  prefault_stack();
}

std::uint64_t Executive::next_due_tick(const Lane& lane, std::uint64_t from) const {
  std::uint64_t best = UINT64_MAX;
  for (int i = 0; i < lane.task_count; ++i) {
    const TaskSpec& t = task_[static_cast<std::size_t>(lane.tasks[static_cast<std::size_t>(i)])].spec;
    std::uint64_t due = t.phase_ticks;
    if (from > due) due += (from - due + t.period_ticks - 1) / t.period_ticks * t.period_ticks;
    best = std::min(best, due);
  }
  return best;
}

void Executive::record(Lane& lane, Nanos time, int task, TraceEvent::Kind kind) {
  if (!spec_.trace) return;
  if (lane.trace.size() == lane.trace.capacity()) {
    ++lane.trace_dropped;
    return;
  }
  lane.trace.push_back(TraceEvent{time, static_cast<std::int16_t>(lane.index), static_cast<std::int16_t>(task), kind});
}

void Executive::lane_main(int index) {
  set_realtime(index);
  Lane& lane = lane_[static_cast<std::size_t>(index)];
  std::uint64_t k = next_due_tick(lane, 0);
  for (;;) {
    const Nanos release = epoch_ + static_cast<Nanos>(k) * spec_.tick;
    if (clock_.sleep_until(index, release) == WakeResult::kStopped || stop_.load(std::memory_order_acquire)) break;
    const Nanos woke = clock_.now(index);
    lane.heartbeat.store(woke, std::memory_order_release);
    lane.stats.wake_latency.record(woke - release);
    lane.stats.ticks.store(lane.stats.ticks.load(std::memory_order_relaxed) + 1, std::memory_order_relaxed);
    for (int i = 0; i < lane.task_count; ++i) {
      const int ti = lane.tasks[static_cast<std::size_t>(i)];
      const TaskSpec& t = task_[static_cast<std::size_t>(ti)].spec;
      if (k >= t.phase_ticks && (k - t.phase_ticks) % t.period_ticks == 0) run_task(lane, ti, release, k);
    }
    std::uint64_t next = next_due_tick(lane, k + 1);
    // A lane that is late does not burst to catch up: it skips the releases it missed
    // (counted per task) and continues at the first one still ahead of it.
    const Nanos after = clock_.now(index);
    if (epoch_ + static_cast<Nanos>(next) * spec_.tick < after) {
      const auto first_ahead = static_cast<std::uint64_t>((after - epoch_ + spec_.tick - 1) / spec_.tick);
      const std::uint64_t resume = next_due_tick(lane, first_ahead);
      for (int i = 0; i < lane.task_count; ++i) {
        Task& task = task_[static_cast<std::size_t>(lane.tasks[static_cast<std::size_t>(i)])];
        const auto p = task.spec.period_ticks;
        const auto ph = task.spec.phase_ticks;
        auto count_before = [&](std::uint64_t x) { return x <= ph ? 0 : (x - ph + p - 1) / p; };
        const std::uint64_t missed = count_before(resume) - count_before(k + 1);
        task.stats.skipped.store(task.stats.skipped.load(std::memory_order_relaxed) + missed, std::memory_order_relaxed);
        for (std::uint64_t m = 0; m < missed && m < 4; ++m) record(lane, after, lane.tasks[static_cast<std::size_t>(i)], TraceEvent::kSkipped);
      }
      lane.stats.missed_ticks.store(lane.stats.missed_ticks.load(std::memory_order_relaxed) + (resume - next),
                                    std::memory_order_relaxed);
      next = resume;
    }
    k = next;
  }
}

void Executive::run_task(Lane& lane, int index, Nanos release, std::uint64_t tick) {
  Task& task = task_[static_cast<std::size_t>(index)];
  TaskStats& stats = task.stats;
  auto bump = [](std::atomic<std::uint64_t>& a) { a.store(a.load(std::memory_order_relaxed) + 1, std::memory_order_relaxed); };
  if (task.degraded && (task.skip_toggle++ % 2) == 1) {
    bump(stats.skipped);
    record(lane, release, index, TraceEvent::kSkipped);
    return;
  }
  record(lane, release, index, TraceEvent::kRelease);
  const Nanos start = clock_.now(lane.index);
  const Nanos cpu_start = clock_.cpu_now(lane.index);
  TaskContext ctx(*this, lane.index, index, release, tick, task.degraded);
  const TaskResult result = task.fn(ctx, task.user);
  // The budget is on what the task computed; time it was kept off its core is the lane's
  // lateness (wake latency, deadline misses), reported apart, never an overrun of its own.
  const Nanos exec = clock_.cpu_now(lane.index) - cpu_start;
  const Nanos end = clock_.now(lane.index);
  stats.exec.record(exec);
  if (end - start > stats.wall_max.load(std::memory_order_relaxed)) stats.wall_max.store(end - start, std::memory_order_relaxed);
  record(lane, end, index, TraceEvent::kComplete);

  if (result == TaskResult::kFault) {
    bump(stats.faults);
    safe_stop_.trigger(end, FaultCode::kTaskFault, task.spec.name, "the task reported a fault");
  }
  if (exec > task.spec.budget) {
    bump(stats.overruns);
    record(lane, end, index, TraceEvent::kOverrun);
    FixedString<119> detail;
    detail.format("ran %lld us, budget %lld us, policy %s", static_cast<long long>(exec / kNanosPerMicro),
                  static_cast<long long>(task.spec.budget / kNanosPerMicro), to_string(task.spec.overrun).data());
    if (task.spec.overrun == OverrunPolicy::kSafeStop) {
      safe_stop_.trigger(end, FaultCode::kTaskOverrun, task.spec.name, detail.view());
    } else {
      Fault fault;
      fault.time = end;
      fault.code = FaultCode::kTaskOverrun;
      fault.source.assign(task.spec.name);
      fault.detail = detail;
      safe_stop_.log().push(fault);
      if (task.spec.overrun == OverrunPolicy::kDegrade) {
        task.degraded = true;
        task.in_budget_streak = 0;
        task.skip_toggle = 1;  // the very next release is the first one skipped
      }
    }
  } else if (task.degraded && ++task.in_budget_streak >= spec_.degrade_recovery_runs) {
    task.degraded = false;
  }
  const Nanos deadline = release + static_cast<Nanos>(task.spec.period_ticks) * spec_.tick;
  if (end > deadline) bump(stats.deadline_misses);
}

bool Executive::lane_alive(int lane) const {
  return clock_.now(lane_count_) - lane_[static_cast<std::size_t>(lane)].heartbeat.load(std::memory_order_acquire) <=
         spec_.lane_stall_limit;
}

void Executive::supervisor_main() {
  const int self = lane_count_;
  Lane& me = lane_[static_cast<std::size_t>(self)];
  std::array<bool, kMaxLanes> stalled{};
  for (std::uint64_t k = 1;; ++k) {
    const Nanos release = epoch_ + static_cast<Nanos>(k) * spec_.supervisor_period;
    if (clock_.sleep_until(self, release) == WakeResult::kStopped || stop_.load(std::memory_order_acquire)) break;
    const Nanos now = clock_.now(self);
    me.heartbeat.store(now, std::memory_order_release);
    bool all = true;
    for (int l = 0; l < lane_count_; ++l) {
      const Nanos since = now - lane_[static_cast<std::size_t>(l)].heartbeat.load(std::memory_order_acquire);
      if (since <= spec_.lane_stall_limit && !stalled[static_cast<std::size_t>(l)]) continue;
      all = false;
      if (stalled[static_cast<std::size_t>(l)]) continue;  // latched: the process must restart
      stalled[static_cast<std::size_t>(l)] = true;
      record(me, now, -1, TraceEvent::kStall);
      FixedString<119> detail;
      detail.format("no tick for %lld ms (limit %lld ms)", static_cast<long long>(since / kNanosPerMilli),
                    static_cast<long long>(spec_.lane_stall_limit / kNanosPerMilli));
      if (safe_stop_.trigger(now, FaultCode::kLaneStall, spec_.lanes[static_cast<std::size_t>(l)].name, detail.view()))
        record(me, now, -1, TraceEvent::kSafeStop);
    }
    all_alive_.store(all, std::memory_order_release);
    if (!all) continue;
    for (int w = 0; w < watchdog_count_; ++w) watchdogs_[static_cast<std::size_t>(w)]->feed(now);
    feeds_.fetch_add(1, std::memory_order_relaxed);
  }
}

std::vector<TraceEvent> Executive::trace() const {
  std::vector<TraceEvent> all;
  for (int l = 0; l <= lane_count_; ++l) {
    const auto& t = lane_[static_cast<std::size_t>(l)].trace;
    all.insert(all.end(), t.begin(), t.end());
  }
  std::stable_sort(all.begin(), all.end(), [](const TraceEvent& a, const TraceEvent& b) {
    return a.time != b.time ? a.time < b.time : a.lane < b.lane;
  });
  return all;
}

std::string Executive::timing_report() const {
  std::ostringstream os;
  char line[256];
  std::snprintf(line, sizeof line, "%-18s %-10s %9s %10s %9s %9s %9s %9s %7s %8s %7s %7s %11s\n", "task", "lane",
                "period_ms", "budget_us", "runs", "mean_us", "p99_us", "max_us", "use_%", "overruns", "misses",
                "skipped", "wall_max_us");
  os << line;
  for (int i = 0; i < task_count_; ++i) {
    const Task& t = task_[static_cast<std::size_t>(i)];
    const Histogram& h = t.stats.exec;
    const double budget_us = to_micros(t.spec.budget);
    std::snprintf(line, sizeof line, "%-18s %-10s %9.3f %10.0f %9llu %9.1f %9.1f %9.1f %7.1f %8llu %7llu %7llu %11.1f\n",
                  t.spec.name.c_str(), spec_.lanes[static_cast<std::size_t>(t.spec.lane)].name.c_str(),
                  to_seconds(static_cast<Nanos>(t.spec.period_ticks) * spec_.tick) * 1e3, budget_us,
                  static_cast<unsigned long long>(h.count()), h.mean() * 1e-3, to_micros(h.percentile(0.99)),
                  to_micros(h.max()), budget_us > 0 ? 100.0 * to_micros(h.max()) / budget_us : 0.0,
                  static_cast<unsigned long long>(t.stats.overruns.load()),
                  static_cast<unsigned long long>(t.stats.deadline_misses.load()),
                  static_cast<unsigned long long>(t.stats.skipped.load()), to_micros(t.stats.wall_max.load()));
    os << line;
  }
  std::snprintf(line, sizeof line, "\n%-18s %9s %5s %9s %9s %9s %9s %9s %7s\n", "lane", "priority", "core", "ticks",
                "wake_p50", "wake_p99", "p99.9_us", "max_us", "missed");
  os << line;
  for (int l = 0; l < lane_count_; ++l) {
    const LaneSpec& ls = spec_.lanes[static_cast<std::size_t>(l)];
    const LaneStats& s = lane_[static_cast<std::size_t>(l)].stats;
    std::snprintf(line, sizeof line, "%-18s %9d %5d %9llu %9.1f %9.1f %9.1f %9.1f %7llu\n", ls.name.c_str(),
                  ls.priority, ls.core, static_cast<unsigned long long>(s.ticks.load()),
                  to_micros(s.wake_latency.percentile(0.5)), to_micros(s.wake_latency.percentile(0.99)),
                  to_micros(s.wake_latency.percentile(0.999)), to_micros(s.wake_latency.max()),
                  static_cast<unsigned long long>(s.missed_ticks.load()));
    os << line;
  }
  return os.str();
}

}  // namespace markcell::control
