// The marking sequence's state machine on its own, one transition a case (ros2_control's
// mock components are the model): the sequence runs as the marking task of an executive
// in simulated time beside the real PLC handshake task and spray valve on simulated
// lines, with a mock arm whose every command is recorded and whose answers the test
// decides. No vision: where a case needs none, no pose ever comes. The reference of each
// case is the transition the sequence's documentation (docs/marking.md, safety.md)
// gives: the state, the result's fault and reason, each defect's skip reason, the PLC's
// lines, and what the arm was told.
#include <catch2/catch.hpp>

#include <array>

#include <memory>
#include <string>
#include <vector>

#include "alloc_guard.hpp"
#include "markcell/common/triple_buffer.hpp"
#include "markcell/control/exec_clock.hpp"
#include "markcell/control/executive.hpp"
#include "markcell/control/marking.hpp"
#include "markcell/control/plc_io.hpp"
#include "markcell/control/spray_valve.hpp"
#include "markcell/drivers/arm.hpp"
#include "markcell/drivers/gpio.hpp"

using namespace markcell;
using namespace markcell::control;

namespace {

enum : int { kPanel = 0, kEnable = 1, kEstop = 2, kReady = 3, kBusy = 4, kDone = 5, kFault = 6, kValve = 7 };

// An arm whose answers the test sets: it records every command; a home command makes it
// report homed `home_after` later, unless `never_home`.
class MockArm final : public drivers::ArmLink {
 public:
  void activate(Nanos now) override { state_.received = now; }
  void deactivate() noexcept override {}
  std::uint8_t send(const drivers::ArmCommand& command, Nanos now) noexcept override {
    commands.push_back({command, now});
    if (command.mode == drivers::ArmMode::kHome && !never_home) homed_at_ = now + home_after;
    return static_cast<std::uint8_t>(commands.size());
  }
  drivers::ArmLinkStatus poll(Nanos) noexcept override { return drivers::ArmLinkStatus::kOk; }
  // The state as of `now` (the test advances it through the clock it reads).
  const drivers::ArmState& state() const override {
    const Nanos now = clock_ != nullptr ? clock_->global_now() : 0;
    state_.received = now;
    state_.flags = homed_at_ >= 0 && now >= homed_at_ ? drivers::kHomed | drivers::kInPosition : 0;
    return state_;
  }
  drivers::ArmLinkStatus status() const override { return drivers::ArmLinkStatus::kOk; }
  const drivers::ArmLinkCounters& counters() const override { return counters_; }

  void use_clock(const SimClock* clock) { clock_ = clock; }
  int count(drivers::ArmMode mode) const {
    int n = 0;
    for (const auto& c : commands) n += c.command.mode == mode ? 1 : 0;
    return n;
  }
  struct Sent {
    drivers::ArmCommand command;
    Nanos at;
  };
  std::vector<Sent> commands;
  Nanos home_after = millis(300);
  bool never_home = false;

