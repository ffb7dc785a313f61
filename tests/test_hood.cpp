// Issue 20's hood test. A panel
// type that is not in the repository, made of files only: the test writes a doubly
// curved hood mesh with a cut-out and two round holes, renders a reference image, picks
// its MFs with headless select-mfs (two of them holes), writes the panel-type file's rig
// keys and a scenario file, and `markcell sim` must mark every defect within 3 mm with
// no false spray.
#include <catch2/catch.hpp>

#include <cstdio>
#include <filesystem>
#include <fstream>

#include <opencv2/imgcodecs.hpp>

#include "markcell/rig/panel_mesh.hpp"
#include "markcell/rig/render.hpp"
#include "markcell/vision/calibration_io.hpp"
#include "markcell/vision/panel_tracker.hpp"
#include "sheet_mesh.hpp"
#include "sim_helpers.hpp"
#include "test_files.hpp"

using namespace markcell;
using namespace markcell::test;

namespace {
SheetSpec hood_sheet() {
  SheetSpec s;
  s.width = 1.0, s.height = 0.6;
  s.bend_x = 0.3, s.bend_y = 0.2;  // doubly curved
  s.cutouts = {{-0.05, 0.05, 0.15, 0.2}};
  s.holes = {{-0.3, 0.15, 0.014}, {0.35, -0.18, 0.012}};
  s.spacing = 0.01;
  return s;
}
std::string num(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.6f", v);
  return b;
}
}  // namespace

TEST_CASE("a hood made of files only: its mesh, MFs picked headless (two holes), a scenario, and sim marks every defect within 3 mm") {
  TempDir dir;
  const SheetSpec spec = hood_sheet();
  const std::filesystem::path panels = dir.path() / "panels";
  std::filesystem::create_directories(panels);
  rig::save_mesh_ply((panels / "hood.ply").string(), sheet_mesh(spec));
  // Its MFs: the outline's corners, the cut-out's, the two holes' centres (last).
  std::vector<Eigen::Vector3d> mfs;
  for (const auto& [x, y] : std::vector<std::pair<double, double>>{{-0.5, -0.3}, {0.5, -0.3}, {0.5, 0.3}, {-0.5, 0.3}})
    mfs.push_back(spec.point(x, y));
  const auto& c = spec.cutouts[0];
  for (const auto& [x, y] : std::vector<std::pair<double, double>>{{c.x0, c.y0}, {c.x1, c.y0}, {c.x1, c.y1}, {c.x0, c.y1}})
    mfs.push_back(spec.point(x, y));
  for (const auto& h : spec.holes) mfs.push_back(spec.point(h.x, h.y));
  // The reference image as the scenario reader renders it: the panel on the line, square to
  // the left camera (rig::reference_panel_type's pose).
  const auto cal = vision::load_stereo_calibration(source_path("config/calibration/marking_stereo.yaml"));
  const rig::Panel panel = sheet_panel("hood", spec, mfs);
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::Vector3d(1, -1, -1).asDiagonal();
  X.translation() = Eigen::Vector3d(cal.X_CamR_CamL.translation().x(), 0.0, 3.1);
  const rig::StereoRenderer renderer(cal, rig::RenderSettings{});
  cv::Mat left, right;
  renderer.render(panel, X, 1.0, 11, {}, left, right);
  const std::string image = (dir.path() / "hood.png").string();
  cv::imwrite(image, left);
  std::string args;
  for (std::size_t i = 0; i < mfs.size(); ++i) {
    const Eigen::Vector2d p = renderer.project(0, X * mfs[i]);
    args += " --mf " + std::to_string(std::lround(p.x()) + 1) + "," + std::to_string(std::lround(p.y())) +
            (i >= 8 ? ",hole" : "");
  }
  const std::string type_file = (panels / "hood.yaml").string();
  const auto picked = run_command(kMarkcell + " select-mfs --image " + image + " --panel hood --out " + type_file + args);
  INFO(picked.output);
  REQUIRE(picked.exit_code == 0);
  CHECK(picked.output.find("MF  9 hole") != std::string::npos);
  CHECK(picked.output.find("MF 10 hole") != std::string::npos);
  // The rig's keys: the mesh and the MFs' true positions.
  {
    std::ofstream out(type_file, std::ios::app);
    out << "mesh: hood.ply\nmesh_metres_per_unit: 1.\nmacro_features_panel: !!opencv-matrix\n   rows: " << mfs.size()
        << "\n   cols: 3\n   dt: d\n   data: [ ";
    for (std::size_t i = 0; i < mfs.size(); ++i)
      out << (i ? ", " : "") << num(mfs[i].x()) << ", " << num(mfs[i].y()) << ", " << num(mfs[i].z());
    out << " ]\n";
  }
  // (sim renders the inspection station's views with its calibration, beside the configuration's)
  std::filesystem::create_directories(dir.path() / "calibration");
  std::filesystem::copy_file(source_path("config/calibration/inspection_stereo.yaml"),
                             dir.path() / "calibration" / "inspection_stereo.yaml");
  const std::string config = dir.write(
      "cell.yaml", example_config_text({{"  fender: {macro_features: 10, file: panels/fender.yaml}",
                                         "  fender: {macro_features: 10, file: panels/fender.yaml}\n  hood: {macro_features: 10, file: " +
                                             type_file + "}"}}));
  const std::string scenario = dir.write("hood.yaml", R"(panel_type: hood
seed: 1
duration_s: 12
fps: 10
speed: {kind: constant, min_m_per_s: 0.014, max_m_per_s: 0.014}
line:
  X_CamR_Line:
    translation: [-0.3625, 0.0, 3.1]
    rotation: [[1, 0, 0], [0, -1, 0], [0, 0, -1]]
defects:
  - {id: 1, x: 0.2, y: -0.1, radius: 0.012}
  - {id: 2, x: -0.2, y: -0.15, radius: 0.012}
  - {id: 3, x: 0.3, y: 0.1, radius: 0.012}
exposure_drift: 0.0
inspection:
  X_SL_Panel:
    translation: [0.15, 0.02, 2.0]
    rotation: [[1, 0, 0], [0, -1, 0], [0, 0, -1]]
  pixel_sigma: 0.25
  depth_sigma: 0.0003
  ding_depth: 0.0004
  points_per_defect: 60
)");
  const std::string out = (dir.path() / "out").string();
  const auto sim = run_command("cd " + dir.path().string() + " && " + kMarkcell + " sim " + scenario + " --config " + config +
                               " --one-predictor -q --out " + out);
  INFO(sim.output);
  REQUIRE(sim.exit_code == 0);
  const auto report = parse_json(read_file(out + "/report.json"));
  CHECK(report["scored_on"] == "surface");
  CHECK(report["defects"]["marked"] == 3);
  CHECK(report["false_sprays"] == 0);
  CHECK(report["marking_error_mm"]["max"].get<double>() < 3.0);
  CHECK(report["intercalibration_cm"]["macro_features"].get<int>() >= 8);
  std::printf("hood: %d of 3 marked, marking error max %.2f mm rms %.2f mm, pose error max %.2f mm, %d MFs in the "
              "inter-calibration\n",
              report["defects"]["marked"].get<int>(), report["marking_error_mm"]["max"].get<double>(),
              report["marking_error_mm"]["rms"].get<double>(), report["pose_error_mm"]["max"].get<double>(),
              report["intercalibration_cm"]["macro_features"].get<int>());
}
