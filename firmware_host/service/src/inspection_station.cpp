#include "markcell/host/inspection_station.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <stdexcept>

#include <opencv2/imgcodecs.hpp>

#include "markcell/common/bounded_file.hpp"
#include "markcell/host/inspection_record.hpp"
#include "markcell/vision/calibration_io.hpp"
#include "markcell/vision/stereo_rig.hpp"

namespace markcell::host {

namespace fs = std::filesystem;

cv::Mat read_scan_image(const std::string& path, int width, int height) {
  std::string bytes;
  try {
    bytes = read_bounded_file(path, kMaxScanImageBytes, "a scanner image");
  } catch (const FileRefused& e) {
    throw std::runtime_error(e.what());
  }
  const cv::Mat raw(1, static_cast<int>(bytes.size()), CV_8U, bytes.data());
  cv::Mat image = cv::imdecode(raw, cv::IMREAD_GRAYSCALE);
  if (image.empty()) throw std::runtime_error(path + ": not an image OpenCV can read (PNG, TIFF, PGM, BMP, JPEG)");
  if (image.cols != width || image.rows != height)
    throw std::runtime_error(path + ": " + std::to_string(image.cols) + "x" + std::to_string(image.rows) +
                             ", the scanner's cameras are " + std::to_string(width) + "x" + std::to_string(height) +
                             " (its calibration)");
  return image;
}

struct InspectionStation::Impl {
  explicit Impl(const vision::StereoCalibration& calibration) : scanner(calibration), rig(scanner) {}
  vision::StereoCalibration scanner;
  vision::StereoRig rig;
  // One tracker per panel type, built at start-up: measuring a panel allocates nothing
  // in the vision code (the record's text is built afterwards).
  std::vector<std::unique_ptr<vision::PanelTracker>> trackers;
};

InspectionStation::InspectionStation(const InspectionStationConfig& config) : config_(config) {
  impl_ = std::make_unique<Impl>(vision::load_stereo_calibration(config.scanner_calibration));
  for (const PanelTypeConfig& panel : config_.panel_types) {
    const vision::PanelTypeModel model = vision::load_panel_type(panel.file);
    impl_->trackers.push_back(std::make_unique<vision::PanelTracker>(impl_->rig, model, config_.vision));
  }
}

InspectionStation::~InspectionStation() = default;

const vision::StereoCalibration& InspectionStation::scanner() const { return impl_->scanner; }

ScannerVolume InspectionStation::volume() const {
  ScannerVolume v;
  const Eigen::Matrix3d& K = impl_->scanner.left.K;
  v.fx = K(0, 0);
  v.fy = K(1, 1);
  v.cx = K(0, 2);
  v.cy = K(1, 2);
  v.width = impl_->scanner.left.width;
  v.height = impl_->scanner.left.height;
  v.z_min_m = config_.vision.depth_min;
  v.z_max_m = config_.vision.depth_max;
  return v;
}

InspectionOutcome InspectionStation::inspect(const std::string& panel_id, const std::string& panel_type,
                                             const cv::Mat& left, const cv::Mat& right,
                                             const std::vector<DefectCluster>& defects) {
  InspectionOutcome out;
  out.panel_id = panel_id;
  out.panel_type = panel_type;
  if (const std::string why = panel_id_problem(panel_id); !why.empty()) {
    out.problem = std::string("panel id '") + panel_id + "': " + why;
    return out;
  }
  std::size_t index = config_.panel_types.size();
  for (std::size_t i = 0; i < config_.panel_types.size(); ++i)
    if (config_.panel_types[i].name == panel_type) index = i;
  if (index == config_.panel_types.size()) {
    out.problem = std::string("panel type '") + panel_type + "' is not configured in " + config_.file;
    return out;
  }
  const int w = impl_->scanner.left.width, h = impl_->scanner.left.height;
  for (const cv::Mat* image : {&left, &right})
    if (image->cols != w || image->rows != h || image->type() != CV_8UC1) {
      out.problem = std::string(image == &left ? "the left" : "the right") + " image is " + std::to_string(image->cols) + "x" +
                    std::to_string(image->rows) + (image->type() == CV_8UC1 ? "" : " and not 8-bit grey") +
                    ", the scanner's cameras are " + std::to_string(w) + "x" + std::to_string(h);
      return out;
    }
  out.measurement = impl_->trackers[index]->measure(left, right);
  if (!out.measurement.ok()) {
    char b[240];
    std::snprintf(b, sizeof b, "%d of %d macro-features of a %s measured, at least %d needed: %s", out.measurement.found,
                  out.measurement.mfs.ssize(), panel_type.c_str(), config_.vision.min_macro_features,
                  std::string(out.measurement.reason).c_str());
    out.problem = b;
    return out;
  }
  out.record = format_inspection_record(panel_id, panel_type, out.measurement, defects);
  return out;
}

namespace {
std::string number(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.9g", v);
  return b;
}
std::string point(const Eigen::Vector3d& p) { return std::string("[") + number(p.x()) + ", " + number(p.y()) + ", " + number(p.z()) + "]"; }
std::string pixel(const Eigen::Vector2d& p) {
  char b[64];
  std::snprintf(b, sizeof b, "[%.3f, %.3f]", p.x(), p.y());
  return b;
}
}  // namespace

std::string format_inspection_record(const std::string& panel_id, const std::string& panel_type,
                                     const vision::StereoMeasurement& measurement, const std::vector<DefectCluster>& defects) {
  std::string s;
  s.reserve(4096 + 64 * defects.size() * 64);
  s += "panel_id: ";
  s += panel_id;
  s += "\npanel_type: ";
  s += panel_type;
  s += "\nframe: CamL_SL\nunits: m\n";
  s += "# each MF in the panel type's order, measured in the scanner's pair; ~: not found there\nmacro_features:\n";
  for (const auto& m : measurement.mfs) {
    s += "  - ";
    s += m.found ? point(m.p_CamL) : std::string("~");
    s += "\n";
  }
  s += "macro_feature_quality:\n";
  for (const auto& m : measurement.mfs) {
    if (!m.found) {
      s += "  - ~\n";
      continue;
    }
    char b[200];
    std::snprintf(b, sizeof b, "  - {left_px: %s, right_px: %s, epipolar_px: %.4f, corner_response: %.2f, hole_rms_px: %.4f}\n",
                  pixel(m.left).c_str(), pixel(m.right).c_str(), m.epipolar_px, m.corner_response, m.hole_rms_px);
    s += b;
  }
  s += "defects:";
  s += defects.empty() ? " []\n" : "\n";
  for (const DefectCluster& d : defects) {
    s += "  - id: ";
    s += std::to_string(d.id);
    s += "\n    points:\n";
    for (const Eigen::Vector3d& p : d.points_SL) {
      s += "      - ";
      s += point(p);
      s += "\n";
    }
  }
  s += "...\n";  // the end of the record: a drop folder takes only a finished one
  return s;
}

void write_file_atomically(const std::string& path, const std::string& text) {
  const fs::path target(path);
  const fs::path folder = target.has_parent_path() ? target.parent_path() : fs::path(".");
  const fs::path part = folder / (std::string(".") + target.filename().string() + ".part");
  const auto fail = [&](const std::string& what) {
    const int e = errno;
    ::unlink(part.c_str());
    throw std::runtime_error(path + ": " + what + ": " + std::strerror(e));
  };
  const int fd = ::open(part.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC | O_NOFOLLOW, 0644);
  if (fd < 0) fail(std::string("cannot create ") + part.string());
  std::size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      ::close(fd);
      fail("cannot write");
    }
    done += static_cast<std::size_t>(n);
  }
  if (::fsync(fd) != 0) {
    ::close(fd);
    fail("cannot sync");
  }
  ::close(fd);
  if (::rename(part.c_str(), target.c_str()) != 0) fail(std::string("cannot rename ") + part.string() + " over it");
  if (const int dir = ::open(folder.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC); dir >= 0) {
    ::fsync(dir);
    ::close(dir);
  }
}

}  // namespace markcell::host