 private:
  const SimClock* clock_ = nullptr;
  mutable drivers::ArmState state_;
  drivers::ArmLinkCounters counters_;
  Nanos homed_at_ = -1;
};

// A record of a panel with `defects` defects, each a small patch of points (the sequence
// needs nothing more from it until a pose comes).
PanelJob record(const char* id, int defects) {
  PanelJob job;
  job.panel_id.assign(id);
  job.panel_type.assign("door");
  for (int i = 0; i < 4; ++i) REQUIRE(job.mfs_SL.push_back(Eigen::Vector3d(0.1 * i, 0.05 * (i % 2), 2.0)));
  for (int d = 0; d < defects; ++d) {
    PanelJob::Defect* defect = job.defects.emplace_back();
    REQUIRE(defect != nullptr);
    defect->id = d + 1;
    for (int k = 0; k < 20; ++k)
      defect->points_SL.push_back(Eigen::Vector3d(0.2 + 0.1 * d + 0.001 * (k % 5), 0.1 + 0.001 * (k / 5), 2.0));
  }
  return job;
}

struct Harness {
  // `line_silent` > 0: pairing by panel id, with the line's announcements in `arrivals`.
  explicit Harness(MarkingParams p = params(), Nanos line_silent = 0)
      : spec(make_spec()), clock(Executive::clock_lanes(spec)), safe(log), outputs(gpio, kFault),
        plc(gpio, PlcLineMap{kPanel, kEnable, kEstop, kReady, kBusy, kDone, kFault}, safe, millis(3)),
        valve(gpio, kValve, millis(5), millis(500)),
        marking(p, arm, valve, gpio, PlcLineMap{kPanel, kEnable, kEstop, kReady, kBusy, kDone, kFault}, plc, estimates,
                requests) {
    gpio.configure({{"PANEL", false, false, false},
                    {"ENABLE", false, false, false},
                    {"ESTOP", false, true, false},
                    {"READY", true, false, false},
                    {"BUSY", true, false, false},
                    {"DONE", true, false, false},
                    {"FAULT", true, false, false},
                    {"VALVE", true, false, false}});
    gpio.set_time_source([](void* u) { return static_cast<Harness*>(u)->clock.global_now(); }, this);
    safe.add_output(outputs);
    valve.set_permit(&plc.inputs().spray_permitted);
    arm.use_clock(&clock);
    if (line_silent > 0) marking.use_line_arrivals(&arrivals, line_silent);
    exec = std::make_unique<Executive>(spec, clock, safe);
    exec->bind("plc_io", &PlcIo::task, &plc);
    exec->bind("spray_valve", &SprayValve::task, &valve);
    exec->bind("marking", &MarkingSequence::task, &marking);
    gpio.activate();
    arm.activate(0);
    gpio.drive_physical(kEstop, true);  // active low: released
    exec->start();
  }
  ~Harness() { exec->stop(); }
  static MarkingParams params() {
    MarkingParams p;
    p.acquire_timeout = seconds(2);
    p.home_timeout = seconds(2);
    p.record_timeout = seconds(1);
    p.record_expiry = seconds(5);
    return p;
  }
  static ExecutiveSpec make_spec() {
    ExecutiveSpec s;
    s.tick = millis(1);
    s.lanes = {{"control", -1, 0}};
    s.tasks = {{"plc_io", 0, 1, 0, micros(200), OverrunPolicy::kSafeStop},
               {"spray_valve", 0, 1, 0, micros(100), OverrunPolicy::kSafeStop},
               {"marking", 0, 2, 0, micros(200), OverrunPolicy::kSafeStop}};
    s.lane_stall_limit = millis(100);
    return s;
  }
  void run_to(Nanos t) { REQUIRE(clock.run_until(t) == SimClock::RunResult::kReached); }
  void panel(bool present, Nanos t) {
    run_to(t);
    gpio.drive_physical(kPanel, present);
  }
  void enable(bool on, Nanos t) {
    run_to(t);
    gpio.drive_physical(kEnable, on);
  }
  bool line(int l) const { return gpio.physical(l); }
  const PanelResult& result() const { return marking.current(); }
  // The line's panel-id source says panel `id` comes next (its `counter`-th announcement).
  void announce(std::uint32_t counter, std::string_view id, Nanos t) {
    run_to(t);
    msg::LineArrival& a = arrivals.write_slot();
    a.counter = counter;
    a.panel_id.assign(id);
    a.heard = clock.global_now();
    arrivals.publish();
  }

  ExecutiveSpec spec;
  SimClock clock;
  FaultLog log;
  SafeStop safe;
  drivers::SimGpioLines gpio;
  GpioSafeOutputs outputs;
  PlcIo plc;
  SprayValve valve;
  MockArm arm;
  TripleBuffer<MarkingEstimate> estimates;
  TripleBuffer<msg::TrackerRequest> requests;
  TripleBuffer<msg::LineArrival> arrivals;
  MarkingSequence marking;
  std::unique_ptr<Executive> exec;
};

}  // namespace

