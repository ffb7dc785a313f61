#pragma once
// The tools' subcommands, registered on the command line: calibrate-stereo,
// calibrate-base, record, capacity, select-mfs, bench loop, bench vision.
#include <cstdint>
#include <string>

#include "markcell/host/command.hpp"

namespace markcell::host {

void add_tool_commands(CLI::App& app, Commands& out);

// calibrate-base: with the simulated arm on the rig's calibration-board scenario (seed),
// otherwise the live arm and cameras; writes `out` only when the fit is within the
// limits, the pairs taken into `images` and a report.json into `report_dir` when given.
int calibrate_base_command(const CellConfig& config, const std::string& out, std::uint64_t seed, const std::string& images,
                           const std::string& report_dir);

}  // namespace markcell::host
