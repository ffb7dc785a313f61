#pragma once
// The inspection station's side of the rig: for every panel, the record that station
// would send. Its scanner is a higher-resolution stereo pair (1392x1040) at its own pose
// to the panel; its frame is its left camera, CamL_SL.
//  - the macro-features: projected into both scanner views, perturbed by the scanner's
//    pixel noise, triangulated back (DLT) in CamL_SL, as the station measures them;
//  - each defect: a cluster of surface points around its centre (a shallow ding), in
//    CamL_SL, with the scanner's depth noise.
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "markcell/vision/calibration_io.hpp"
#include "markcell/rig/render.hpp"

namespace markcell::rig {

struct InspectionDefect {
  int id = 0;
  std::vector<Eigen::Vector3d> points_SL;  // surface points of the defect, CamL_SL, m
};

struct InspectionRecord {
  std::string panel_id;
  std::string panel_type;
  std::vector<Eigen::Vector3d> macro_features_SL;  // in the panel type's order, CamL_SL, m
  std::vector<InspectionDefect> defects;
};

struct InspectionNoise {
  double pixel_sigma = 0.25;        // scanner's corner localisation, px
  double depth_sigma = 0.0003;      // scanner's surface points along the normal, m
  double ding_depth = 0.0004;       // a ding's depth at its centre, m
  int points_per_defect = 60;
};

struct DefectSpec {
  int id = 0;
  double x = 0, y = 0;     // centre on the panel surface, panel frame, m
  double radius = 0.012;   // the ding's radius on the surface, m
};

InspectionRecord simulate_inspection(const std::string& panel_id, const rig::Panel& panel,
                                     const std::vector<DefectSpec>& defects, const vision::StereoCalibration& scanner,
                                     const Eigen::Isometry3d& X_SL_Panel, const InspectionNoise& noise, std::uint64_t seed);

}  // namespace markcell::rig
