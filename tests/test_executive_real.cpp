// The executive on the real clock: 2 s at 1 kHz, statistics reported (no timing
// thresholds: the machines are shared), and a clean stop.
#include <catch2/catch.hpp>
#include <time.h>

#include <chrono>
#include <iostream>
#include <thread>

#include "markcell/control/executive.hpp"

using namespace markcell;
using namespace markcell::control;

TEST_CASE("2 s at 1 kHz on the real clock: every tick accounted for, statistics reported") {
  ExecutiveSpec spec;
  spec.tick = millis(1);
  spec.lanes = {{"control", -1, 10}, {"vision", -1, 5}};
  spec.tasks = {{"fast", 0, 1, 0, micros(500), OverrunPolicy::kLog},
                {"slow", 1, 33, 0, millis(20), OverrunPolicy::kLog}};
  spec.lane_stall_limit = millis(500);  // generous: the test machine is shared
  spec.supervisor_period = millis(50);
  RealClock clock;
  FaultLog log;
  SafeStop safe(log);
  Executive exec(spec, clock, safe);
  struct Counter {
    std::atomic<int> runs{0};
  } fast, slow;
  auto count = [](TaskContext&, void* u) {
    static_cast<Counter*>(u)->runs.fetch_add(1);
    return TaskResult::kOk;
  };
  exec.bind("fast", count, &fast);
  exec.bind("slow", count, &slow);
  const Nanos t0 = monotonic_now();
  exec.start();
  std::this_thread::sleep_for(std::chrono::seconds(2));
  exec.stop();
  const Nanos elapsed = monotonic_now() - t0;
  std::cout << exec.timing_report();
  const auto& lane = exec.lane_stats(0);
  // Every 1 ms release up to the stop either ran or was counted as missed: none is lost.
  const auto accounted = lane.ticks.load() + lane.missed_ticks.load();
  const auto max_releases = static_cast<std::uint64_t>(elapsed / millis(1)) + 1;
  CHECK(accounted <= max_releases);
  CHECK(accounted > 0);
  CHECK(static_cast<std::uint64_t>(fast.runs.load()) == exec.task_stats(0).exec.count());
  CHECK(exec.task_stats(0).exec.count() + exec.task_stats(0).skipped.load() == lane.ticks.load() + lane.missed_ticks.load());
  CHECK(slow.runs.load() >= 1);
  CHECK(lane.wake_latency.count() == lane.ticks.load());
  CHECK(lane.wake_latency.min() >= 0);
}

namespace {
// One lane at 1 kHz with one task "t": the spec the single-task cases below share.
ExecutiveSpec one_task_spec(std::uint32_t period_ticks, Nanos budget, OverrunPolicy policy) {
  ExecutiveSpec spec;
  spec.tick = millis(1);
  spec.lanes = {{"control", -1, 0}};
  spec.tasks = {{"t", 0, period_ticks, 0, budget, policy}};
  spec.lane_stall_limit = millis(1000);
  spec.supervisor_period = millis(100);
  return spec;
}
}  // namespace

TEST_CASE("stop() returns within one period plus the longest budget") {
  const ExecutiveSpec spec = one_task_spec(100, millis(20), OverrunPolicy::kLog);
  RealClock clock;
  FaultLog log;
  SafeStop safe(log);
  Executive exec(spec, clock, safe);
  exec.bind("t", [](TaskContext&, void*) { return TaskResult::kOk; }, nullptr);
  exec.start();
  std::this_thread::sleep_for(std::chrono::milliseconds(150));
  const Nanos t0 = monotonic_now();
  exec.stop();
  const Nanos took = monotonic_now() - t0;
  std::cout << "stop took " << to_micros(took) << " us (bound: period 100 ms + budget 20 ms)\n";
  CHECK_FALSE(exec.running());
  CHECK(exec.task_stats(0).exec.count() >= 1);
}

TEST_CASE("the budget is on the task's own CPU time: kept off its core is no overrun, computing too long is") {
  // Two tasks with a 500 us budget and policy safe_stop: one sleeps 3 ms in its step (off
  // its core, as a thread the kernel or the hypervisor preempts), one spins 3 ms of its
  // own CPU time (measured by the same clock as the reference).
  for (const bool spin : {false, true}) {
    CAPTURE(spin);
    const ExecutiveSpec spec = one_task_spec(20, micros(500), OverrunPolicy::kSafeStop);
    RealClock clock;
    FaultLog log;
    SafeStop safe(log);
    Executive exec(spec, clock, safe);
    exec.bind("t", spin ? [](TaskContext&, void*) {
      timespec t0{}, t{};
      clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t0);
      do clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
      while ((t.tv_sec - t0.tv_sec) * 1'000'000'000L + (t.tv_nsec - t0.tv_nsec) < 3'000'000L);
      return TaskResult::kOk;
    } : [](TaskContext&, void*) {
      std::this_thread::sleep_for(std::chrono::milliseconds(3));
      return TaskResult::kOk;
    }, nullptr);
    exec.start();
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    exec.stop();
    std::cout << exec.timing_report();
    const auto& stats = exec.task_stats(0);
    REQUIRE(stats.exec.count() >= 1);
    CHECK(stats.wall_max.load() >= millis(3));
    if (spin) {
      CHECK(stats.overruns.load() >= 1);
      CHECK(stats.exec.max() >= millis(3));
      CHECK(safe.active());
    } else {
      CHECK(stats.overruns.load() == 0);
      CHECK(stats.exec.max() < micros(500));
      CHECK_FALSE(safe.active());
    }
  }
}
