// The executive on the simulated clock: exact release times, overrun policies, stall
// detection, determinism, and 10,000 cycles without a heap allocation.
#include <catch2/catch.hpp>
#include <vector>

#include "alloc_guard.hpp"
#include "markcell/common/triple_buffer.hpp"
#include "markcell/control/executive.hpp"
#include "markcell/control/plc_io.hpp"

using namespace markcell;
using namespace markcell::control;

namespace {

struct CountingOutput final : SafeOutput {
  std::string_view name() const override { return "counting"; }
  void enter_safe_state() noexcept override { ++calls; }
  int calls = 0;
};

struct CountingWatchdog final : WatchdogSink {
  std::string_view name() const override { return "counting"; }
  void feed(Nanos now) noexcept override {
    ++feeds;
    last = now;
  }
  int feeds = 0;
  Nanos last = 0;
};

// A task whose simulated execution time is scripted per run.
struct Scripted {
  explicit Scripted(std::vector<Nanos> c) : cost(std::move(c)) {}
  std::vector<Nanos> cost;  // per run index; beyond the end: default_cost
  Nanos default_cost = micros(10);
  int runs = 0;
  std::vector<bool> saw_degraded;
  static TaskResult fn(TaskContext& ctx, void* self) {
    auto& s = *static_cast<Scripted*>(self);
    const auto i = static_cast<std::size_t>(s.runs++);
    ctx.consume(i < s.cost.size() ? s.cost[i] : s.default_cost);
    if (s.saw_degraded.size() < 64) s.saw_degraded.push_back(ctx.degraded());
    return TaskResult::kOk;
  }
};

TaskResult idle(TaskContext& ctx, void*) {
  ctx.consume(micros(5));
  return TaskResult::kOk;
}

ExecutiveSpec two_lanes() {
  ExecutiveSpec s;
  s.tick = millis(1);
  s.lanes = {{"control", -1, 0}, {"vision", -1, 0}};
  s.tasks = {
      {"a", 0, 2, 0, micros(500), OverrunPolicy::kLog},
      {"b", 0, 5, 3, micros(500), OverrunPolicy::kLog},
      {"c", 1, 3, 1, micros(900), OverrunPolicy::kLog},
  };
  s.lane_stall_limit = millis(50);
  s.supervisor_period = millis(10);
  s.trace = true;
  return s;
}

struct Harness {
  explicit Harness(ExecutiveSpec spec)
      : clock(Executive::clock_lanes(spec)), safe(log), exec(std::move(spec), clock, safe) {
    safe.add_output(output);
    exec.add_watchdog(watchdog);
  }
  ~Harness() { exec.stop(); }
  SimClock clock;
  FaultLog log;
  SafeStop safe;
  CountingOutput output;
  CountingWatchdog watchdog;
  Executive exec;
};

std::vector<TraceEvent> releases(const std::vector<TraceEvent>& trace, int task) {
  std::vector<TraceEvent> out;
  for (const auto& e : trace)
    if (e.kind == TraceEvent::kRelease && e.task == task) out.push_back(e);
  return out;
}

}  // namespace

