#pragma once
// This build's version and git commit (firmware_host/cmake/build_info.cmake), for what the
// tools write into their files (a calibration's provenance). One source file holds them, so
// a new commit recompiles that file alone.
namespace markcell::host {

const char* build_version();  // the project's version, e.g. 0.1.0
const char* build_commit();   // the short commit, with -dirty for uncommitted changes

}  // namespace markcell::host
