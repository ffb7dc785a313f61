#pragma once
// What select-mfs prints about the panel type it wrote: `markcell select-mfs --mf` and the
// window's own program (markcell-select-mfs) print the same lines.
#include <string>
#include <vector>

#include <Eigen/Core>

#include "markcell/vision/panel_tracker.hpp"

namespace markcell::host {

// Each MF's kind and position; with `given` (the positions typed on the command line, in
// the same order) how far each one moved from its own.
void print_panel_type(const vision::PanelTypeModel& model, const std::vector<Eigen::Vector2d>& given, const std::string& out);

}  // namespace markcell::host
