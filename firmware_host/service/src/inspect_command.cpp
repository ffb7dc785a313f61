// `markcell inspect`: the inspection station's side (docs/inspection.md), once from files.
#include <filesystem>
#include <iostream>
#include <memory>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "markcell/common/bounded_file.hpp"
#include "markcell/host/command.hpp"
#include "markcell/host/exit_codes.hpp"
#include "markcell/host/inspection_record.hpp"
#include "markcell/host/inspection_station.hpp"
#include "markcell/vision/stereo_rig.hpp"

namespace markcell::host {

cv::Mat plot_scanner_views(const vision::StereoCalibration& scanner, const vision::TrackerParams& params,
                           const InspectionOutcome& outcome, const cv::Mat& left, const cv::Mat& right) {
  // The paper's Fig. 5: the MFs in the scanner's left view (CamL_SL), their epipolar lines
  // and matches in the right one, each labelled with its index and epipolar residual.
  const vision::StereoRig rig(scanner);
  cv::Mat l, r;
  cv::cvtColor(left, l, cv::COLOR_GRAY2BGR);
  cv::cvtColor(right, r, cv::COLOR_GRAY2BGR);
  const Eigen::Matrix3d& K = scanner.left.K;
  const Eigen::Isometry3d& X_R_L = scanner.X_CamR_CamL;
  // Quarter pixels for the lines (drawn with shift 2), whole ones for the markers.
  const auto pt = [](const Eigen::Vector2d& p) { return cv::Point(static_cast<int>(std::lround(p.x() * 4)), static_cast<int>(std::lround(p.y() * 4))); };
  const auto px = [](const Eigen::Vector2d& p) { return cv::Point(static_cast<int>(std::lround(p.x())), static_cast<int>(std::lround(p.y()))); };
  for (int i = 0; i < outcome.measurement.mfs.ssize(); ++i) {
    const vision::MfMeasurement& m = outcome.measurement.mfs[static_cast<std::size_t>(i)];
    if (!m.found) continue;
    const cv::Scalar colour(0, 200, 0);
    cv::drawMarker(l, px(m.left), colour, cv::MARKER_CROSS, 24, 2, cv::LINE_AA);
    cv::putText(l, std::to_string(i), cv::Point(static_cast<int>(m.left.x()) + 8, static_cast<int>(m.left.y()) - 8),
                cv::FONT_HERSHEY_SIMPLEX, 0.8, colour, 2, cv::LINE_AA);
    // The epipolar line of the left pixel: its ray's points between the panel's depths,
    // projected through the right camera's model (curved slightly by its distortion).
    const Eigen::Vector2d u = rig.undistort(vision::Camera::kLeft, m.left);
    const Eigen::Vector3d ray((u.x() - K(0, 2)) / K(0, 0), (u.y() - K(1, 2)) / K(1, 1), 1.0);
    std::vector<cv::Point> line;
    for (int s = 0; s <= 32; ++s) {
      const double z = params.depth_min + (params.depth_max - params.depth_min) * s / 32.0;
      line.push_back(pt(rig.project(vision::Camera::kRight, X_R_L * (ray * z))));
    }
    cv::polylines(r, line, false, cv::Scalar(0, 160, 255), 1, cv::LINE_AA, 2);
    cv::drawMarker(r, px(m.right), colour, cv::MARKER_CROSS, 24, 2, cv::LINE_AA);
    char label[48];
    std::snprintf(label, sizeof label, "%d: %.2f px", i, m.epipolar_px);
    cv::putText(r, label, cv::Point(static_cast<int>(m.right.x()) + 8, static_cast<int>(m.right.y()) - 8),
                cv::FONT_HERSHEY_SIMPLEX, 0.8, colour, 2, cv::LINE_AA);
  }
  cv::Mat both;
  cv::hconcat(l, r, both);
  const std::string title = outcome.panel_id + " (" + outcome.panel_type + "): " + std::to_string(outcome.measurement.found) +
                            " of " + std::to_string(outcome.measurement.mfs.ssize()) + " MFs; left: CamL_SL, right: epipolar lines";
  cv::putText(both, title, cv::Point(20, 40), cv::FONT_HERSHEY_SIMPLEX, 1.2, cv::Scalar(255, 255, 255), 2, cv::LINE_AA);
  return both;
}

void add_inspect_command(CLI::App& app, Commands& out) {
  struct Options {
    std::string config, images, defects, out, panel_id, panel_type, plot;
  };
  const auto o = std::make_shared<Options>();
  auto* inspect = app.add_subcommand(
      "inspect",
      "The inspection station's side (docs/inspection.md): measure a panel type's macro-features in the scanner's stereo "
      "pair and write the panel's inspection record with the defect detector's point clusters");
  inspect->add_option("--config,-c", o->config, "The inspection station's configuration (station: inspection)")->required();
  inspect->add_option("--images", o->images, "Folder with the scanner's pair of one panel: left.png and right.png")->required();
  inspect->add_option("--defects", o->defects,
                      "The defect detector's points (CSV or ASCII PLY, vision/RECORDING.md \"The defects file\"); none: no defects");
  inspect->add_option("--out", o->out, "The record to write (default: inspection.record_folder/PANEL_ID.yaml)");
  inspect->add_option("--panel-id", o->panel_id, "The panel's id (default: the images folder's name)");
  inspect->add_option("--panel-type", o->panel_type, "The panel type in front of the scanner (default: the only one configured)");
  inspect->add_option("--plot", o->plot, "Also write the paper's Fig. 5 on the scanner's two views (PNG)");
  out.push_back({inspect, [o] {
                   InspectionStationConfig config;
                   try {
                     config = load_inspection_station_config(o->config);
                   } catch (const ConfigInvalid& e) {
                     for (const auto& error : e.errors()) std::cerr << error.to_string() << "\n";
                     return kExitConfig;
                   }
                   std::string panel_type = o->panel_type;
                   if (panel_type.empty()) {
                     if (config.panel_types.size() != 1) {
                       std::cerr << "markcell inspect: " << config.file << " has " << config.panel_types.size()
                                 << " panel types: say which with --panel-type\n";
                       return kExitConfig;
                     }
                     panel_type = config.panel_types.front().name;
                   }
                   const std::filesystem::path images(o->images);
                   const std::string panel_id =
                       o->panel_id.empty() ? images.lexically_normal().filename().string() : o->panel_id;
                   if (o->panel_id.empty() && panel_id.empty()) {
                     std::cerr << "markcell inspect: --images " << o->images << " names no folder to take the panel id from: give --panel-id\n";
                     return kExitConfig;
                   }
                   if (const std::string why = panel_id_problem(panel_id); !why.empty()) {
                     std::cerr << "markcell inspect: panel id '" << panel_id << "': " << why << "\n";
                     return kExitConfig;
                   }
                   std::string record_path = o->out;
                   if (record_path.empty()) {
                     if (config.record_folder.empty()) {
                       std::cerr << "markcell inspect: give --out, or set inspection.record_folder in " << config.file << "\n";
                       return kExitConfig;
                     }
                     record_path = (std::filesystem::path(config.record_folder) / (panel_id + ".yaml")).string();
                   }
                   std::unique_ptr<InspectionStation> station;
                   cv::Mat left, right;
                   std::vector<DefectCluster> defects;
                   try {
                     station = std::make_unique<InspectionStation>(config);
                     const int w = station->scanner().left.width, h = station->scanner().left.height;
                     left = read_scan_image((images / "left.png").string(), w, h);
                     right = read_scan_image((images / "right.png").string(), w, h);
                     if (!o->defects.empty())
                       defects = read_defects_file(o->defects, station->volume(), config.min_points_per_defect);
                   } catch (const std::exception& e) {
                     std::cerr << "markcell inspect: " << e.what() << "\n";
                     return kExitConfig;
                   }
                   const InspectionOutcome outcome = station->inspect(panel_id, panel_type, left, right, defects);
                   if (!o->plot.empty()) {
                     const cv::Mat plot = plot_scanner_views(station->scanner(), config.vision, outcome, left, right);
                     if (!cv::imwrite(o->plot, plot)) std::cerr << "markcell inspect: cannot write " << o->plot << "\n";
                   }
                   for (int i = 0; i < outcome.measurement.mfs.ssize(); ++i) {
                     const auto& m = outcome.measurement.mfs[static_cast<std::size_t>(i)];
                     char line[200];
                     if (m.found)
                       std::snprintf(line, sizeof line, "MF %2d: (%.4f, %.4f, %.4f) m in CamL_SL, epipolar %.3f px\n", i,
                                     m.p_CamL.x(), m.p_CamL.y(), m.p_CamL.z(), m.epipolar_px);
                     else
                       std::snprintf(line, sizeof line, "MF %2d: not found\n", i);
                     std::cout << line;
                   }
                   if (!outcome.ok()) {
                     std::cerr << "markcell inspect: no record for panel " << panel_id << ": " << outcome.problem << "\n";
                     return kExitRuntime;
                   }
                   try {
                     // The marking station's own reader first: what it would refuse is never written.
                     // (The loader has checked each panel type's macro_features against its file.)
                     (void)parse_inspection_record(outcome.record, record_path, config.panel_types);
                     write_file_atomically(record_path, outcome.record);
                   } catch (const std::exception& e) {
                     std::cerr << "markcell inspect: no record for panel " << panel_id << ": " << e.what() << "\n";
                     return kExitRuntime;
                   }
                   std::cout << "panel " << panel_id << " (" << panel_type << "): " << outcome.measurement.found << " of "
                             << outcome.measurement.mfs.ssize() << " macro-features, " << defects.size() << " defect(s); record "
                             << record_path << "\n";
                   return kExitOk;
                 }});
}

}  // namespace markcell::host