TEST_CASE("release times follow period and phase exactly, in table order within a tick") {
  Harness h(two_lanes());
  for (const char* t : {"a", "b", "c"}) h.exec.bind(t, idle, nullptr);
  h.exec.start();
  REQUIRE(h.clock.run_until(millis(20)) == SimClock::RunResult::kReached);
  h.exec.stop();
  const auto trace = h.exec.trace();
  // Closed form: release n of a task is at (phase + n * period) * tick, up to 20 ms.
  const struct { int task; Nanos period, phase; } expected[] = {{0, 2, 0}, {1, 5, 3}, {2, 3, 1}};
  for (const auto& e : expected) {
    const auto r = releases(trace, e.task);
    std::vector<Nanos> want;
    for (Nanos t = e.phase; t <= 20; t += e.period) want.push_back(millis(t));
    std::vector<Nanos> got;
    for (const auto& ev : r) got.push_back(ev.time);
    CHECK(got == want);
  }
  // At 8 ms both a and b are due on lane 0: a runs first (table order), b after it.
  std::vector<int> at8;
  for (const auto& ev : trace)
    if (ev.kind == TraceEvent::kRelease && ev.lane == 0 && ev.time >= millis(8) && ev.time < millis(9)) at8.push_back(ev.task);
  CHECK(at8 == std::vector<int>{0, 1});
  CHECK(h.exec.task_stats(0).exec.count() == 11);
  CHECK(h.exec.task_stats(0).exec.max() == micros(5));
  CHECK(h.exec.lane_stats(0).wake_latency.max() == 0);  // simulated wake-ups are exact
  CHECK_FALSE(h.safe.active());
  CHECK(h.watchdog.feeds == 2);  // supervisor at 10 and 20 ms, all lanes alive
}

TEST_CASE("overrun policy log: counted and recorded, nothing else changes") {
  Harness h(two_lanes());
  Scripted a{{micros(100), micros(700), micros(100)}};
  h.exec.bind("a", Scripted::fn, &a);
  h.exec.bind("b", idle, nullptr);
  h.exec.bind("c", idle, nullptr);
  h.exec.start();
  REQUIRE(h.clock.run_until(millis(10)) == SimClock::RunResult::kReached);
  h.exec.stop();
  CHECK(h.exec.task_stats(0).overruns == 1);
  CHECK(h.exec.task_stats(0).skipped == 0);
  CHECK_FALSE(h.safe.active());
  Fault f;
  REQUIRE(h.log.pop(f));
  CHECK(f.code == FaultCode::kTaskOverrun);
  CHECK(f.source.view() == "a");
  CHECK(f.detail.view() == "ran 700 us, budget 500 us, policy log");
  CHECK(f.time == millis(2) + micros(700));
  CHECK_FALSE(h.log.pop(f));
}

TEST_CASE("overrun policy degrade: half rate until back within budget, and the task knows") {
  auto spec = two_lanes();
  spec.tasks[0].overrun = OverrunPolicy::kDegrade;
  spec.degrade_recovery_runs = 3;
  Harness h(spec);
  Scripted a{{micros(100), micros(800)}};
  h.exec.bind("a", Scripted::fn, &a);
  h.exec.bind("b", idle, nullptr);
  h.exec.bind("c", idle, nullptr);
  h.exec.start();
  REQUIRE(h.clock.run_until(millis(30)) == SimClock::RunResult::kReached);
  h.exec.stop();
  // Releases at 0,2,4,...,30 ms (16). Run 1 (2 ms) overruns; degraded from then on: the
  // releases at 4, 8, 12 run... let us count from the trace instead of guessing.
  const auto trace = h.exec.trace();
  std::vector<Nanos> ran, skipped;
  for (const auto& e : trace) {
    if (e.task != 0) continue;
    if (e.kind == TraceEvent::kRelease) ran.push_back(e.time);
    if (e.kind == TraceEvent::kSkipped) skipped.push_back(e.time);
  }
  // After the overrun at 2 ms: skip 4, run 6, skip 8, run 10, skip 12, run 14 (third
  // in-budget run ends the degraded period), then every release again.
  CHECK(ran == std::vector<Nanos>{0, millis(2), millis(6), millis(10), millis(14), millis(16), millis(18), millis(20),
                                  millis(22), millis(24), millis(26), millis(28), millis(30)});
  CHECK(skipped == std::vector<Nanos>{millis(4), millis(8), millis(12)});
  CHECK(h.exec.task_stats(0).skipped == 3);
  REQUIRE(a.saw_degraded.size() >= 6);
  CHECK(a.saw_degraded[0] == false);
  CHECK(a.saw_degraded[1] == false);  // the overrunning run itself started undegraded
  CHECK(a.saw_degraded[2] == true);
  CHECK(a.saw_degraded[4] == true);
  CHECK(a.saw_degraded[5] == false);
  CHECK_FALSE(h.safe.active());
}

