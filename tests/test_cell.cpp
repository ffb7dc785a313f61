// The cell assembled from the example configuration, in simulated time: the arm link
// over the simulated CAN arm, valve pulses timed by the executive, device faults to the
// safe stop, and 10,000 cycles of the whole cell with no heap allocation.
#include <catch2/catch.hpp>
#include <cstdio>

#include "alloc_guard.hpp"
#include "markcell/host/cell.hpp"
#include "test_files.hpp"

using namespace markcell;
using namespace markcell::host;

namespace {

struct SimCell {
  SimCell() : config(load_config(test::source_path("config/cell.example.yaml"), task_catalog())), cell(config, ClockKind::kSimulated) {
    cell.start();
  }
  ~SimCell() { cell.shutdown(control::FaultCode::kShutdown, "test", "end of test"); }
  void run_to(Nanos t) { REQUIRE(cell.sim_clock()->run_until(t) == control::SimClock::RunResult::kReached); }
  bool line(LineRole role) const { return const_cast<Cell&>(cell).sim_gpio()->physical(static_cast<int>(role)); }
  // At 200 ms the arm is sent towards a far target; at 400 ms it is on its way.
  void arm_on_its_way() {
    run_to(millis(200));
    drivers::ArmCommand move;
    move.mode = drivers::ArmMode::kMove;
    move.target.position = {0.9, 0.4, 0.2};
    cell.arm_link().send(move, millis(200));
    run_to(millis(400));
  }
  // The valve opens only with a panel in front of it (the PLC's panel present).
  void panel_in_front(bool present = true) { cell.drive_sim_input(LineRole::kPlcPanelPresent, present); }
  CellConfig config;
  Cell cell;
};

}  // namespace

TEST_CASE("the simulated cell brings the arm link up over the simulated CAN arm") {
  SimCell s;
  s.run_to(millis(500));
  CHECK(s.cell.arm_supervision().status() == drivers::ArmLinkStatus::kOk);
  CHECK(s.cell.sim_arm()->nmt_state() == drivers::canopen::NmtState::kOperational);
  CHECK_FALSE(s.cell.safe_stop().active());
  CHECK(s.line(LineRole::kPlcReady));
  CHECK_FALSE(s.line(LineRole::kPlcFault));
}

TEST_CASE("the valve's pulse record and the nozzle's are rings: pulse 300 is counted and readable, the oldest overwritten") {
  // A cell sprays for years: the count never stops, the newest kHistory pulses are kept.
  SimCell s;
  s.panel_in_front();
  s.run_to(millis(50));  // the valve's interlock: panel present seen steady
  constexpr std::uint64_t kPulses = control::SprayValve::kHistory + 44;
  for (std::uint64_t i = 0; i < kPulses; ++i) {
    const Nanos start = millis(100) + static_cast<Nanos>(i) * millis(20);
    REQUIRE(s.cell.spray_valve().request(start, millis(10), false) == control::PulseRequest::kAccepted);
    s.run_to(start + millis(15));
    REQUIRE(s.cell.spray_valve().pulse_count() == i + 1);
    const auto& p = s.cell.spray_valve().pulse(i);
    CHECK(p.requested_start == start);
    CHECK(p.opened == start);
    CHECK(p.closed == start + millis(10));
  }
  // The oldest kept is pulse 44; pulse 0's slot now holds pulse 256.
  CHECK(s.cell.spray_valve().pulse(44).requested_start == millis(100) + 44 * millis(20));
  CHECK(s.cell.spray_valve().pulse(0).requested_start == millis(100) + 256 * millis(20));
  // The simulated world saw every opening at the nozzle, at its tick, and keeps the newest.
  const sim::NozzleWitness& nozzle = *s.cell.sim_nozzle();
  CHECK(nozzle.total() == kPulses);
  REQUIRE(nozzle.kept() == sim::NozzleWitness::kCapacity);
  for (std::size_t i = nozzle.total() - nozzle.kept(); i < nozzle.total(); ++i)
    CHECK(nozzle.spray(i).time == millis(100) + static_cast<Nanos>(i) * millis(20));
}

