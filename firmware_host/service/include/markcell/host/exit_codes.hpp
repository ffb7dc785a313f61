#pragma once
// markcell's exit codes, the same for every subcommand and for markcell-select-mfs
// (docs/commands.md): scripts and systemd's RestartPreventExitStatus= rely on them.
namespace markcell::host {

inline constexpr int kExitOk = 0;
inline constexpr int kExitRuntime = 1;  // a device, a fault at start-up, a fault of the cell itself
inline constexpr int kExitConfig = 2;   // an invalid configuration or arguments

}  // namespace markcell::host
