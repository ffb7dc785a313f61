// The PLC inputs against hostile timing (issue: the valve open with no panel present):
// the input filter on the edges' kernel times, the valve's interlock on panel present,
// the edge-latched e-stop. An executive in simulated time runs plc_io and spray_valve
// at 1 kHz; the test drives the far side of the simulated lines at times between the
// ticks, as a PLC's relay or a chattering photo-eye would. The reference is the drive
// itself: when each pulse began and ended.
#include <catch2/catch.hpp>

#include <cmath>
#include <vector>

#include "markcell/control/exec_clock.hpp"
#include "markcell/control/executive.hpp"
#include "markcell/control/plc_io.hpp"
#include "markcell/control/spray_valve.hpp"
#include "markcell/drivers/gpio.hpp"

using namespace markcell;
using namespace markcell::control;

namespace {

enum : int { kPanel = 0, kEnable = 1, kEstop = 2, kReady = 3, kFault = 4, kValve = 5 };
constexpr Nanos kFilter = millis(3);

struct Bench {
  explicit Bench(Nanos filter = kFilter)
      : spec(make_spec()), clock(Executive::clock_lanes(spec)), safe(log), outputs(gpio, kFault),
        plc(gpio, PlcLineMap{kPanel, kEnable, kEstop, kReady, -1, -1, kFault}, safe, filter),
        valve(gpio, kValve, millis(1), seconds(10)) {
    gpio.configure({{"PANEL", false, false, false}, {"ENABLE", false, false, false}, {"ESTOP", false, true, false},
                    {"READY", true, false, false}, {"FAULT", true, false, false}, {"VALVE", true, false, false}});
    // Edges the test drives are stamped with their own time (between two ticks, as the
    // kernel stamps them); the valve's with the clock's.
    gpio.set_time_source([](void* u) {
      auto& b = *static_cast<Bench*>(u);
      return b.drive_at >= 0 ? b.drive_at : b.clock.global_now();
    }, this);
    safe.add_output(outputs);
    valve.set_permit(&plc.inputs().spray_permitted);
    exec = std::make_unique<Executive>(spec, clock, safe);
    exec->bind("plc_io", &PlcIo::task, &plc);
    exec->bind("spray_valve", &SprayValve::task, &valve);
    gpio.activate();
    gpio.drive_physical(kEnable, true);
    gpio.drive_physical(kEstop, true);  // active low: released
    gpio.drive_physical(kPanel, true);
    exec->start();
  }
  ~Bench() { exec->stop(); }
  static ExecutiveSpec make_spec() {
    ExecutiveSpec s;
    s.tick = millis(1);
    s.lanes = {{"control", -1, 0}};
    s.tasks = {{"plc_io", 0, 1, 0, micros(200), OverrunPolicy::kSafeStop},
               {"spray_valve", 0, 1, 0, micros(100), OverrunPolicy::kSafeStop}};
    s.lane_stall_limit = millis(100);
    return s;
  }
  void run_to(Nanos t) { REQUIRE(clock.run_until(t) == SimClock::RunResult::kReached); }
  // The far side of an input changes at `t` (the clock run up to it first).
  void drive(int line, bool high, Nanos t) {
    run_to(t);
    drive_at = t;
    gpio.drive_physical(line, high);
    drive_at = -1;
  }
  Nanos drive_at = -1;
  // The valve's edges as the line saw them (logical: true = open).
  std::vector<drivers::SimGpioLines::Edge> valve_edges() const {
    std::vector<drivers::SimGpioLines::Edge> e;
    for (const auto& x : gpio.output_history())
      if (x.line == kValve) e.push_back(x);
    return e;
  }
  ExecutiveSpec spec;
  SimClock clock;
  FaultLog log;
  SafeStop safe;
  drivers::SimGpioLines gpio;
  GpioSafeOutputs outputs;
  PlcIo plc;
  SprayValve valve;
  std::unique_ptr<Executive> exec;
};

}  // namespace

TEST_CASE("panel present: a glitch shorter than the filter is ignored, a drop as long always counts, whatever its phase, "
          "and the valve closes on the next tick either way") {
  const std::vector<double> widths_ms = {0.05, 0.3, 0.9, 1.0, 1.7, 2.5, 2.95, 3.0, 3.4, 4.2, 7.5};
  const std::vector<double> phases_ms = {0.0, 0.001, 0.25, 0.5, 0.75, 0.999};
  for (const double w : widths_ms) {
    for (const double phase : phases_ms) {
      INFO("drop of " << w << " ms starting " << phase << " ms after the 60 ms tick");
      Bench b;
      b.run_to(millis(20));
      REQUIRE(b.plc.inputs().panel_present);
      // A long pulse, open across the drop.
      REQUIRE(b.valve.request(millis(30), millis(500), false) == PulseRequest::kAccepted);
      const Nanos fall = millis(60) + static_cast<Nanos>(std::llround(phase * 1e6));
      const Nanos rise = fall + static_cast<Nanos>(std::llround(w * 1e6));
      b.run_to(fall);
      REQUIRE(b.valve.open());
      b.drive(kPanel, false, fall);
      b.drive(kPanel, true, rise);
      b.run_to(millis(120));
      const bool long_enough = rise - fall >= kFilter;
      CHECK(b.plc.inputs().panel_present_drops == (long_enough ? 1U : 0U));
      CHECK(b.plc.inputs().glitches == (long_enough ? 0U : 1U));
      CHECK(b.plc.inputs().panel_present);  // high again for longer than the filter
      // The valve: opened at 30 ms, closed at the first tick after the fall, never again.
      const auto edges = b.valve_edges();
      REQUIRE(edges.size() == 2);
      CHECK(edges[0].active);
      CHECK(edges[0].time == millis(30));
      CHECK_FALSE(edges[1].active);
      CHECK(edges[1].time > fall - 1);
      CHECK(edges[1].time <= fall + millis(1));
      REQUIRE(b.valve.pulse_count() == 1);
      CHECK(b.valve.pulse(0).cut_short);
    }
  }
}