TEST_CASE("idle, a record waiting, the panel arrives with cycle enable: the panel starts, the tracker is asked to search") {
  Harness h;
  REQUIRE(h.marking.offer_job(record("p-1", 2)));
  CHECK_FALSE(h.marking.offer_job(record("p-2", 1)));  // one waits at a time
  h.enable(true, millis(10));
  h.run_to(millis(100));
  CHECK(h.marking.state() == MarkingState::kIdle);  // no panel yet
  h.panel(true, millis(100));
  h.run_to(millis(150));
  CHECK(h.marking.state() == MarkingState::kAcquire);
  CHECK(h.marking.can_offer());  // the mailbox is free for the next record
  CHECK(h.line(kBusy));
  CHECK_FALSE(h.line(kDone));
  REQUIRE(h.requests.update());
  const msg::TrackerRequest& req = h.requests.read();
  CHECK(req.mfs_SL.size() == 4);
  CHECK(req.job_serial != 0);
  CHECK(h.arm.count(drivers::ArmMode::kMove) == 0);  // nothing moves before the panel is found
}

TEST_CASE("acquire: no macro-features within the timeout, the arm sent home, the panel a fault, each defect not found") {
  Harness h;
  REQUIRE(h.marking.offer_job(record("p-1", 3)));
  h.enable(true, 0);
  h.panel(true, millis(10));
  h.run_to(millis(2000));
  CHECK(h.marking.state() == MarkingState::kAcquire);
  h.run_to(millis(2100));  // 2 s after the start: the timeout
  CHECK(h.arm.count(drivers::ArmMode::kHome) == 1);
  h.run_to(millis(2500));  // homed 300 ms later: the result is out
  CHECK(h.marking.panels_completed() == 1);
  CHECK(h.marking.state() == MarkingState::kWaitRelease);
  CHECK(h.result().fault);
  CHECK(h.result().reason.view() == "macro-features not found in time");
  REQUIRE(h.result().defects.size() == 3);
  for (const DefectResult& d : h.result().defects) CHECK(d.skipped == SkipReason::kNotFound);
  CHECK(h.line(kFault));
  CHECK_FALSE(h.line(kDone));
  CHECK(h.valve.pulse_count() == 0);
  // The PLC takes the panel away: both answer lines drop, the sequence is idle again.
  h.panel(false, millis(2600));
  h.run_to(millis(2700));
  CHECK(h.marking.state() == MarkingState::kIdle);
  CHECK_FALSE(h.line(kFault));
}

TEST_CASE("acquire: the panel leaves before its macro-features are found: the panel a fault, stopped") {
  Harness h;
  REQUIRE(h.marking.offer_job(record("p-1", 2)));
  h.enable(true, 0);
  h.panel(true, millis(10));
  h.panel(false, millis(500));
  h.run_to(millis(1000));
  CHECK(h.marking.panels_completed() == 1);
  CHECK(h.result().reason.view() == "panel left before its macro-features were found");
  for (const DefectResult& d : h.result().defects) CHECK(d.skipped == SkipReason::kStopped);
  CHECK(h.arm.count(drivers::ArmMode::kHome) == 1);
}

TEST_CASE("home: an arm that never reports home ends the panel with both reasons, the first kept first") {
  Harness h;
  h.arm.never_home = true;
  REQUIRE(h.marking.offer_job(record("p-1", 1)));
  h.enable(true, 0);
  h.panel(true, millis(10));
  h.run_to(millis(2100));  // acquire timed out: home sent
  REQUIRE(h.arm.count(drivers::ArmMode::kHome) == 1);
  h.run_to(millis(4000));
  CHECK(h.marking.panels_completed() == 0);  // still waiting for home
  h.run_to(millis(4200));  // home_timeout (2 s) after the command
  CHECK(h.marking.panels_completed() == 1);
  CHECK(h.result().fault);
  CHECK(h.result().reason.view() == "macro-features not found in time; then the arm did not reach home in time");
}

TEST_CASE("a panel present without a record: PLC fault after the record timeout, the arm never commanded") {
  Harness h;
  h.enable(true, 0);
  h.panel(true, millis(10));
  h.run_to(millis(900));
  CHECK_FALSE(h.line(kFault));
  h.run_to(millis(1100));  // record_timeout: 1 s
  CHECK(h.marking.panels_completed() == 1);
  CHECK(h.result().fault);
  CHECK(h.result().reason.view() == "panel present without an inspection record");
  CHECK(h.result().panel_id.view() == "(no record)");
  CHECK(h.result().defects.empty());
  CHECK(h.line(kFault));
  CHECK(h.arm.commands.empty());
  // A record that comes now is the next panel's: it waits, and is not taken by this one.
  REQUIRE(h.marking.offer_job(record("p-2", 1)));
  h.run_to(millis(1500));
  CHECK_FALSE(h.marking.can_offer());
  CHECK(h.marking.state() == MarkingState::kWaitRelease);
}

