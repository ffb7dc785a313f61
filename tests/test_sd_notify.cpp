// systemd's notify protocol, seen from systemd's side: the test owns NOTIFY_SOCKET.
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <chrono>
#include <cstdlib>
#include <string>
#include <thread>
#include <vector>

#include "markcell/control/executive.hpp"
#include "markcell/host/sd_notify.hpp"
#include "notify_socket.hpp"
#include "test_files.hpp"

using namespace markcell;
using namespace markcell::control;


TEST_CASE("READY=1, WATCHDOG=1 at the interval while the lanes tick, none once a lane stalls, STOPPING=1") {
  test::TempDir dir;
  const std::string socket_path = (dir.path() / "notify").string();
  test::NotifySocket listener(socket_path);
  setenv("NOTIFY_SOCKET", socket_path.c_str(), 1);
  setenv("WATCHDOG_USEC", "200000", 1);  // WatchdogSec=200ms: feed every 100 ms
  unsetenv("WATCHDOG_PID");
  host::SystemdNotifier notifier(millis(999));
  CHECK(notifier.under_systemd());
  CHECK(notifier.watchdog_requested());
  CHECK(notifier.interval() == millis(100));

  ExecutiveSpec spec;
  spec.tick = millis(1);
  spec.lanes = {{"control", -1, 0}};
  spec.tasks = {{"worker", 0, 5, 0, millis(5), OverrunPolicy::kLog}};
  spec.lane_stall_limit = millis(300);  // a loaded test machine's scheduling is not a stall
  spec.supervisor_period = millis(20);
  RealClock clock;
  FaultLog log;
  SafeStop safe(log);
  Executive exec(spec, clock, safe);
  struct Blocker {
    std::atomic<bool> block{false};
  } blocker;
  exec.bind("worker", [](TaskContext&, void* u) {
    auto& b = *static_cast<Blocker*>(u);
    // A lane that hangs: sleeps (bounded, 1.5 s) when told to.
    if (b.block.exchange(false)) std::this_thread::sleep_for(std::chrono::milliseconds(1500));
    return TaskResult::kOk;
  }, &blocker);
  exec.add_watchdog(notifier);
  exec.start();
  notifier.ready();
  listener.collect(millis(700));
  blocker.block = true;
  listener.collect(millis(1000), [&] { return safe.done(); });
  listener.collect(millis(60));  // what was already on its way
  const std::size_t at_stall = listener.messages.size();
  listener.collect(millis(500));
  notifier.stopping();
  listener.collect(millis(50));
  exec.stop();
  unsetenv("NOTIFY_SOCKET");
  unsetenv("WATCHDOG_USEC");

  const auto& m = listener.messages;
  REQUIRE(!m.empty());
  CHECK(m.front().text == "READY=1");
  std::vector<Nanos> feeds;
  for (const auto& x : m)
    if (x.text == "WATCHDOG=1") feeds.push_back(x.sent);
  INFO("WATCHDOG=1 messages: " << feeds.size());
  CHECK(feeds.size() >= 3);  // ~6 in the first 700 ms on an idle machine
  // Never faster than the interval, judged as sent (a reader descheduled on a loaded machine
  // reads two queued feeds microseconds apart): on average over the run at least the
  // interval less the supervisor's period (its own jitter), and no two feeds closer than
  // half the interval (a sender preempted between its clock and its send shortens one gap;
  // a feed sent twice would be microseconds apart).
  REQUIRE(feeds.size() >= 2);
  CHECK(feeds.back() - feeds.front() >= static_cast<Nanos>(feeds.size() - 1) * (millis(100) - millis(20)));
  for (std::size_t i = 1; i < feeds.size(); ++i) CHECK(feeds[i] - feeds[i - 1] >= millis(50));
  // The stall is seen, the safe stop names the lane, and the watchdog starves.
  REQUIRE(safe.done());
  CHECK(safe.reason().code == FaultCode::kLaneStall);
  CHECK(safe.reason().source.view() == "control");
  int after_stall = 0;
  for (std::size_t i = at_stall; i < m.size(); ++i) after_stall += m[i].text == "WATCHDOG=1";
  CHECK(after_stall == 0);
  CHECK(m.size() > at_stall);  // STOPPING=1 did arrive: the socket was still being read
  CHECK(m.back().text == "STOPPING=1");
}
