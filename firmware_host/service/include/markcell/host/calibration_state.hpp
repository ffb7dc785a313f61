#pragma once
// The calibrations as the cell's state (docs/calibrations.md): written atomically with a
// dated, bounded history (common/file_history.hpp), each with its provenance
// (vision::CalibrationProvenance), listed by `markcell calibrations` and named by
// `markcell check-config`.
#include <functional>
#include <string>

#include "markcell/vision/calibration_io.hpp"

namespace markcell::host {

// The provenance a markcell tool writes now: this moment in UTC, "markcell VERSION
// (commit C, TOOL)", the cameras and the fit's figures.
vision::CalibrationProvenance make_provenance(const std::string& tool, const std::string& left_camera,
                                              const std::string& right_camera, double rms, const std::string& rms_unit,
                                              std::vector<vision::CalibrationProvenance::View> views);

// Writes a calibration through `save(temporary)`, replacing `out` atomically and keeping
// the previous version in its history; prints where each went on `log`. Throws
// std::runtime_error (file, step, reason) with `out` untouched.
void write_calibration(const std::string& out, const std::function<void(const std::string&)>& save, std::ostream& log);

// One line about a calibration file: "calibrated 2026-12-07T03:40:12Z by markcell 0.1.0
// (commit ..., calibrate-stereo), RMS 0.213 px over 14 views, cameras L and R", or that it
// has no provenance (with its modification time), or why it cannot be read. Text from the
// file is escaped.
std::string calibration_summary(const std::string& path);

// `markcell calibrations`: for a calibration in use (`role`: stereo, base), its path and
// summary, each view's figure, and its history, newest first, each with its summary.
std::string calibration_listing(const std::string& role, const std::string& path);

}  // namespace markcell::host