TEST_CASE("overrun policy safe_stop: outputs driven once, the reason names the task") {
  auto spec = two_lanes();
  spec.tasks[2].overrun = OverrunPolicy::kSafeStop;
  Harness h(spec);
  Scripted c{{micros(100), micros(100), micros(950)}};
  h.exec.bind("a", idle, nullptr);
  h.exec.bind("b", idle, nullptr);
  h.exec.bind("c", Scripted::fn, &c);
  h.exec.start();
  REQUIRE(h.clock.run_until(millis(20)) == SimClock::RunResult::kReached);
  h.exec.stop();
  REQUIRE(h.safe.done());
  CHECK(h.output.calls == 1);
  CHECK(h.safe.reason().code == FaultCode::kTaskOverrun);
  CHECK(h.safe.reason().source.view() == "c");
  CHECK(h.safe.reason().detail.view() == "ran 950 us, budget 900 us, policy safe_stop");
  CHECK(h.safe.reason().time == millis(7) + micros(950));  // third run: released at 7 ms
  CHECK(h.exec.task_stats(2).overruns == 1);
}

TEST_CASE("a task reporting a fault goes to the safe stop") {
  Harness h(two_lanes());
  h.exec.bind("a", idle, nullptr);
  h.exec.bind("b", [](TaskContext&, void*) { return TaskResult::kFault; }, nullptr);
  h.exec.bind("c", idle, nullptr);
  h.exec.start();
  REQUIRE(h.clock.run_until(millis(5)) == SimClock::RunResult::kReached);
  h.exec.stop();
  REQUIRE(h.safe.done());
  CHECK(h.safe.reason().code == FaultCode::kTaskFault);
  CHECK(h.safe.reason().source.view() == "b");
  CHECK(h.safe.reason().time == millis(3));
}

TEST_CASE("a stalled lane is detected by the supervisor and the watchdogs starve") {
  Harness h(two_lanes());
  // Lane 1's task c runs at 1, 4, 7, 10 ms; its run at 10 ms takes 200 ms.
  Scripted c{{micros(10), micros(10), micros(10), millis(200)}};
  h.exec.bind("a", idle, nullptr);
  h.exec.bind("b", idle, nullptr);
  h.exec.bind("c", Scripted::fn, &c);
  h.exec.start();
  REQUIRE(h.clock.run_until(millis(300)) == SimClock::RunResult::kReached);
  h.exec.stop();
  REQUIRE(h.safe.done());
  CHECK(h.safe.reason().code == FaultCode::kLaneStall);
  CHECK(h.safe.reason().source.view() == "vision");
  CHECK(h.safe.reason().detail.view() == "no tick for 60 ms (limit 50 ms)");
  // Last tick of lane 1 started at 10 ms; the supervisor (every 10 ms) first sees more
  // than 50 ms without a tick at 70 ms.
  CHECK(h.safe.reason().time == millis(70));
  CHECK(h.watchdog.feeds == 6);               // 10..60 ms, then never again
  CHECK(h.watchdog.last == millis(60));
  CHECK_FALSE(h.exec.all_lanes_alive());
  // The lane came back at 210 ms, but the stall is latched until a restart.
  CHECK(h.exec.lane_stats(1).missed_ticks > 0);
}

TEST_CASE("the same task set gives the same trace, event for event") {
  auto run = [] {
    Harness h(two_lanes());
    Scripted a{{micros(100), micros(700), micros(300), micros(600)}};
    Scripted c{{micros(100), micros(2500)}};
    h.exec.bind("a", Scripted::fn, &a);
    h.exec.bind("b", idle, nullptr);
    h.exec.bind("c", Scripted::fn, &c);
    h.exec.start();
    REQUIRE(h.clock.run_until(millis(100)) == SimClock::RunResult::kReached);
    h.exec.stop();
    return h.exec.trace();
  };
  const auto first = run();
  const auto second = run();
  REQUIRE(first.size() > 100);
  CHECK(first == second);
}

