#pragma once
// Where a subcommand's default files are. The package's binary (/usr/bin/markcell, the
// .deb's path) finds them where the package put them, whatever the working directory:
// `cd / && markcell capacity` reads /etc/markcell/cell.yaml. Any other binary (a build
// folder's) is run from the source tree and finds them under config/ relative to the
// working directory, as the README's commands do.
#include <string>

namespace markcell::host {

// True when this process is the installed package's binary (/proc/self/exe).
bool running_installed();

// The configuration folder: /etc/markcell installed, config otherwise.
std::string default_config_dir();
// The calibrations (state, not configuration: docs/calibrations.md):
// /var/lib/markcell/calibration installed, config/calibration otherwise.
std::string default_calibration_dir();
// The cell configuration: /etc/markcell/cell.yaml installed, config/cell.example.yaml otherwise.
std::string default_config_file();
// Said in each --config option's help (the man page is made by a build folder's binary).
inline constexpr const char* kDefaultConfigHelp =
    " (default: /etc/markcell/cell.yaml for the installed package, config/cell.example.yaml in the source tree)";

}  // namespace markcell::host