TEST_CASE("a valve pulse opens and closes on the executive's ticks") {
  SimCell s;
  s.panel_in_front();
  s.run_to(millis(100));
  // Asked for 100.5 ms + 80 ms: opens at the first tick at or after 100.5 ms (101 ms),
  // closes at the first tick at or after 180.5 ms (181 ms).
  REQUIRE(s.cell.spray_valve().request(micros(100'500), millis(80), false) == control::PulseRequest::kAccepted);
  CHECK(s.cell.spray_valve().request(millis(150), millis(80), false) == control::PulseRequest::kBusy);
  s.run_to(millis(300));
  REQUIRE(s.cell.spray_valve().pulse_count() == 1);
  const auto& p = s.cell.spray_valve().pulse(0);
  CHECK(p.opened == millis(101));
  CHECK(p.closed == millis(181));
  CHECK_FALSE(p.cut_short);
  // The wire saw the same: the valve line went high at 101 ms and low at 181 ms.
  std::vector<std::pair<bool, Nanos>> valve;
  for (const auto& e : s.cell.sim_gpio()->output_history())
    if (e.line == static_cast<int>(LineRole::kSprayValve)) valve.emplace_back(e.active, e.time);
  REQUIRE(valve.size() == 2);
  CHECK(valve[0] == std::pair<bool, Nanos>{true, millis(101)});
  CHECK(valve[1] == std::pair<bool, Nanos>{false, millis(181)});
  CHECK(s.cell.spray_valve().request(millis(400), millis(1), false) == control::PulseRequest::kBadLength);
}

TEST_CASE("the arm falling silent safe-stops the cell: valve closed, PLC told") {
  SimCell s;
  s.panel_in_front();
  s.run_to(millis(200));
  REQUIRE(s.cell.spray_valve().request(millis(250), millis(400), false) == control::PulseRequest::kAccepted);
  s.run_to(millis(300));
  REQUIRE(s.line(LineRole::kSprayValve));
  s.cell.sim_arm()->set_silent(true);
  s.run_to(millis(700));
  REQUIRE(s.cell.safe_stop().done());
  const auto& why = s.cell.safe_stop().reason();
  CHECK(why.code == control::FaultCode::kDeviceFault);
  CHECK(why.source.view() == "arm");
  CHECK(why.detail.view() == "arm link heartbeat_lost (arm fault code 0)");
  // The arm's last heartbeat went out in the 300 ms tick (sim_world runs after
  // arm_link), the link read it at 301 ms, and the first tick more than 150 ms later is
  // 452 ms.
  CHECK(why.time == millis(452));
  CHECK_FALSE(s.line(LineRole::kSprayValve));
  CHECK(s.line(LineRole::kPlcFault));
  CHECK_FALSE(s.line(LineRole::kPlcReady));
  REQUIRE(s.cell.spray_valve().pulse_count() == 1);
  CHECK(s.cell.spray_valve().pulse(0).cut_short);
}

TEST_CASE("an e-stop holds the arm where it is") {
  SimCell s;
  s.arm_on_its_way();
  const auto moving = s.cell.sim_arm()->model().tool().position;
  CHECK(moving[0] > 0.35);
  const int estop = static_cast<int>(LineRole::kPlcEstop);
  s.cell.sim_gpio()->drive_physical(estop, false);  // active low: pressed
  s.run_to(millis(1500));
  REQUIRE(s.cell.safe_stop().done());
  CHECK(s.cell.safe_stop().reason().code == control::FaultCode::kOperatorStop);
  CHECK(s.cell.sim_arm()->model().state().mode == drivers::ArmMode::kHold);
  const auto held = s.cell.sim_arm()->model().tool().position;
  CHECK(held[0] < 0.9 - 0.05);  // it did not carry on to the target
}

TEST_CASE("no panel present, no spray: the valve refuses a pulse, and closes on the tick after the panel goes") {
  SimCell s;
  s.run_to(millis(100));
  CHECK(s.cell.spray_valve().request(millis(150), millis(80), false) == control::PulseRequest::kNotPermitted);
  s.panel_in_front();
  s.run_to(millis(200));
  REQUIRE(s.cell.spray_valve().request(millis(250), millis(480), false) == control::PulseRequest::kAccepted);
  s.run_to(micros(700'400));
  REQUIRE(s.line(LineRole::kSprayValve));
  s.panel_in_front(false);
  s.run_to(millis(800));
  CHECK_FALSE(s.line(LineRole::kSprayValve));
  REQUIRE(s.cell.spray_valve().pulse_count() == 1);
  CHECK(s.cell.spray_valve().pulse(0).closed == millis(701));
  CHECK(s.cell.spray_valve().pulse(0).cut_short);
  CHECK_FALSE(s.cell.safe_stop().active());  // a panel leaving is not a fault of the cell
}

TEST_CASE("after an e-stop: the PLC's release and reset send the arm home, then the cell runs again") {
  SimCell s;
  s.arm_on_its_way();
  s.cell.drive_sim_input(LineRole::kPlcEstop, true);  // pressed
  s.run_to(millis(1500));
  REQUIRE(s.cell.safe_stop().done());
  CHECK(s.line(LineRole::kPlcFault));
  CHECK_FALSE(s.line(LineRole::kPlcReady));
  CHECK(s.cell.safe_stop().recoverable());
  // Released: still stopped, the PLC told so, until its reset edge.
  s.cell.drive_sim_input(LineRole::kPlcEstop, false);
  s.run_to(millis(2000));
  CHECK(s.cell.safe_stop().done());
  CHECK(s.line(LineRole::kPlcFault));
  s.cell.drive_sim_input(LineRole::kPlcCycleEnable, false);
  s.run_to(millis(2100));
  s.cell.drive_sim_input(LineRole::kPlcCycleEnable, true);
  s.run_to(millis(2110));
  CHECK(s.cell.safe_stop().rearm_requested());
  CHECK(s.cell.safe_stop().done());  // the arm is on its way home
  s.run_to(millis(6000));
  CHECK(s.cell.sim_arm()->model().state().flags & drivers::kHomed);
  CHECK_FALSE(s.cell.safe_stop().active());
  CHECK(s.line(LineRole::kPlcReady));
  CHECK_FALSE(s.line(LineRole::kPlcFault));
  // Every step is in the fault log: the stop, then the re-arm.
  control::Fault f;
  std::vector<std::string> log;
  while (s.cell.faults().pop(f)) log.push_back(std::string(control::to_string(f.code)) + " " + std::string(f.detail.view()));
  REQUIRE(log.size() >= 2);
  CHECK(log.front() == "operator_stop e-stop input active");
  CHECK(log.back() == "rearm e-stop released, reset by cycle enable, arm at home");
  // And it sprays again.
  s.panel_in_front();
  s.run_to(millis(6100));
  CHECK(s.cell.spray_valve().request(millis(6200), millis(80), false) == control::PulseRequest::kAccepted);
  s.run_to(millis(6300));
  CHECK(s.cell.spray_valve().pulse(s.cell.spray_valve().pulse_count() - 1).closed == millis(6280));
}

TEST_CASE("10,000 cycles of the whole simulated cell allocate nothing") {
  SimCell s;
  s.panel_in_front();
  s.run_to(millis(200));  // warm-up: link up, first states in
  REQUIRE(s.cell.spray_valve().request(millis(5000), millis(80), false) == control::PulseRequest::kAccepted);
  std::size_t allocations = 0;
  control::SimClock::RunResult result;
  {
    test::AllocationGuard guard;
    result = s.cell.sim_clock()->run_until(millis(200) + seconds(10));
    allocations = guard.allocations();
  }
  CHECK(result == control::SimClock::RunResult::kReached);
  CHECK(allocations == 0);
  CHECK(s.cell.executive().task_stats(0).exec.count() == 10'201);
  CHECK(s.cell.arm_supervision().status() == drivers::ArmLinkStatus::kOk);
  CHECK(s.cell.spray_valve().pulse_count() == 1);
  CHECK_FALSE(s.cell.safe_stop().active());
}

TEST_CASE("the camera_trigger task: a rising edge on the trigger line every other run") {
  CellConfig config = load_config(test::source_path("config/cell.example.yaml"), task_catalog());
  control::TaskSpec trigger;
  trigger.name = "camera_trigger";
  trigger.lane = 0;  // control
  trigger.period_ticks = 17;  // 17 ms at the 1 ms tick: 29.4 frames/s
  trigger.budget = micros(50);
  config.executive.tasks.push_back(trigger);
  Cell cell(config, ClockKind::kSimulated);
  cell.start();
  REQUIRE(cell.sim_clock()->run_until(seconds(1)) == control::SimClock::RunResult::kReached);
  std::vector<Nanos> rising;
  for (const auto& e : cell.sim_gpio()->output_history())
    if (e.line == static_cast<int>(LineRole::kCameraTrigger) && e.active) rising.push_back(e.time);
  cell.shutdown(control::FaultCode::kShutdown, "test", "end of test");
  // Runs at 0, 17, 34, ... ms; high on the 1st, 3rd, ...: rising edges at 0, 34, 68, ... ms.
  REQUIRE(rising.size() == 30);  // 0 .. 986 ms
  for (std::size_t i = 0; i < rising.size(); ++i) CHECK(rising[i] == millis(34) * static_cast<Nanos>(i));
  // The line ends low: safe state after the shutdown.
  CHECK_FALSE(cell.sim_gpio()->physical(static_cast<int>(LineRole::kCameraTrigger)));
}

TEST_CASE("the command logs: CAN frames in candump -L, a serial frame off the wire, the valve's edges, what a full log could not keep") {
  sim::CommandLog log;
  log.reserve(6);
  drivers::CanFrame can;
  can.id = 0x202;
  can.len = 3;
  can.data[0] = 0x01, can.data[1] = 0xAB, can.data[2] = 0xFF;
  log.frame(millis(1500), can);
  drivers::CanFrame fd;  // CAN FD, 29-bit id: candump's "ID##F" and eight digits
  fd.id = 0x1234567;
  fd.extended = true;
  fd.fd = true;
  fd.len = 2;
  fd.data[0] = 0x5A, fd.data[1] = 0x00;
  log.frame(millis(1600), fd);
  // A command as the controller puts it on the line, decoded as the rig's arm decodes it.
  drivers::ArmCommand command;
  command.mode = drivers::ArmMode::kMove;
  command.time = seconds(2);
  command.target.position = {0.5, -0.25, 0.4};
  std::array<std::uint8_t, drivers::serial::kMaxFrame> wire{};
  const std::size_t size = drivers::serial::encode_command(command, 0x2A, wire);
  drivers::serial::Decoder decoder;
  REQUIRE(decoder.push(std::span<const std::uint8_t>(wire.data(), size)) == size);
  drivers::serial::Frame frame;
  REQUIRE(decoder.next(frame) == drivers::serial::Decoder::Result::kFrame);
  log.frame(millis(2250), frame);
  log.valve(seconds(3), true);
  log.valve(seconds(3) + 2500, false);  // microseconds: 2.5 us is written 2
  log.valve(millis(500), true);         // before the epoch by half a second
  log.valve(seconds(4), true);          // a seventh entry: not kept, counted
  // The serial line's payload is the wire's bytes between the header and the CRC.
  std::string payload;
  char hex[3];
  for (std::size_t i = drivers::serial::kHeader; i < size - 2; ++i) {
    std::snprintf(hex, sizeof hex, "%02X", wire[i]);
    payload += hex;
  }
  REQUIRE(payload.size() == 2 * drivers::serial::kCommandSize);
  const sim::CommandLogText text = log.text(seconds(1), "vcan3");
  CHECK(text.can == "(946684800.500000) vcan3 202#01ABFF\n"
                    "(946684800.600000) vcan3 01234567##05A00\n");
  CHECK(text.serial == "(946684801.250000) serial 01#2A#" + payload + "\n"
                       "# 1 entries not kept: the log was full\n");
  CHECK(text.valve == "(946684802.000000) valve open\n"
                      "(946684802.000002) valve close\n"
                      "(946684799.500000) valve open\n"
                      "# 1 entries not kept: the log was full\n");
}