TEST_CASE("10,000 cycles of a task set allocate nothing on the heap") {
  ExecutiveSpec spec;
  spec.tick = millis(1);
  spec.lanes = {{"control", -1, 0}, {"vision", -1, 0}};
  spec.tasks = {
      {"plc_io", 0, 1, 0, micros(200), OverrunPolicy::kSafeStop},
      {"consumer", 0, 1, 0, micros(200), OverrunPolicy::kLog},
      {"producer", 1, 33, 0, millis(20), OverrunPolicy::kDegrade},
  };
  spec.lane_stall_limit = millis(100);
  spec.supervisor_period = millis(10);
  SimClock clock(Executive::clock_lanes(spec));
  FaultLog log;
  SafeStop safe(log);
  drivers::SimGpioLines gpio;
  gpio.configure({{"PANEL", false, false, false}, {"ENABLE", false, false, false}, {"ESTOP", false, true, false},
                  {"READY", true, false, false}, {"FAULT", true, false, false}, {"VALVE", true, false, false}});
  gpio.set_time_source([](void* c) { return static_cast<SimClock*>(c)->global_now(); }, &clock);
  GpioSafeOutputs outputs(gpio, 4);
  safe.add_output(outputs);
  PlcIo plc(gpio, PlcLineMap{0, 1, 2, 3, -1, -1, 4}, safe);
  struct Frame {
    std::uint64_t seq = 0;
    double pose[6] = {};
  };
  struct Exchange {
    TripleBuffer<Frame> buffer;
    std::uint64_t produced = 0, consumed = 0, last_seq = 0;
  } x;
  Executive exec(spec, clock, safe);
  CountingWatchdog watchdog;
  exec.add_watchdog(watchdog);
  exec.bind("plc_io", &PlcIo::task, &plc);
  exec.bind("producer", [](TaskContext& ctx, void* u) {
    auto& ex = *static_cast<Exchange*>(u);
    Frame& f = ex.buffer.write_slot();
    f.seq = ++ex.produced;
    for (double& v : f.pose) v = static_cast<double>(f.seq) * 0.5;
    ex.buffer.publish();
    ctx.consume(millis(3));
    return TaskResult::kOk;
  }, &x);
  exec.bind("consumer", [](TaskContext& ctx, void* u) {
    auto& ex = *static_cast<Exchange*>(u);
    if (ex.buffer.update()) {
      ++ex.consumed;
      ex.last_seq = ex.buffer.read().seq;
    }
    ctx.consume(micros(20));
    return TaskResult::kOk;
  }, &x);
  gpio.activate();
  gpio.drive_physical(1, true);  // cycle enabled
  gpio.drive_physical(2, true);  // e-stop released (active low)
  exec.start();
  REQUIRE(clock.run_until(millis(100)) == SimClock::RunResult::kReached);  // warm-up
  std::size_t allocations = 0;
  SimClock::RunResult result;
  {
    test::AllocationGuard guard;
    result = clock.run_until(millis(100) + millis(10'000));
    allocations = guard.allocations();
  }
  exec.stop();
  CHECK(result == SimClock::RunResult::kReached);
  CHECK(allocations == 0);
  CHECK(exec.task_stats(0).exec.count() == 10'101);  // 0..10,100 ms inclusive
  CHECK(exec.lane_stats(0).ticks == 10'101);
  CHECK(x.produced == 10'100 / 33 + 1);
  CHECK(x.last_seq == x.produced);
  CHECK_FALSE(safe.active());
  bool ready = false;
  CHECK(gpio.get(3, ready) == drivers::GpioStatus::kOk);
  CHECK(ready);
  CHECK(watchdog.feeds == 1010);
}
