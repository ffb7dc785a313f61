// `markcell run` as systemd runs it: the test owns NOTIFY_SOCKET, starts the real binary
// on the example configuration (simulated devices, real clock) and watches the notify
// protocol: READY=1 after start-up, WATCHDOG=1 while it runs, RELOADING=1 and READY=1
// around a reload (SIGHUP, as the unit's ExecReload sends it), STOPPING=1 and exit 0 on
// SIGTERM.
#include <signal.h>
#include <spawn.h>
#include <fcntl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "markcell/common/time.hpp"
#include "notify_socket.hpp"
#include "test_files.hpp"

extern char** environ;

using namespace markcell;


TEST_CASE("markcell run under systemd's notify protocol: READY=1, the watchdog fed, reloads, STOPPING=1 and exit 0 on SIGTERM") {
  test::TempDir dir;
  // A copy of the example configuration, for the test to edit while the cell runs.
  const auto config_dir = dir.path() / "config";
  std::filesystem::copy(test::source_path("config"), config_dir, std::filesystem::copy_options::recursive);
  const std::string config_file = (config_dir / "cell.example.yaml").string();
  const std::string shipped = test::read_file(config_file);
  const std::string door = "  door:   {macro_features: 10, file: panels/door.yaml}";
  REQUIRE(shipped.find(door) != std::string::npos);
  const auto with_door_recipe = [&](const std::string& recipe) {
    std::string text = shipped;
    text.replace(text.find(door), door.size(), door.substr(0, door.size() - 1) + ", recipe: " + recipe + "}");
    std::ofstream(config_file) << text;
  };
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
  std::string binary = MARKCELL_BINARY, run = "run", flag = "--config", config = config_file;
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
  // systemctl reload: a recipe for the door taken; then a file that is not valid now:
  // each error logged at its position, nothing changed, the cell still running.
  with_door_recipe("{standoff_m: 0.18, pulse_ms: 60}");
  kill(pid, SIGHUP);
  const bool reloaded = fed && notify.collect(seconds(20), [&] { return notify.count("READY=1") >= 2; });
  with_door_recipe("{standoff_m: 7}");
  kill(pid, SIGHUP);
  const bool refused = reloaded && notify.collect(seconds(20), [&] { return notify.count("READY=1") >= 3; });
  const int watchdog_before = notify.count("WATCHDOG=1");
  const bool still_fed = refused && notify.collect(seconds(5), [&] { return notify.count("WATCHDOG=1") >= watchdog_before + 2; });
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
  CHECK(reloaded);
  CHECK(refused);
  CHECK(still_fed);
  CHECK(notify.count("RELOADING=1") == 2);
  CHECK(err.find("<6>markcell: SIGHUP: reloading the panel types' recipes from " + config_file) != std::string::npos);
  CHECK(err.find("<6>markcell: reloaded the recipes of 2 panel type(s) (with a recipe: door); panels whose record is taken "
                 "from now on use them, other changes take a restart") != std::string::npos);
  const std::size_t line = [&] {  // the door's line in the file
    std::size_t n = 1;
    for (std::size_t i = 0; i < shipped.find(door); ++i) n += shipped[i] == '\n' ? 1 : 0;
    return n;
  }();
  CHECK(err.find("<3>markcell: reload: " + config_file + ":" + std::to_string(line) + ":") != std::string::npos);
  CHECK(err.find(": panel_types.door.recipe.standoff_m: expected a number in [0.01, 1], got 7") != std::string::npos);
  CHECK(err.find("<4>markcell: reload refused (1 error(s)): the running configuration stays") != std::string::npos);
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
