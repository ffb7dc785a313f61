#pragma once
// Calibration of a stereo pair from chessboard image pairs (what
// `markcell calibrate-stereo` runs): corners found and refined in both views, each
// camera's intrinsics first, then the pair with OpenCV's stereoCalibrate. The same code
// calibrates the marking station's 640x480 pair and the inspection station's 1392x1040.
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "markcell/vision/calibration_io.hpp"

namespace markcell::vision {

struct BoardSpec {
  int cols = 9;       // inner corners per row
  int rows = 6;       // inner corners per column
  double square = 0.04;  // m
};

struct StereoView {
  std::string name;
  cv::Mat left, right;  // 8-bit grey
};

struct StereoCalibrationResult {
  StereoCalibration calibration;
  double rms = 0;                        // stereoCalibrate's RMS reprojection error, px
  std::vector<std::string> used;         // view names used
  std::vector<double> view_errors;       // RMS reprojection error of each used view (both cameras), px
  std::vector<std::string> skipped;      // "NAME: why" for views left out
  double epipolar_error = 0;             // mean distance of corners to their epipolar lines, px
};

// Throws CalibrationError when fewer than `min_views` views are usable (naming them).
StereoCalibrationResult calibrate_stereo(const std::vector<StereoView>& views, const BoardSpec& board, int min_views = 6);

// Reads the image pairs of a folder: every file whose name contains "left" pairs with
// the file of the same name with "right" instead. Unpaired files are listed in `unpaired`.
std::vector<StereoView> read_stereo_views(const std::string& folder, std::vector<std::string>& unpaired);

}  // namespace markcell::vision
