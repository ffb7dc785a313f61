// markcell: the controller of a robotic defect-marking cell. One executable; the
// subcommands are the cell (`run`), its tools and its benchmarks, each registered by the
// module that owns it (markcell/host/command.hpp): this file is the command line only.
//
// Exit codes: 0 success; 1 runtime failure (a device, a fault at start-up); 2 invalid
// configuration or arguments (every problem is printed, each naming what to fix).
#include <pthread.h>
#include <signal.h>

#include <CLI/CLI.hpp>
#include <iostream>

#include "markcell/build_info.hpp"  // generated: firmware_host/cmake/build_info.cmake
#include "markcell/host/command.hpp"
#include "markcell/host/service_loop.hpp"
#include "markcell/rig/commands.hpp"
#include "markcell/tools/commands.hpp"
#include "subcommand_suggestion.hpp"

namespace {

// SIGTERM and SIGINT, taken synchronously by the commands that stop in order (run, sim,
// replay). They are blocked first thing in main(): before any lane exists (every thread
// inherits the mask), and before start-up work, so a stop requested while starting is
// held and honoured, never lost (a background job of a shell even starts with SIGINT
// ignored).
sigset_t stop_signals() {
  sigset_t s;
  sigemptyset(&s);
  sigaddset(&s, SIGTERM);
  sigaddset(&s, SIGINT);
  return s;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace markcell;
  const sigset_t signals = stop_signals();
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  CLI::App app{"markcell: controller of a robotic cell that tracks moving body panels and spray-marks their surface defects"};
  app.require_subcommand(1);
  app.set_help_all_flag("--help-all", "Show help for every subcommand");
  // The first line is what help2man puts in the man page's header; the second is what a
  // bug report needs.
  app.set_version_flag("--version", "markcell " MARKCELL_VERSION "\ncommit " MARKCELL_GIT_COMMIT ", build type " MARKCELL_BUILD_TYPE
                       ", " MARKCELL_COMPILER, "Print the version, the git commit and the build type, and exit");

  host::Commands commands;
  host::add_service_commands(app, commands, signals);
  host::add_tool_commands(app, commands);
  rig::add_rig_commands(app, commands, signals, &host::calibrate_base_command);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() != 0) {  // not --help or --version
      if (const auto unknown = host::unknown_subcommand(app, argc, argv)) {
        std::cerr << "markcell: " << *unknown << "\n";
        return host::kExitConfig;
      }
    }
    const int code = app.exit(e);
    return code == 0 ? 0 : host::kExitConfig;
  }
  for (const host::Command& c : commands) {
    if (!c.app->parsed()) continue;
    // Only run, sim and replay take SIGTERM and SIGINT themselves (to stop in order,
    // outputs safe, reports marked); every other command is ended by them at once, as by
    // default (a recording cut short has no recording.yaml, so is no recording).
    if (!c.takes_stop_signals) pthread_sigmask(SIG_UNBLOCK, &signals, nullptr);
    try {
      return c.run();
    } catch (const std::exception& e) {
      std::cerr << "markcell: " << e.what() << "\n";
      return host::kExitRuntime;
    }
  }
  return 0;
}
