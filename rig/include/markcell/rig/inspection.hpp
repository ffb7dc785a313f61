#pragma once
// The inspection station of the rig: the station itself (host/inspection_station.hpp,
// `markcell inspect`) on the scanner's rendered views. For every panel the rig
//  - renders the scanner's 1392x1040 stereo pair at the panel's pose there (X_SL_Panel,
//    its frame the scanner's left camera CamL_SL) through the mesh renderer;
//  - picks the panel type's MFs once on a reference view of the scanner (the panel at a
//    nominal pose, as an installer does with select-mfs), so that every panel is searched
//    for from centimetres and degrees away;
//  - samples each defect as a cluster of surface points around its centre (a shallow
//    ding) with the scanner's depth noise, in CamL_SL: the defect detector's output;
//  - writes all of it as the station's input files under FOLDER/inspection/ (a user can
//    run `markcell inspect` on them by hand), runs the station, and writes its record as
//    FOLDER/inspection.yaml, with each MF's error against the truth in
//    FOLDER/inspection/mfs.csv.
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "markcell/host/defects_file.hpp"
#include "markcell/host/inspection_station.hpp"
#include "markcell/rig/render.hpp"
#include "markcell/vision/calibration_io.hpp"

namespace markcell::rig {

struct InspectionNoise {
  double depth_sigma = 0.0003;      // scanner's surface points along the normal, m
  double ding_depth = 0.0004;       // a ding's depth at its centre, m
  int points_per_defect = 60;
};

struct DefectSpec {
  int id = 0;
  double x = 0, y = 0;     // centre on the panel surface, panel frame, m
  double radius = 0.012;   // the ding's radius on the surface, m
};

// The defect detector's clusters in CamL_SL: uniform over each ding's disc on the
// surface, pressed in by the ding, with the depth noise; seeded.
std::vector<host::DefectCluster> sample_defect_points(const rig::Panel& panel, const std::vector<DefectSpec>& defects,
                                                      const Eigen::Isometry3d& X_SL_Panel, const InspectionNoise& noise,
                                                      std::uint64_t seed);

// The panel at the scanner's reference pose: facing it 2.05 m away, a little right of its
// left camera (where an installer puts a panel to pick the MFs).
Eigen::Isometry3d scanner_reference_pose();

struct InspectionRun {
  host::InspectionOutcome outcome;  // the station's: its record, or why there is none
  std::vector<double> error_mm;     // per MF: |measured - true| in CamL_SL; -1 where not found
  std::string record_path;          // FOLDER/inspection.yaml when the station made a record
};

InspectionRun run_inspection_station(const std::string& folder, const std::string& panel_id, const rig::Panel& panel,
                                     const std::vector<DefectSpec>& defects, const vision::StereoCalibration& scanner,
                                     const Eigen::Isometry3d& X_SL_Panel, const InspectionNoise& noise,
                                     const RenderSettings& render, std::uint64_t seed);

}  // namespace markcell::rig