TEST_CASE("a record without a panel expires: its result a fault, each defect 'no panel', the PLC fault held until a panel") {
  Harness h;
  h.enable(true, 0);
  REQUIRE(h.marking.offer_job(record("p-1", 2)));
  h.run_to(millis(4900));
  CHECK(h.marking.panels_completed() == 0);
  h.run_to(millis(5200));  // record_expiry: 5 s
  CHECK(h.marking.panels_completed() == 1);
  CHECK(h.result().panel_id.view() == "p-1");
  CHECK(h.result().reason.view() == "inspection record expired: its panel never came");
  for (const DefectResult& d : h.result().defects) CHECK(d.skipped == SkipReason::kNoPanel);
  CHECK(h.line(kFault));
  CHECK(h.marking.can_offer());
  h.run_to(millis(6000));
  CHECK(h.line(kFault));  // no panel to release it
  CHECK(h.arm.commands.empty());
}

TEST_CASE("a safe stop mid-acquire ends the panel as a fault with every defect stopped, the valve never opened") {
  Harness h;
  REQUIRE(h.marking.offer_job(record("p-1", 2)));
  h.enable(true, 0);
  h.panel(true, millis(10));
  h.run_to(millis(300));
  REQUIRE(h.marking.state() == MarkingState::kAcquire);
  h.gpio.drive_physical(kEstop, false);  // pressed (active low)
  h.run_to(millis(400));
  CHECK(h.safe.active());
  CHECK(h.marking.panels_completed() == 1);
  CHECK(h.result().reason.view() == "safe stop during the marking sequence");
  for (const DefectResult& d : h.result().defects) CHECK(d.skipped == SkipReason::kStopped);
  CHECK(h.valve.pulse_count() == 0);
}

TEST_CASE("no cycle enable: a panel and a record wait, nothing starts until the PLC enables the cycle") {
  Harness h;
  REQUIRE(h.marking.offer_job(record("p-1", 1)));
  h.panel(true, millis(10));
  h.run_to(millis(3000));  // past the record timeout: it does not count without cycle enable
  CHECK(h.marking.state() == MarkingState::kIdle);
  CHECK(h.marking.panels_completed() == 0);
  h.enable(true, millis(3000));
  h.run_to(millis(3100));
  CHECK(h.marking.state() == MarkingState::kAcquire);
}

TEST_CASE("recipes: each panel runs on its type's, a new set from the next panel taken on, never mid-panel") {
  Harness h;
  MarkingParams door = Harness::params(), fender = Harness::params();
  door.standoff = 0.15;
  door.timing.pulse = millis(60);
  fender.standoff = 0.25;
  REQUIRE(h.marking.set_recipes(std::vector<MarkingParams>{door, fender}));
  PanelJob first = record("f-1", 1);
  first.panel_type.assign("fender");
  first.panel_type_index = 1;
  REQUIRE(h.marking.offer_job(first));
  h.enable(true, 0);
  h.panel(true, millis(10));
  h.run_to(millis(100));
  REQUIRE(h.marking.state() == MarkingState::kAcquire);
  CHECK(h.marking.panel_params().standoff == 0.25);
  // A reload mid-panel (the service's thread): this panel keeps its own.
  MarkingParams fender2 = fender;
  fender2.standoff = 0.30;
  const std::array<MarkingParams, 2> reloaded{door, fender2};
  {
    markcell::test::AllocationGuard guard;
    REQUIRE(h.marking.set_recipes(reloaded));
    CHECK(guard.allocations_on_this_thread() == 0);
  }
  h.run_to(millis(300));
  CHECK(h.marking.panel_params().standoff == 0.25);
  h.panel(false, millis(400));
  h.run_to(millis(1000));
  REQUIRE(h.marking.state() == MarkingState::kIdle);
  // The next fender: the new set; taking it allocates nothing.
  PanelJob second = first;
  second.panel_id.assign("f-2");
  REQUIRE(h.marking.offer_job(second));
  {
    markcell::test::AllocationGuard guard;
    h.panel(true, millis(1100));
    h.run_to(millis(1200));
    CHECK(guard.allocations_on_this_thread() == 0);
  }
  REQUIRE(h.marking.state() == MarkingState::kAcquire);
  CHECK(h.marking.panel_params().standoff == 0.30);
  h.panel(false, millis(1300));
  h.run_to(millis(2000));
  // A door: its own stand-off and pulse.
  REQUIRE(h.marking.offer_job(record("d-1", 1)));  // panel_type_index 0
  h.panel(true, millis(2100));
  h.run_to(millis(2200));
  CHECK(h.marking.panel_params().standoff == 0.15);
  CHECK(h.marking.panel_params().timing.pulse == millis(60));
  // More panel types than a cell knows: refused, the set unchanged.
  const std::vector<MarkingParams> too_many(kMaxPanelTypes + 1, fender2);
  CHECK_FALSE(h.marking.set_recipes(too_many));
}

