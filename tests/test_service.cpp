// `markcell run` as systemd runs it: the test owns NOTIFY_SOCKET, starts the real binary
// on the example configuration (simulated devices, real clock) and watches the notify
// protocol: READY=1 after start-up, WATCHDOG=1 while it runs, STOPPING=1 and exit 0 on
// SIGTERM.
#include <signal.h>
#include <spawn.h>
#include <fcntl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <string>
#include <vector>

#include "markcell/common/time.hpp"
#include "notify_socket.hpp"
#include "test_files.hpp"

extern char** environ;

using namespace markcell;


TEST_CASE("markcell run under systemd's notify protocol: READY=1, the watchdog fed, STOPPING=1 and exit 0 on SIGTERM") {
  test::TempDir dir;
  const std::string socket_path = (dir.path() / "notify").string();
  test::NotifySocket notify(socket_path);
  const std::string log = (dir.path() / "stderr").string();

  std::vector<std::string> env_strings;
  for (char** e = environ; *e != nullptr; ++e) {
    const std::string s(*e);
    if (s.rfind("NOTIFY_SOCKET=", 0) != 0 && s.rfind("WATCHDOG_", 0) != 0) env_strings.push_back(s);
  }
  env_strings.push_back("NOTIFY_SOCKET=" + socket_path);
  env_strings.push_back("WATCHDOG_USEC=1000000");  // WatchdogSec=1s: fed every 500 ms
  std::vector<char*> envp;
  for (auto& s : env_strings) envp.push_back(s.data());
  envp.push_back(nullptr);
  std::string binary = MARKCELL_BINARY, run = "run", flag = "--config", config = test::source_path("config/cell.example.yaml");
  std::vector<char*> argv{binary.data(), run.data(), flag.data(), config.data(), nullptr};
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 2, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_addopen(&actions, 1, "/dev/null", O_WRONLY, 0);
  // The test may run with SIGTERM blocked or ignored; the child starts with defaults.
  posix_spawnattr_t attr;
  posix_spawnattr_init(&attr);
  sigset_t none, term;
  sigemptyset(&none);
  sigemptyset(&term);
  sigaddset(&term, SIGTERM);
  posix_spawnattr_setsigmask(&attr, &none);
  posix_spawnattr_setsigdefault(&attr, &term);
  posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETSIGMASK | POSIX_SPAWN_SETSIGDEF);
  pid_t pid = -1;
  REQUIRE(posix_spawn(&pid, binary.c_str(), &actions, &attr, argv.data(), envp.data()) == 0);
  posix_spawn_file_actions_destroy(&actions);
  posix_spawnattr_destroy(&attr);

  const bool ready = notify.collect(seconds(60), [&] { return notify.count("READY=1") > 0; });
  const Nanos ready_at = monotonic_now();
  const bool fed = ready && notify.collect(seconds(5), [&] { return notify.count("WATCHDOG=1") >= 3; });
  const Nanos fed_in = monotonic_now() - ready_at;
  kill(pid, SIGTERM);
  const bool stopping = notify.collect(seconds(20), [&] { return notify.count("STOPPING=1") > 0; });
  int status = 0;
  pid_t waited = 0;
  for (int i = 0; i < 200 && waited == 0; ++i) {  // at most 20 s
    waited = waitpid(pid, &status, WNOHANG);
    if (waited == 0) usleep(100'000);
  }
  if (waited == 0) {
    kill(pid, SIGKILL);
    waitpid(pid, &status, 0);
  }
  const std::string err = test::read_file(log);
  INFO(err);
  CHECK(ready);
  CHECK(fed);
  INFO("three WATCHDOG=1 within " << to_seconds(fed_in) << " s of READY=1");
  CHECK(stopping);
  REQUIRE(waited == pid);
  REQUIRE(WIFEXITED(status));
  CHECK(WEXITSTATUS(status) == 0);
  CHECK(err.find("<6>markcell: stopped (SIGTERM)") != std::string::npos);
  // The messages came in protocol order: READY first, STOPPING last.
  REQUIRE(!notify.messages.empty());
  CHECK(notify.messages.front().text == "READY=1");
  CHECK(notify.messages.back().text == "STOPPING=1");
}
