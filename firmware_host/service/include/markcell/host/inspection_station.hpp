#pragma once
// The inspection station's half of the inter-calibration (the paper's section III.A;
// docs/inspection.md): on every panel its macro-features are found again in the
// structured-light scanner's stereo pair with the marking station's own tracker code
// (vision::PanelTracker::measure: the template search, LK to the right view, the corner
// or hole refinement, the epipolar check, DLT triangulation), moved into the scanner's
// frame CamL_SL, and written with the defect detector's point clusters as the record the
// marking station takes (vision/RECORDING.md, "inspection.yaml").
//
// The station's configuration is a file of its own (`station: inspection`), validated
// with the same FILE:LINE:COL errors as a cell's (markcell check-config reads both).
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "markcell/host/config.hpp"
#include "markcell/host/defects_file.hpp"
#include "markcell/vision/panel_tracker.hpp"

namespace markcell::host {

struct InspectionStationConfig {
  std::string file;  // the YAML file it came from
  std::string name;
  std::string scanner_calibration;  // the scanner's stereo calibration (calibrate-stereo); absolute
  std::string record_folder;        // records are written here (the marking station's drop folder); absolute, may be empty
  int min_points_per_defect = 3;
  std::vector<PanelTypeConfig> panel_types;  // name and file (select-mfs on a scanner image); recipes do not apply here
  vision::TrackerParams vision;  // the `vision:` section: the same keys as a cell's, for the scanner's geometry
};

// Whether the YAML text declares `station: inspection` at its top level (a cheap look,
// before either loader runs).
bool is_inspection_station_config(const std::string& text);
// Validates and loads; throws ConfigInvalid with every error (FILE:LINE:COL).
InspectionStationConfig load_inspection_station_config(const std::string& path);
InspectionStationConfig load_inspection_station_config_text(const std::string& text, const std::string& path);

// The scanner's images of one panel: DIR/left.png and DIR/right.png (any format OpenCV
// reads, converted to 8-bit grey), each a regular file of at most kMaxScanImageBytes and
// of the scanner calibration's size. Throws std::runtime_error naming the file and what is
// wrong.
inline constexpr std::size_t kMaxScanImageBytes = 64u << 20;
cv::Mat read_scan_image(const std::string& path, int width, int height);

// One panel's outcome: the record's text, or why there is none (never a partial record).
struct InspectionOutcome {
  std::string panel_id, panel_type;
  vision::StereoMeasurement measurement;
  std::string problem;  // empty: `record` is the panel's record
  std::string record;
  bool ok() const { return problem.empty(); }
};

class InspectionStation {
 public:
  // Loads the scanner's calibration and every panel type; throws naming the file.
  explicit InspectionStation(const InspectionStationConfig& config);
  ~InspectionStation();
  const InspectionStationConfig& config() const { return config_; }
  const vision::StereoCalibration& scanner() const;
  // The scanner's working volume the defect points must lie in (its left camera's view,
  // between the vision section's depths).
  ScannerVolume volume() const;
  // Measures the MFs of `panel_type` on the pair and builds the record with `defects`.
  // Fewer MFs than vision.min_macro_features: no record, the reason in `problem`.
  InspectionOutcome inspect(const std::string& panel_id, const std::string& panel_type, const cv::Mat& left,
                            const cv::Mat& right, const std::vector<DefectCluster>& defects);

 private:
  struct Impl;
  InspectionStationConfig config_;
  std::unique_ptr<Impl> impl_;
};

// The record's text (vision/RECORDING.md, "inspection.yaml"): an MF not measured is `~`,
// each measured one's quality under macro_feature_quality; ends with the end marker.
std::string format_inspection_record(const std::string& panel_id, const std::string& panel_type,
                                     const vision::StereoMeasurement& measurement, const std::vector<DefectCluster>& defects);

// Writes `text` to `path` as a whole: a temporary file beside it, synced, renamed over it,
// the folder synced. Throws naming the path.
void write_file_atomically(const std::string& path, const std::string& text);

}  // namespace markcell::host