// Pairing by panel id (docs/line.md): the line's announcements decide which record a
// panel takes.
TEST_CASE("pairing by id: the panel starts with the record the line announced for it") {
  Harness h(Harness::params(), seconds(60));
  REQUIRE(h.marking.offer_job(record("p-1", 2)));
  h.enable(true, 0);
  h.announce(1, "p-1", millis(5));
  h.panel(true, millis(10));
  h.run_to(millis(100));
  CHECK(h.marking.state() == MarkingState::kAcquire);
  CHECK(h.result().panel_id.view() == "p-1");
}

TEST_CASE("pairing by id: a record for another panel than the announced one expires, the panel goes by unmarked") {
  Harness h(Harness::params(), seconds(60));
  REQUIRE(h.marking.offer_job(record("p-1", 2)));
  h.enable(true, 0);
  h.announce(1, "p-2", millis(5));  // p-1 was taken off the line: p-2 comes instead
  h.panel(true, millis(10));
  h.run_to(millis(100));
  CHECK(h.marking.panels_completed() == 1);
  CHECK(h.result().panel_id.view() == "p-1");
  CHECK(h.result().fault);
  CHECK(h.result().reason.view() == "inspection record expired: the line announced panel 'p-2' instead");
  for (const DefectResult& d : h.result().defects) CHECK(d.skipped == SkipReason::kNoPanel);
  CHECK(h.line(kFault));
  CHECK(h.arm.commands.empty());
  CHECK(h.marking.state() == MarkingState::kWaitRelease);
  // p-2's own record now: not for this panel (its announcement was answered), nothing starts.
  REQUIRE(h.marking.offer_job(record("p-2", 1)));
  h.run_to(millis(2000));
  CHECK(h.marking.panels_completed() == 1);
  CHECK(h.arm.commands.empty());
  h.panel(false, millis(2000));  // it leaves: the fault line drops
  h.run_to(millis(2100));
  CHECK_FALSE(h.line(kFault));
  CHECK(h.marking.state() == MarkingState::kIdle);
}

TEST_CASE("pairing by id: a panel announced without its record ends with the announced id in its result") {
  Harness h(Harness::params(), seconds(60));
  h.enable(true, 0);
  h.announce(7, "p-9", millis(5));
  h.panel(true, millis(10));
  h.run_to(millis(1100));  // record_timeout: 1 s
  CHECK(h.marking.panels_completed() == 1);
  CHECK(h.result().panel_id.view() == "p-9");
  CHECK(h.result().reason.view() == "panel 'p-9' present without its inspection record");
  CHECK(h.line(kFault));
  CHECK(h.arm.commands.empty());
}

