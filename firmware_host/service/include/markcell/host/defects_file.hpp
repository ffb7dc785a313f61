#pragma once
// The defect detector's output as the inspection station takes it (the detection itself
// stays outside markcell; format: vision/RECORDING.md "The defects file"): each defect's
// surface points in the scanner's frame CamL_SL, in metres, as CSV
//
//   defect_id,x_m,y_m,z_m
//   1,0.2779,0.1439,2.0122
//
// or as an ASCII PLY whose vertices carry x, y, z and an integer defect_id. Validated
// point by point: finite, inside the scanner's working volume (between z_min and z_max
// in front of the left camera and within its image), at least `min_points` and at most
// control::kMaxDefectPoints a defect, at most control::kMaxDefects defects. A file that
// is not valid is refused whole with FILE:LINE and what is wrong.
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>

namespace markcell::host {

class DefectsInvalid : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The scanner's working volume in CamL_SL: the left camera's view between two depths.
struct ScannerVolume {
  double fx = 0, fy = 0, cx = 0, cy = 0;  // the left camera's intrinsics (px)
  int width = 0, height = 0;              // its image (px)
  double z_min_m = 0.3, z_max_m = 5.0;
};

struct DefectCluster {
  int id = 0;
  std::vector<Eigen::Vector3d> points_SL;
};

inline constexpr std::size_t kMaxDefectsFileBytes = 8u << 20;

// Reads FILE (a regular file of at most kMaxDefectsFileBytes; .csv or .ply by its
// content: PLY starts with "ply"). Clusters in ascending id.
std::vector<DefectCluster> read_defects_file(const std::string& path, const ScannerVolume& volume, int min_points = 3);
std::vector<DefectCluster> parse_defects(std::string_view text, const std::string& path, const ScannerVolume& volume,
                                         int min_points = 3);
// The same clusters as the CSV form (header, one point a line, 9 significant digits):
// what a detector writes, and what the rig writes for the station.
std::string format_defects_csv(const std::vector<DefectCluster>& clusters);

}  // namespace markcell::host
