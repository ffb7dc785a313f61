#pragma once
// A subcommand of `markcell`, registered by the module that owns it: its options on its
// CLI::App and what it does once parsed. The service registers check-config,
// config-schema and run (commands.cpp here), the tools theirs (markcell/tools/commands.hpp),
// the rig sim and replay (markcell/rig/commands.hpp); firmware_host/main.cpp only gathers
// them, parses, and runs the one given.
#include <signal.h>

#include <CLI/CLI.hpp>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "markcell/host/config.hpp"
#include "markcell/host/service_loop.hpp"  // the exit codes

namespace markcell::host {

struct Command {
  CLI::App* app = nullptr;
  std::function<int()> run;         // once parsed: the exit code (service_loop.hpp's kExit*)
  bool takes_stop_signals = false;  // stops in order on SIGTERM/SIGINT itself; others end at once
};
using Commands = std::vector<Command>;

// check-config, config-schema, run. `stop_signals`: blocked in every thread since main()'s
// first line; run takes them with sigtimedwait.
void add_service_commands(CLI::App& app, Commands& out, const sigset_t& stop_signals);
// inspect: the inspection station's side (inspect_command.cpp).
void add_inspect_command(CLI::App& app, Commands& out);

// The configuration, or every error printed to stderr with the count (nullopt: exit 2).
std::optional<CellConfig> load_or_report(const std::string& file);
// `run` on the configuration at `file`; exit 2 (every error printed) when it is invalid.
template <class Run>
int with_config(const std::string& file, Run&& run) {
  const std::optional<CellConfig> config = load_or_report(file);
  return config ? run(*config) : kExitConfig;
}

}  // namespace markcell::host