TEST_CASE("pairing by id: one announcement starts one panel and the next panel without a new one goes by unmarked") {
  Harness h(Harness::params(), seconds(60));
  REQUIRE(h.marking.offer_job(record("p-1", 1)));
  h.enable(true, 0);
  h.announce(1, "p-1", millis(5));
  h.panel(true, millis(10));
  h.run_to(millis(100));
  REQUIRE(h.marking.state() == MarkingState::kAcquire);
  h.panel(false, millis(200));  // it leaves before its MFs are found: the panel ends
  h.run_to(millis(1000));
  REQUIRE(h.marking.panels_completed() == 1);
  REQUIRE(h.marking.state() == MarkingState::kIdle);
  // A record with the same id again, and a second panel with no new announcement.
  REQUIRE(h.marking.offer_job(record("p-1", 1)));
  h.panel(true, millis(1100));
  h.run_to(millis(2000));
  CHECK(h.marking.panels_completed() == 1);
  CHECK(h.marking.state() == MarkingState::kIdle);
  h.run_to(millis(2300));  // record_timeout after the panel
  CHECK(h.marking.panels_completed() == 2);
  CHECK(h.result().panel_id.view() == "(no record)");
  CHECK(h.result().reason.view() == "panel present, but the line announced no new panel id");
  CHECK_FALSE(h.marking.can_offer());  // the record was not used: it waits (and expires with no panel)
}

TEST_CASE("pairing by id: a record offered for a panel the line then replaces expires at once and the next panel is marked") {
  Harness h(Harness::params(), seconds(60));
  h.enable(true, 0);
  h.announce(1, "p-1", millis(5));
  PanelJob first = record("p-1", 2);
  first.announced = 1;  // as the drop folder offers it: for announcement 1
  REQUIRE(h.marking.offer_job(first));
  h.announce(2, "p-2", millis(50));  // p-1 taken off before the station: p-2 comes
  h.run_to(millis(60));
  CHECK(h.marking.panels_completed() == 1);
  CHECK(h.result().panel_id.view() == "p-1");
  CHECK(h.result().reason.view() == "inspection record expired: the line announced panel 'p-2' instead");
  for (const DefectResult& d : h.result().defects) CHECK(d.skipped == SkipReason::kNoPanel);
  REQUIRE(h.marking.can_offer());  // p-2's record is not held behind it
  PanelJob second = record("p-2", 1);
  second.announced = 2;
  REQUIRE(h.marking.offer_job(second));
  h.panel(true, millis(100));
  h.run_to(millis(200));
  CHECK(h.marking.state() == MarkingState::kAcquire);
  CHECK(h.result().panel_id.view() == "p-2");
  CHECK_FALSE(h.line(kFault));  // the new panel's start cleared the expired record's fault
}

TEST_CASE("pairing by id: a record that comes after its panel went by expires at once") {
  Harness h(Harness::params(), seconds(60));
  h.enable(true, 0);
  h.announce(1, "p-9", millis(5));
  h.panel(true, millis(10));
  h.run_to(millis(1100));  // record_timeout: the panel goes by without its record
  REQUIRE(h.marking.panels_completed() == 1);
  h.panel(false, millis(1200));
  h.run_to(millis(1300));
  REQUIRE(h.marking.state() == MarkingState::kIdle);
  PanelJob late = record("p-9", 1);
  late.announced = 1;
  REQUIRE(h.marking.offer_job(late));
  h.run_to(millis(1400));
  CHECK(h.marking.panels_completed() == 2);
  CHECK(h.result().panel_id.view() == "p-9");
  CHECK(h.result().reason.view() == "inspection record expired: its panel went by before it came");
  CHECK(h.marking.can_offer());
  CHECK(h.arm.commands.empty());
}

TEST_CASE("pairing by id: a panel-id source that stops answering stops the cell, naming plc_link and the silence") {
  Harness h(Harness::params(), millis(500));
  h.enable(true, 0);
  h.announce(1, "p-1", millis(100));
  h.run_to(millis(550));
  CHECK_FALSE(h.safe.active());  // heard at 100 ms: 450 ms of silence so far
  h.run_to(millis(700));
  REQUIRE(h.safe.active());
  CHECK(h.safe.reason().code == FaultCode::kDeviceFault);
  CHECK(h.safe.reason().source.view() == "plc_link");
  // (the marking task runs every 2 ms: the first run past the limit)
  CHECK(h.safe.reason().detail.view() == "the line's panel-id source has not answered for 502 ms (limit 500 ms)");
  CHECK(h.line(kFault));
}
