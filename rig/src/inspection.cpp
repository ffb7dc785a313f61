#include "markcell/rig/inspection.hpp"

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include <opencv2/imgcodecs.hpp>

#include "markcell/common/splitmix.hpp"
#include "markcell/vision/panel_tracker.hpp"

namespace markcell::rig {

namespace fs = std::filesystem;

std::vector<host::DefectCluster> sample_defect_points(const rig::Panel& panel, const std::vector<DefectSpec>& defects,
                                                      const Eigen::Isometry3d& X_SL_Panel, const InspectionNoise& noise,
                                                      std::uint64_t seed) {
  // The project's own generator, each draw in a statement of its own: the same seed gives
  // the same points on every compiler and architecture (docs/determinism.md).
  SplitMix rng{seed};
  std::vector<host::DefectCluster> out;
  for (const auto& d : defects) {
    host::DefectCluster c;
    c.id = d.id;
    for (int i = 0; i < noise.points_per_defect; ++i) {
      // Uniform over the disc around the centre, on the surface, pressed in by the ding.
      const double rho = d.radius * std::sqrt(rng.unit());
      const double phi = 2 * M_PI * rng.unit();
      const double x = d.x + rho * std::cos(phi), y = d.y + rho * std::sin(phi);
      const double dent = noise.ding_depth * std::exp(-0.5 * (rho * rho) / (0.4 * d.radius * 0.4 * d.radius));
      const double pressed = dent + rng.normal(0.0, noise.depth_sigma);
      const MeshHit front = panel.surface->from_front(x, y);
      if (!front.hit()) continue;  // over a hole or past an edge: the scanner sees no surface there
      c.points_SL.push_back(X_SL_Panel * (front.p - front.normal * pressed));
    }
    out.push_back(std::move(c));
  }
  return out;
}

Eigen::Isometry3d scanner_reference_pose() {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() << 1, 0, 0, 0, -1, 0, 0, 0, -1;  // the panel's front face towards the scanner, its y up
  X.translation() = Eigen::Vector3d(0.12, 0.0, 2.05);
  return X;
}


InspectionRun run_inspection_station(const std::string& folder, const std::string& panel_id, const rig::Panel& panel,
                                     const std::vector<DefectSpec>& defects, const vision::StereoCalibration& scanner,
                                     const Eigen::Isometry3d& X_SL_Panel, const InspectionNoise& noise,
                                     const RenderSettings& render, std::uint64_t seed) {
  const fs::path dir = fs::path(folder) / "inspection";
  fs::create_directories(dir);
  const StereoRenderer renderer(scanner, render);
  // The renderer's frame is the scanner's right camera; the station's its left one.
  const Eigen::Isometry3d X_CamR_SL = scanner.X_CamR_CamL;

  // Once per panel type, as an installer would: the MFs picked on a reference view.
  cv::Mat reference_left, reference_right;
  renderer.render(panel, X_CamR_SL * scanner_reference_pose(), 1.0, seed * 7919ULL + 29, {}, reference_left, reference_right);
  // An MF that cannot be picked on the scanner's view (a hole too large for the template
  // at its scale) is one this station does not see: kept in the order, its reason noted.
  std::vector<vision::MfPick> picks;
  std::ofstream notes(dir / "panel_type_notes.txt");
  for (std::size_t i = 0; i < panel.macro_features.size(); ++i) {
    const Eigen::Vector2d px = renderer.project(0, X_CamR_SL * scanner_reference_pose() * panel.macro_features[i]);
    const vision::SnapResult snap = vision::snap_macro_feature(reference_left, px, 2, vision::MfKindRequest::kAuto);
    if (!snap.ok()) notes << "MF " << i + 1 << " unseen at the scanner: " << snap.problem << "\n";
    picks.push_back({px, snap.ok() ? vision::MfKindRequest::kAuto : vision::MfKindRequest::kUnseen});
  }
  // The panel may stand some centimetres and degrees off the reference: search wide.
  const vision::PanelTypeModel model = vision::make_panel_type(panel.name, reference_left, picks, 2, 200, 160);
  vision::save_panel_type((dir / "panel_type.yaml").string(), model);
  cv::imwrite((dir / "reference_left.png").string(), reference_left);
  vision::save_stereo_calibration((dir / "scanner.yaml").string(), scanner);
  {
    std::ofstream station(dir / "station.yaml");
    station << "# The rig's inspection station: markcell inspect --config station.yaml --images . --defects defects.csv\n"
            << "station: inspection\ninspection:\n  name: rig-scanner\n  scanner_calibration: scanner.yaml\n"
            << "panel_types:\n  " << panel.name << ":\n    macro_features: " << model.count()
            << "\n    file: panel_type.yaml\nvision:\n  depth_min_m: 1.2\n  depth_max_m: 3.5\n  reinit_local_px: 48\n";
  }

  // This panel: its pair, and the detector's points.
  cv::Mat left, right;
  renderer.render(panel, X_CamR_SL * X_SL_Panel, 1.0, seed * 1'000'033ULL + 3, {}, left, right);
  cv::imwrite((dir / "left.png").string(), left);
  cv::imwrite((dir / "right.png").string(), right);
  std::ofstream(dir / "defects.csv") << host::format_defects_csv(sample_defect_points(panel, defects, X_SL_Panel, noise, seed));

  // The station, from its files, as `markcell inspect` runs it.
  const host::InspectionStationConfig config = host::load_inspection_station_config((dir / "station.yaml").string());
  host::InspectionStation station(config);
  const int w = scanner.left.width, h = scanner.left.height;
  const cv::Mat l = host::read_scan_image((dir / "left.png").string(), w, h);
  const cv::Mat r = host::read_scan_image((dir / "right.png").string(), w, h);
  const auto clusters = host::read_defects_file((dir / "defects.csv").string(), station.volume(), config.min_points_per_defect);
  InspectionRun run;
  run.outcome = station.inspect(panel_id, panel.name, l, r, clusters);
  std::ofstream mfs(dir / "mfs.csv");
  mfs << "mf,found,left_u,left_v,right_u,right_v,epipolar_px,x_m,y_m,z_m,true_x_m,true_y_m,true_z_m,error_mm\n";
  for (std::size_t i = 0; i < panel.macro_features.size(); ++i) {
    const Eigen::Vector3d truth = X_SL_Panel * panel.macro_features[i];
    const vision::MfMeasurement* m = i < run.outcome.measurement.mfs.size() ? &run.outcome.measurement.mfs[i] : nullptr;
    const bool found = m != nullptr && m->found;
    run.error_mm.push_back(found ? (m->p_CamL - truth).norm() * 1e3 : -1.0);
    char line[400];
    if (found)
      std::snprintf(line, sizeof line, "%zu,1,%.3f,%.3f,%.3f,%.3f,%.4f,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.4f\n", i, m->left.x(),
                    m->left.y(), m->right.x(), m->right.y(), m->epipolar_px, m->p_CamL.x(), m->p_CamL.y(), m->p_CamL.z(),
                    truth.x(), truth.y(), truth.z(), run.error_mm.back());
    else
      std::snprintf(line, sizeof line, "%zu,0,,,,,,,,,%.9g,%.9g,%.9g,\n", i, truth.x(), truth.y(), truth.z());
    mfs << line;
  }
  if (run.outcome.ok()) {
    run.record_path = (fs::path(folder) / "inspection.yaml").string();
    host::write_file_atomically(run.record_path, run.outcome.record);
  }
  return run;
}

}  // namespace markcell::rig