TEST_CASE("panel present chattering every 1 ms in step with the tick: never a spray, the chatter reported") {
  // Sampled on the tick, a line toggling every millisecond reads one level for ever
  // (or low half the time); its edges tell the truth.
  for (const double phase : {0.0, 0.3, 0.5, 0.9}) {
    INFO("toggles " << phase << " ms after each tick");
    Bench b;
    b.run_to(millis(20));
    const Nanos t0 = millis(30) + static_cast<Nanos>(std::llround(phase * 1e6));
    int refused = 0;
    for (int k = 0; k < 200; ++k) {
      b.drive(kPanel, k % 2 == 1, t0 + k * millis(1));
      // Asked for a pulse on every tick, the valve never opens while the line chatters.
      if (k > 2 && b.valve.request(t0 + k * millis(1), millis(80), false) == PulseRequest::kNotPermitted) ++refused;
    }
    b.run_to(t0 + millis(201));
    CHECK(b.valve_edges().empty());
    CHECK(refused == 197);
    // Every pulse of the chatter is shorter than the filter: not a drop, but not hidden.
    CHECK(b.plc.inputs().panel_present_drops == 0);
    CHECK(b.plc.inputs().glitches >= 99);
    Fault f;
    bool reported = false;
    while (b.log.pop(f)) reported = reported || f.code == FaultCode::kInputGlitch;
    CHECK(reported);
  }
}

TEST_CASE("an e-stop pulse shorter than a tick, between two ticks, still stops the cell") {
  Bench b;
  b.run_to(millis(20));
  REQUIRE(b.valve.request(millis(25), millis(500), false) == PulseRequest::kAccepted);
  b.drive(kEstop, false, millis(40) + micros(200));  // pressed (active low) for 0.3 ms
  b.drive(kEstop, true, millis(40) + micros(500));
  b.run_to(millis(60));
  REQUIRE(b.safe.done());
  CHECK(b.safe.reason().code == FaultCode::kOperatorStop);
  CHECK(b.safe.reason().detail.view() == "e-stop pulse (edge latched)");
  CHECK(b.safe.reason().time == millis(41));
  CHECK_FALSE(b.valve.open());
  CHECK(b.gpio.physical(kFault));
}

TEST_CASE("after an e-stop the PLC re-arms the cell: released first, then a cycle-enable edge, never before") {
  Bench b;
  b.drive(kEstop, false, millis(20));
  b.run_to(millis(100));
  REQUIRE(b.safe.done());
  CHECK_FALSE(b.gpio.physical(kReady));
  // A cycle-enable edge while the e-stop is still pressed does not count.
  b.gpio.drive_physical(kEnable, false);
  b.drive(kEnable, true, millis(120));
  b.run_to(millis(200));
  CHECK_FALSE(b.safe.rearm_requested());
  b.gpio.drive_physical(kEstop, true);  // released
  b.run_to(millis(300));
  CHECK_FALSE(b.safe.rearm_requested());  // released, but no reset yet
  CHECK(b.safe.done());
  // A reset pulse shorter than the filter is a glitch, not a reset.
  b.gpio.drive_physical(kEnable, false);
  b.drive(kEnable, true, millis(301));
  b.run_to(millis(350));
  CHECK_FALSE(b.safe.rearm_requested());
  // The reset: low for 10 ms, high again (rises once the high has lasted the filter).
  b.gpio.drive_physical(kEnable, false);
  b.drive(kEnable, true, millis(360));
  b.run_to(millis(380));
  REQUIRE(b.safe.rearm_requested());
  // No arm task here: the test stands in for it once the arm is home.
  REQUIRE(b.safe.rearm(millis(380), "test: arm at home"));
  b.run_to(millis(400));
  CHECK_FALSE(b.safe.active());
  CHECK(b.gpio.physical(kReady));
  CHECK_FALSE(b.gpio.physical(kFault));
  REQUIRE(b.valve.request(millis(410), millis(20), false) == PulseRequest::kAccepted);
  b.run_to(millis(450));
  CHECK(b.valve.pulse(b.valve.pulse_count() - 1).closed == millis(430));
  // A second e-stop stops it again, and needs its own release and reset.
  b.gpio.drive_physical(kEstop, false);
  b.run_to(millis(500));
  CHECK(b.safe.done());
  CHECK(b.safe.stops() == 2);
  b.gpio.drive_physical(kEstop, true);
  b.run_to(millis(600));
  CHECK_FALSE(b.safe.rearm_requested());
}

TEST_CASE("a stop that is not the PLC's is never re-armed by the PLC") {
  Bench b;
  b.drive(kEstop, false, millis(20));
  b.run_to(millis(40));
  // During the e-stop the cell faults on its own (a device): that stop stays for good.
  b.safe.trigger(millis(40), FaultCode::kDeviceFault, "arm", "test: heartbeat lost");
  b.gpio.drive_physical(kEstop, true);
  b.drive(kEnable, false, millis(100));
  b.drive(kEnable, true, millis(120));
  b.run_to(millis(200));
  CHECK(b.safe.internal_fault());
  CHECK_FALSE(b.safe.recoverable());
  CHECK_FALSE(b.safe.rearm_requested());
  CHECK_FALSE(b.safe.rearm(millis(200), "test"));
  CHECK(b.safe.done());
}
