// The simulated GPIO line set, the PLC handshake task, and the watchdog device.
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <cstring>
#include <system_error>
#include <thread>

#include "markcell/control/plc_io.hpp"
#include "markcell/drivers/gpio.hpp"
#include "markcell/drivers/gpiod_lines.hpp"
#include "markcell/drivers/watchdog_device.hpp"
#include "test_files.hpp"

using namespace markcell;
using namespace markcell::drivers;

TEST_CASE("simulated GPIO: active-low, directions, safe state, edges with time") {
  SimGpioLines gpio;
  Nanos fake_now = 1000;
  gpio.set_time_source([](void* t) { return *static_cast<Nanos*>(t); }, &fake_now);
  gpio.configure({{"VALVE", true, false, false}, {"FAULT", true, true, false}, {"ESTOP", false, true, false}});
  bool v = true;
  CHECK(gpio.set(0, true) == GpioStatus::kNotActive);
  gpio.activate();
  CHECK_FALSE(gpio.physical(0));  // valve: safe = inactive = low
  CHECK(gpio.physical(1));        // fault, active-low: inactive = high
  CHECK(gpio.physical(2));        // e-stop input rests released (high, active-low)
  CHECK(gpio.get(2, v) == GpioStatus::kOk);
  CHECK_FALSE(v);
  CHECK(gpio.set(2, true) == GpioStatus::kWrongDirection);
  CHECK(gpio.set(7, true) == GpioStatus::kBadLine);
  fake_now = 2000;
  CHECK(gpio.set(0, true) == GpioStatus::kOk);
  CHECK(gpio.physical(0));
  fake_now = 3000;
  gpio.drive_physical(2, false);  // e-stop pressed: pulls the active-low line down
  std::array<LineEvent, 4> events{};
  REQUIRE(gpio.read_events(events, 0) == 1);
  CHECK(events[0].line == 2);
  CHECK(events[0].active);
  CHECK(events[0].time == 3000);
  fake_now = 4000;
  gpio.outputs_to_safe_state();
  CHECK_FALSE(gpio.physical(0));
  const auto history = gpio.output_history();
  REQUIRE(history.size() == 2);
  CHECK(history[0].line == 0);
  CHECK(history[0].active);
  CHECK(history[0].time == 2000);
  CHECK(history[1].time == 4000);
  CHECK_FALSE(history[1].active);
  CHECK_THROWS_WITH(SimGpioLines().configure({{"A", true, false, false}, {"A", false, false, false}}),
                    "gpio (simulated): line 'A' requested twice");
}

TEST_CASE("plc_io: ready follows cycle enable, e-stop safe-stops and raises the fault line") {
  SimGpioLines gpio;
  gpio.configure({{"PANEL", false, false, false}, {"ENABLE", false, false, false}, {"ESTOP", false, true, false},
                  {"READY", true, false, false}, {"FAULT", true, false, false}, {"VALVE", true, false, false}});
  control::FaultLog log;
  control::SafeStop safe(log);
  control::GpioSafeOutputs outputs(gpio, 4);
  safe.add_output(outputs);
  control::PlcIo plc(gpio, control::PlcLineMap{0, 1, 2, 3, -1, -1, 4}, safe);

  control::ExecutiveSpec spec;
  spec.lanes = {{"control", -1, 0}};
  spec.tasks = {{"plc_io", 0, 1, 0, micros(200), control::OverrunPolicy::kSafeStop}};
  control::SimClock clock(control::Executive::clock_lanes(spec));
  control::Executive exec(spec, clock, safe);
  exec.bind("plc_io", &control::PlcIo::task, &plc);
  gpio.set_time_source([](void* c) { return static_cast<control::SimClock*>(c)->global_now(); }, &clock);
  gpio.activate();
  exec.start();
  REQUIRE(clock.run_until(millis(3)) == control::SimClock::RunResult::kReached);
  CHECK_FALSE(gpio.physical(3));  // cycle not enabled: not ready
  gpio.drive_physical(1, true);
  REQUIRE(clock.run_until(millis(6)) == control::SimClock::RunResult::kReached);
  CHECK(gpio.physical(3));
  gpio.drive_physical(0, true);  // a panel arrives at 6 ms
  gpio.drive_physical(2, false);  // and the e-stop is pressed
  gpio.set(5, true);             // the valve happened to be open
  REQUIRE(clock.run_until(millis(9)) == control::SimClock::RunResult::kReached);
  exec.stop();
  CHECK(plc.inputs().panel_present);
  CHECK(plc.inputs().panel_present_since == millis(6));
  REQUIRE(safe.done());
  CHECK(safe.reason().code == control::FaultCode::kOperatorStop);
  CHECK(safe.reason().time == millis(7));
  CHECK_FALSE(gpio.physical(5));  // valve closed
  CHECK_FALSE(gpio.physical(3));  // not ready
  CHECK(gpio.physical(4));        // fault raised
  CHECK(plc.io_errors() == 0);
}

TEST_CASE("watchdog device: feeds, and the magic close disarms it") {
  test::TempDir dir;
  const std::string fifo = (dir.path() / "watchdog").string();
  REQUIRE(mkfifo(fifo.c_str(), 0600) == 0);
  const int reader = open(fifo.c_str(), O_RDONLY | O_NONBLOCK);
  REQUIRE(reader >= 0);
  {
    WatchdogDevice wd({fifo, 0});
    CHECK_FALSE(wd.feed());
    wd.activate();
    CHECK(wd.feed());
    CHECK(wd.feed());
    wd.deactivate();
    CHECK_FALSE(wd.active());
  }
  char buf[8] = {};
  REQUIRE(read(reader, buf, sizeof buf) == 3);
  CHECK(buf[0] == '\0');
  CHECK(buf[1] == '\0');
  CHECK(buf[2] == 'V');  // the magic close disarms it on an orderly stop
  close(reader);
}

// [kernel-ioctl]: the error is the kernel's answer to a watchdog ioctl on a plain file
// (ENOTTY); qemu-user answers ioctls it does not emulate with ENOSYS itself, so the arm64
// suite under qemu leaves this case out (tests/CMakeLists.txt).
TEST_CASE("watchdog device: a clear error for a file that is not a watchdog", "[kernel-ioctl]") {
  test::TempDir dir;
  const std::string plain = dir.write("not-a-watchdog", "");
  WatchdogDevice wrong({plain, 10});
  CHECK_THROWS_WITH(wrong.activate(), "watchdog device '" + plain +
                                          "': WDIOC_SETTIMEOUT 10 s (is it a watchdog device?): Inappropriate ioctl for device");
  WatchdogDevice missing({(dir.path() / "none").string(), 0});
  CHECK_THROWS_AS(missing.activate(), std::system_error);
}

TEST_CASE("libgpiod lines: a chip that is not there is a clear error at configure") {
  GpiodLines lines("gpiochip-markcell-none");
  CHECK_THROWS_WITH(lines.configure({{"MC_SPRAY_VALVE", true, false, false}}),
                    "gpio chip 'gpiochip-markcell-none': cannot open: No such file or directory");
  CHECK_FALSE(lines.active());
  CHECK(lines.set(0, true) == GpioStatus::kNotActive);
  CHECK_THROWS_WITH(lines.activate(), "gpio chip 'gpiochip-markcell-none': activate before configure");
}
