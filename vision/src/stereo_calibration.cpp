#include "markcell/vision/stereo_calibration.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>

#include <Eigen/Geometry>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace markcell::vision {

namespace fs = std::filesystem;

std::vector<StereoView> read_stereo_views(const std::string& folder, std::vector<std::string>& unpaired) {
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(folder))
    if (e.is_regular_file()) files.push_back(e.path());
  std::sort(files.begin(), files.end());
  std::vector<StereoView> views;
  for (const auto& f : files) {
    const std::string name = f.filename().string();
    const auto at = name.find("left");
    if (at == std::string::npos) {
      if (name.find("right") == std::string::npos) continue;
      std::string partner = name;
      partner.replace(name.find("right"), 5, "left");
      if (!fs::exists(f.parent_path() / partner)) unpaired.push_back(name);
      continue;
    }
    std::string partner = name;
    partner.replace(at, 4, "right");
    if (!fs::exists(f.parent_path() / partner)) {
      unpaired.push_back(name);
      continue;
    }
    StereoView v;
    v.name = name.substr(0, at) + name.substr(at + 4);
    v.left = cv::imread(f.string(), cv::IMREAD_GRAYSCALE);
    v.right = cv::imread((f.parent_path() / partner).string(), cv::IMREAD_GRAYSCALE);
    views.push_back(v);
  }
  return views;
}

StereoCalibrationResult calibrate_stereo(const std::vector<StereoView>& views, const BoardSpec& board, int min_views) {
  StereoCalibrationResult result;
  const cv::Size pattern(board.cols, board.rows);
  std::vector<cv::Point3f> object;
  for (int r = 0; r < board.rows; ++r)
    for (int c = 0; c < board.cols; ++c)
      object.emplace_back(static_cast<float>(c * board.square), static_cast<float>(r * board.square), 0.0f);
  std::vector<std::vector<cv::Point3f>> objects;
  std::vector<std::vector<cv::Point2f>> left_points, right_points;
  cv::Size size;
  for (const auto& v : views) {
    if (v.left.empty() || v.right.empty()) {
      result.skipped.push_back(v.name + ": an image is missing or unreadable");
      continue;
    }
    if (v.left.size() != v.right.size() || (!size.empty() && v.left.size() != size)) {
      result.skipped.push_back(v.name + ": image sizes differ from the other views");
      continue;
    }
    std::vector<cv::Point2f> l, r;
    const int flags = cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE;
    const bool found_l = cv::findChessboardCorners(v.left, pattern, l, flags);
    const bool found_r = found_l && cv::findChessboardCorners(v.right, pattern, r, flags);
    if (!found_l || !found_r) {
      result.skipped.push_back(v.name + ": board not found in the " + (found_l ? "right" : "left") + " image");
      continue;
    }
    const cv::TermCriteria criteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 50, 1e-4);
    cv::cornerSubPix(v.left, l, cv::Size(5, 5), cv::Size(-1, -1), criteria);
    cv::cornerSubPix(v.right, r, cv::Size(5, 5), cv::Size(-1, -1), criteria);
    size = v.left.size();
    objects.push_back(object);
    left_points.push_back(l);
    right_points.push_back(r);
    result.used.push_back(v.name);
  }
  if (static_cast<int>(result.used.size()) < min_views) {
    std::string why = "only " + std::to_string(result.used.size()) + " usable view(s), at least " +
                      std::to_string(min_views) + " needed";
    for (const auto& s : result.skipped) why += "; " + s;
    throw CalibrationError(why);
  }
  // Each camera alone first, then the pair with the intrinsics as the starting point.
  cv::Mat K1, D1, K2, D2, R, T, E, F;
  std::vector<cv::Mat> rv1, tv1, rv2, tv2;
  cv::calibrateCamera(objects, left_points, size, K1, D1, rv1, tv1);
  cv::calibrateCamera(objects, right_points, size, K2, D2, rv2, tv2);
  cv::Mat per_view;
  result.rms = cv::stereoCalibrate(objects, left_points, right_points, K1, D1, K2, D2, size, R, T, E, F, per_view,
                                   cv::CALIB_USE_INTRINSIC_GUESS,
                                   cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-7));
  for (int i = 0; i < per_view.rows; ++i)
    result.view_errors.push_back(std::sqrt((per_view.at<double>(i, 0) * per_view.at<double>(i, 0) +
                                            per_view.at<double>(i, 1) * per_view.at<double>(i, 1)) / 2.0));
  // Epipolar check on the undistorted corners.
  double sum = 0;
  std::size_t n = 0;
  for (std::size_t v = 0; v < left_points.size(); ++v) {
    std::vector<cv::Point2f> ul, ur;
    cv::undistortPoints(left_points[v], ul, K1, D1, cv::noArray(), K1);
    cv::undistortPoints(right_points[v], ur, K2, D2, cv::noArray(), K2);
    std::vector<cv::Vec3f> lines;
    cv::computeCorrespondEpilines(ul, 1, F, lines);
    for (std::size_t i = 0; i < ur.size(); ++i) {
      sum += std::abs(lines[i][0] * ur[i].x + lines[i][1] * ur[i].y + lines[i][2]);
      ++n;
    }
  }
  result.epipolar_error = n > 0 ? sum / static_cast<double>(n) : 0.0;
  StereoCalibration& c = result.calibration;
  cv::cv2eigen(K1, c.left.K);
  cv::cv2eigen(K2, c.right.K);
  c.left.distortion = D1.clone().reshape(1, 1);
  c.right.distortion = D2.clone().reshape(1, 1);
  c.left.width = c.right.width = size.width;
  c.left.height = c.right.height = size.height;
  Eigen::Matrix3d Re;
  Eigen::Vector3d Te;
  cv::cv2eigen(R, Re);
  cv::cv2eigen(T.reshape(1, 3), Te);
  c.X_CamR_CamL.linear() = Re;
  c.X_CamR_CamL.translation() = Te;
  return result;
}

}  // namespace markcell::vision
