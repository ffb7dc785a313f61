#include "markcell/vision/calibration_io.hpp"

#include <cmath>
#include <sstream>

#include <opencv2/core/eigen.hpp>

#include "markcell/common/bounded_file.hpp"

namespace markcell::vision {

namespace {

[[noreturn]] void fail(const std::string& path, const std::string& key, const std::string& what) {
  throw CalibrationError(path + ": key '" + key + "': " + what);
}

}  // namespace

cv::FileStorage open_yaml_storage(const std::string& path, std::size_t max_bytes, std::string_view what) {
  std::string text;
  try {
    text = read_bounded_file(path, max_bytes, what);
  } catch (const FileRefused& e) {
    throw CalibrationError(e.what());
  }
  if (text.rfind("%YAML", 0) != 0)
    throw CalibrationError(path + ": not an OpenCV FileStorage YAML file (its first line must be %YAML:1.0)");
  if (const int line = nesting_beyond(text, 16); line > 0)
    throw CalibrationError(path + ":" + std::to_string(line) + ": nested deeper than " + std::string(what) + " is (16 levels)");
  cv::FileStorage fs;
  try {
    if (!fs.open(text, cv::FileStorage::READ | cv::FileStorage::MEMORY)) throw CalibrationError(path + ": cannot parse the calibration file");
  } catch (const cv::Exception& e) {
    throw CalibrationError(path + ": not an OpenCV FileStorage file: " + e.err);
  }
  return fs;
}

namespace {

// A calibration is a few matrices: at most 1 MiB.
cv::FileStorage open_for_read(const std::string& path) { return open_yaml_storage(path, 1 << 20, "a calibration file"); }

cv::Mat read_matrix(const cv::FileStorage& fs, const std::string& path, const std::string& key, int rows, int cols) {
  const cv::FileNode node = fs[key];
  if (node.empty()) fail(path, key, "missing");
  cv::Mat m;
  try {
    node >> m;
  } catch (const cv::Exception& e) {
    fail(path, key, "expected a " + std::to_string(rows) + "x" + std::to_string(cols) + " matrix (" + e.err + ")");
  }
  if (m.empty() || m.channels() != 1) fail(path, key, "expected a single-channel matrix");
  if ((rows > 0 && m.rows != rows) || (cols > 0 && m.cols != cols)) {
    std::ostringstream os;
    os << "expected a " << (rows > 0 ? std::to_string(rows) : "N") << "x" << (cols > 0 ? std::to_string(cols) : "N")
       << " matrix, got " << m.rows << "x" << m.cols;
    fail(path, key, os.str());
  }
  m.convertTo(m, CV_64F);
  for (int r = 0; r < m.rows; ++r)
    for (int c = 0; c < m.cols; ++c)
      if (!std::isfinite(m.at<double>(r, c))) fail(path, key, "contains a non-finite value");
  return m;
}

int read_positive_int(const cv::FileStorage& fs, const std::string& path, const std::string& key) {
  const cv::FileNode node = fs[key];
  if (node.empty()) fail(path, key, "missing");
  if (!node.isInt()) fail(path, key, "expected an integer");
  const int v = static_cast<int>(node);
  if (v <= 0) fail(path, key, "expected a positive integer, got " + std::to_string(v));
  return v;
}

Eigen::Matrix3d read_camera_matrix(const cv::FileStorage& fs, const std::string& path, const std::string& key) {
  Eigen::Matrix3d K;
  cv::cv2eigen(read_matrix(fs, path, key, 3, 3), K);
  if (!K.allFinite() || K(0, 0) <= 0 || K(1, 1) <= 0 || K(2, 2) != 1.0 || K(1, 0) != 0 || K(2, 0) != 0 || K(2, 1) != 0)
    fail(path, key, "not a camera matrix [fx s cx; 0 fy cy; 0 0 1] with fx, fy > 0");
  // A lens of this world: a focal length of 1e-300 px or 1e300 px is a broken file.
  if (K(0, 0) < 1 || K(0, 0) > 1e6 || K(1, 1) < 1 || K(1, 1) > 1e6) {
    std::ostringstream os;
    os << "focal lengths " << K(0, 0) << ", " << K(1, 1) << " px: expected within [1, 1e6] px";
    fail(path, key, os.str());
  }
  return K;
}

cv::Mat read_distortion(const cv::FileStorage& fs, const std::string& path, const std::string& key) {
  cv::Mat d = read_matrix(fs, path, key, 0, 0);
  d = d.reshape(1, 1);
  const int n = d.cols;
  if (n != 4 && n != 5 && n != 8 && n != 12 && n != 14)
    fail(path, key, "expected 4, 5, 8, 12 or 14 distortion coefficients, got " + std::to_string(n));
  return d;
}

void check_rotation(const Eigen::Matrix3d& R, const std::string& path, const std::string& key) {
  const double orthogonality = (R.transpose() * R - Eigen::Matrix3d::Identity()).norm();
  if (orthogonality > 1e-6 || std::abs(R.determinant() - 1.0) > 1e-6) {
    std::ostringstream os;
    os << "not a rotation (|R'R - I| = " << orthogonality << ", det = " << R.determinant() << ")";
    fail(path, key, os.str());
  }
}

}  // namespace

StereoCalibration load_stereo_calibration(const std::string& path) {
  cv::FileStorage fs = open_for_read(path);
  StereoCalibration c;
  const int w = read_positive_int(fs, path, "image_width");
  const int h = read_positive_int(fs, path, "image_height");
  c.left.width = c.right.width = w;
  c.left.height = c.right.height = h;
  c.left.K = read_camera_matrix(fs, path, "K1");
  c.right.K = read_camera_matrix(fs, path, "K2");
  c.left.distortion = read_distortion(fs, path, "D1");
  c.right.distortion = read_distortion(fs, path, "D2");
  Eigen::Matrix3d R;
  Eigen::Vector3d T;
  cv::cv2eigen(read_matrix(fs, path, "R", 3, 3), R);
  check_rotation(R, path, "R");
  cv::Mat t = read_matrix(fs, path, "T", 0, 0);
  if (t.total() != 3) fail(path, "T", "expected 3 values, got " + std::to_string(t.total()));
  T << t.at<double>(0), t.at<double>(1), t.at<double>(2);
  if (!T.allFinite() || T.norm() <= 0) fail(path, "T", "zero (or not a finite) baseline");
  // A stereo pair on one cell: from a millimetre to a hundred metres apart.
  if (T.norm() < 1e-3 || T.norm() > 100) {
    std::ostringstream os;
    os << "baseline " << T.norm() << " m: expected within [0.001, 100] m (T is in metres)";
    fail(path, "T", os.str());
  }
  if (w > 16384 || h > 16384) fail(path, "image_width", "image " + std::to_string(w) + "x" + std::to_string(h) + " is larger than 16384 px a side");
  c.X_CamR_CamL.linear() = R;
  c.X_CamR_CamL.translation() = T;
  return c;
}

namespace {

void write_provenance(cv::FileStorage& fs, const CalibrationProvenance* p) {
  if (p == nullptr) return;
  fs << "provenance" << "{";
  fs << "calibrated_utc" << p->calibrated_utc << "tool" << p->tool;
  fs << "left_camera" << p->left_camera << "right_camera" << p->right_camera;
  fs << "rms" << p->rms << "rms_unit" << p->rms_unit;
  fs << "views" << "[";
  for (const auto& v : p->views) fs << "{" << "name" << v.name << "rms" << v.rms << "}";
  fs << "]" << "}";
}

std::string read_text(const cv::FileNode& node, const std::string& path, const std::string& key) {
  if (node.empty()) return "";
  if (!node.isString()) fail(path, key, "expected a text");
  return static_cast<std::string>(node);
}

double read_rms(const cv::FileNode& node, const std::string& path, const std::string& key) {
  if (!node.isReal() && !node.isInt()) fail(path, key, "expected a number");
  const double v = static_cast<double>(node);
  if (!std::isfinite(v) || v < 0) fail(path, key, "expected a finite RMS of at least 0");
  return v;
}

}  // namespace

std::optional<CalibrationProvenance> load_provenance(const std::string& path) {
  cv::FileStorage fs = open_for_read(path);
  const cv::FileNode node = fs["provenance"];
  if (node.empty()) return std::nullopt;
  if (!node.isMap()) fail(path, "provenance", "expected a map");
  CalibrationProvenance p;
  p.calibrated_utc = read_text(node["calibrated_utc"], path, "provenance.calibrated_utc");
  p.tool = read_text(node["tool"], path, "provenance.tool");
  p.left_camera = read_text(node["left_camera"], path, "provenance.left_camera");
  p.right_camera = read_text(node["right_camera"], path, "provenance.right_camera");
  p.rms = read_rms(node["rms"], path, "provenance.rms");
  p.rms_unit = read_text(node["rms_unit"], path, "provenance.rms_unit");
  if (p.rms_unit != "px" && p.rms_unit != "mm") fail(path, "provenance.rms_unit", "expected px or mm");
  const cv::FileNode views = node["views"];
  if (!views.empty()) {
    if (!views.isSeq()) fail(path, "provenance.views", "expected a list");
    if (views.size() > kMaxProvenanceViews)
      fail(path, "provenance.views", std::to_string(views.size()) + " views, more than " + std::to_string(kMaxProvenanceViews));
    for (std::size_t i = 0; i < views.size(); ++i) {
      const std::string at = "provenance.views[" + std::to_string(i) + "]";
      const cv::FileNode v = views[static_cast<int>(i)];
      if (!v.isMap()) fail(path, at, "expected {name, rms}");
      p.views.push_back({read_text(v["name"], path, at + ".name"), read_rms(v["rms"], path, at + ".rms")});
    }
  }
  return p;
}

void save_stereo_calibration(const std::string& path, const StereoCalibration& c, const CalibrationProvenance* provenance) {
  cv::FileStorage fs(path, cv::FileStorage::WRITE);
  if (!fs.isOpened()) throw CalibrationError(path + ": cannot open for writing");
  cv::Mat K1, K2, R, T;
  cv::eigen2cv(c.left.K, K1);
  cv::eigen2cv(c.right.K, K2);
  cv::eigen2cv(Eigen::Matrix3d(c.X_CamR_CamL.linear()), R);
  cv::eigen2cv(Eigen::Vector3d(c.X_CamR_CamL.translation()), T);
  fs << "image_width" << c.left.width << "image_height" << c.left.height;
  fs << "K1" << K1 << "D1" << (c.left.distortion.empty() ? cv::Mat::zeros(1, 5, CV_64F) : c.left.distortion);
  fs << "K2" << K2 << "D2" << (c.right.distortion.empty() ? cv::Mat::zeros(1, 5, CV_64F) : c.right.distortion);
  fs << "R" << R << "T" << T;
  write_provenance(fs, provenance);
}

Eigen::Isometry3d load_pose(const std::string& path, const std::string& key) {
  cv::FileStorage fs = open_for_read(path);
  Eigen::Matrix4d m;
  cv::cv2eigen(read_matrix(fs, path, key, 4, 4), m);
  if (m.row(3) != Eigen::RowVector4d(0, 0, 0, 1)) fail(path, key, "last row is not [0 0 0 1]");
  check_rotation(m.topLeftCorner<3, 3>(), path, key);
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.matrix() = m;
  return X;
}

void save_pose(const std::string& path, const std::string& key, const Eigen::Isometry3d& pose,
               const CalibrationProvenance* provenance) {
  cv::FileStorage fs(path, cv::FileStorage::WRITE);
  if (!fs.isOpened()) throw CalibrationError(path + ": cannot open for writing");
  cv::Mat m;
  cv::eigen2cv(Eigen::Matrix4d(pose.matrix()), m);
  fs << key << m;
  write_provenance(fs, provenance);
}

}  // namespace markcell::vision
