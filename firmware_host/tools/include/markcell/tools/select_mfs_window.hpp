#pragma once
// `markcell select-mfs` with a window: the installation engineer picks a panel type's
// macro-features on a reference image of the left camera.
//
//   left click        add an MF: a hole's centre when the click is inside a round or oval
//                     hole, else snapped to the strongest Shi-Tomasi corner nearby
//   drag an MF        move it (snapped again where it is let go)
//   d, x, Delete      delete the selected MF (the one last clicked or added)
//   s                 save (at least 3 MFs) and close
//   q, Esc            close without saving
//
// Each action is also printed on `log`, so a script (or a test under Xvfb) can follow.
#include <optional>
#include <ostream>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "markcell/vision/panel_tracker.hpp"

namespace markcell::host {

// The MFs (position and kind) in the order they were added, or nullopt when closed
// without saving. Throws std::runtime_error when no window can be opened (no display).
std::optional<std::vector<vision::MfPick>> select_mfs_window(const cv::Mat& reference_left, const std::string& title,
                                                              int snap_radius, std::ostream& log);

}  // namespace markcell::host
