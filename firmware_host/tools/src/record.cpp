#include "markcell/tools/record.hpp"

#include <filesystem>
#include <ostream>
#include <stdexcept>

#include <opencv2/core.hpp>

#include "markcell/drivers/camera.hpp"
#include "markcell/host/cell.hpp"
#include "markcell/vision/recording.hpp"

namespace markcell::host {

RecordSummary record_stereo(const CellConfig& config, const RecordOptions& o, std::ostream* progress) {
  drivers::CameraUnitSettings left_own = config.cameras.left, right_own = config.cameras.right;
  if (!o.left_id.empty()) left_own.id = o.left_id;
  if (!o.right_id.empty()) right_own.id = o.right_id;
  const std::string& left_id = left_own.id;
  const std::string& right_id = right_own.id;
  if (left_id.empty() || right_id.empty())
    throw std::runtime_error(config.file + ": devices.cameras.left.id and right.id: record needs both cameras' ids (or --left/--right)");
  namespace fs = std::filesystem;
  vision::RecordingManifest m;
  m.station = "marking";
  m.panel_type = o.panel_type;
  m.frame_rate_hz = config.cameras.fps;
  m.image_width = config.cameras.width;
  m.image_height = config.cameras.height;
  if (!config.calibration.stereo.empty()) m.calibration = "calibration.yaml";
  vision::RecordingWriter writer(o.out, m);
  if (!config.calibration.stereo.empty())
    fs::copy_file(config.calibration.stereo, fs::path(o.out) / "calibration.yaml", fs::copy_options::overwrite_existing);

  drivers::AravisCamera left(camera_settings(config.cameras, left_own)), right(camera_settings(config.cameras, right_own));
  left.activate();
  right.activate();
  const Nanos period = static_cast<Nanos>(1e9 / config.cameras.fps);
  drivers::StereoCamera pair(left, right, period / 2, config.cameras.lost_after);
  const bool software = config.cameras.trigger == CameraTrigger::kSoftware;
  RecordSummary summary;
  Nanos first = -1;
  // Bounded: every pair waits at most half of lost_after_ms, and as many time-outs as pairs asked for end it.
  while (summary.pairs < o.frames && summary.timeouts < o.frames) {
    if (software) pair.trigger();
    drivers::StereoFrame f;
    const drivers::PairStatus s = pair.next(f, config.cameras.lost_after / 2);  // a dropped trigger is retried before the camera counts as lost
    if (s == drivers::PairStatus::kLeftLost || s == drivers::PairStatus::kRightLost) {
      writer.close();
      throw std::runtime_error("camera '" + (s == drivers::PairStatus::kLeftLost ? left_id : right_id) + "' lost after " +
                               std::to_string(summary.pairs) + " pairs (the recording so far is kept)");
    }
    if (s != drivers::PairStatus::kPair) {
      ++summary.timeouts;
      continue;
    }
    if (first < 0) first = f.time;
    const cv::Mat l(f.left.height, f.left.width, CV_8UC1, const_cast<std::uint8_t*>(f.left.pixels),
                    static_cast<std::size_t>(f.left.stride));
    const cv::Mat r(f.right.height, f.right.width, CV_8UC1, const_cast<std::uint8_t*>(f.right.pixels),
                    static_cast<std::size_t>(f.right.stride));
    writer.add(static_cast<std::uint64_t>(summary.pairs), f.time - first, l, r);
    ++summary.pairs;
    if (progress && summary.pairs % 10 == 0) *progress << "\rmarkcell record: " << summary.pairs << "/" << o.frames << " pairs" << std::flush;
  }
  if (progress) *progress << "\n";
  summary.unpaired = pair.counters().unpaired_left + pair.counters().unpaired_right;
  writer.close();
  left.deactivate();
  right.deactivate();
  return summary;
}

}  // namespace markcell::host
