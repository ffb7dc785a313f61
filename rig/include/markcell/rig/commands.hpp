#pragma once
// The rig's subcommands: `markcell sim` (a scenario generated, then replayed and scored)
// and `markcell replay` (a recording replayed and scored), registered on the command line.
#include <signal.h>

#include <cstdint>
#include <functional>
#include <string>

#include "markcell/host/command.hpp"

namespace markcell::rig {

// The calibration-board scenario is markcell calibrate-base on the rig's arm: a tool's
// work the rig does not include (the layout's rule), handed in by the command line.
using BoardCalibration = std::function<int(const host::CellConfig& config, const std::string& out, std::uint64_t seed,
                                           const std::string& images, const std::string& report_dir)>;

// sim, replay: both stop at their next step on SIGTERM/SIGINT, their reports marked partial.
void add_rig_commands(CLI::App& app, host::Commands& out, const sigset_t& stop_signals, BoardCalibration calibrate_board);

}  // namespace markcell::rig
