// Issue 20's hood test. A panel
// type that is not in the repository, made of files only: the test writes a doubly
// curved hood mesh with a cut-out and two round holes, renders a reference image, picks
// its MFs with headless select-mfs (two of them holes), writes the panel-type file's rig
// keys and a scenario file, and `markcell sim` must mark every defect within 3 mm with
// no false spray; and the rig's scorer lands sprays on that hood where the closed-form
// ray-surface intersection does, to 0.1 mm.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include <opencv2/imgcodecs.hpp>

#include "markcell/rig/panel_mesh.hpp"
#include "markcell/rig/panel.hpp"
#include "markcell/rig/render.hpp"
#include "markcell/rig/scoring.hpp"
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

// The scorer on the hood's mesh file (written, read back through the rig's PLY reader)
// against SheetSpec::intersect, the closed form of the same doubly curved sheet: a grid of
// sprays over the moving, tilted panel, aimed at material, at the cut-out, at the holes and
// past the edges, each from its own slanted nozzle. The mesh is the sheet's tessellation
// (1 cm grid, sagitta below 0.01 mm), so every landing point agrees to 0.1 mm and every
// spray agrees on whether it met material, except within 2 mm of an edge, where the
// mesh's polygonal rims and the true circles part.
TEST_CASE("the scorer's landing points on the hood agree with the closed-form ray-surface intersection to 0.1 mm") {
  TempDir dir;
  const SheetSpec spec = hood_sheet();
  const std::string file = (dir.path() / "hood.ply").string();
  rig::save_mesh_ply(file, sheet_mesh(spec));
  const rig::Panel panel = rig::load_panel_mesh("hood", file, 1.0);
  // The panel moving along the line at 5 cm/s, tilted 0.2 rad about y and 0.1 about x.
  const auto X_CamR_Panel_at = [](Nanos t) {
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() = (Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitY()) * Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitX())).toRotationMatrix() *
                 Eigen::Vector3d(1, -1, -1).asDiagonal();
    X.translation() = Eigen::Vector3d(-0.2 + 0.05 * to_seconds(t), 0.02, 3.0);
    return X;
  };
  const std::vector<rig::TrueDefect> defects = {{1, spec.point(0.2, -0.1)}, {2, spec.point(-0.2, -0.15)}, {3, spec.point(0.3, 0.1)}};
  std::vector<rig::Spray> sprays;
  std::vector<Eigen::Vector2d> aims;
  int k = 0;
  for (double x = -0.56; x <= 0.56; x += 0.035)
    for (double y = -0.34; y <= 0.34; y += 0.035, ++k) {
      aims.emplace_back(x, y);
      rig::Spray s;
      s.time = static_cast<Nanos>(k) * 7 * kNanosPerMilli;
      const Eigen::Isometry3d X_CamR_Panel = X_CamR_Panel_at(s.time);
      // From 0.12 m off the sheet along its normal, tilted a little from it, through (x, y, z(x, y)).
      const Eigen::Vector3d target = spec.point(x, y);
      const Eigen::Vector3d tilt(0.15 * std::sin(k), 0.15 * std::cos(1.7 * k), 0.0);
      const Eigen::Vector3d axis_P = (spec.normal(x, y) + tilt).normalized();  // from the target towards the nozzle
      const Eigen::Vector3d nozzle_P = target + 0.12 * axis_P;
      // The nozzle sprays along its -z: its z axis is axis_P.
      const Eigen::Vector3d z = X_CamR_Panel.linear() * axis_P;
      const Eigen::Vector3d x_axis = z.unitOrthogonal();
      s.X_CamR_Nozzle.linear().col(0) = x_axis;
      s.X_CamR_Nozzle.linear().col(1) = z.cross(x_axis);
      s.X_CamR_Nozzle.linear().col(2) = z;
      s.X_CamR_Nozzle.translation() = X_CamR_Panel * nozzle_P;
      sprays.push_back(s);
    }
  const rig::Score score = rig::score_sprays(panel, X_CamR_Panel_at, defects, sprays, {}, 0.012);
  REQUIRE(score.sprays.size() == sprays.size());
  // Distance from (x, y) to the nearest edge of material: the outline, the cut-out, the holes.
  const auto edge_distance = [&spec](double x, double y) {
    double d = std::min(std::abs(std::abs(x) - spec.width / 2), std::abs(std::abs(y) - spec.height / 2));
    for (const auto& c : spec.cutouts) {
      const bool inside = x > c.x0 && x < c.x1 && y > c.y0 && y < c.y1;
      d = std::min(d, inside ? std::min({x - c.x0, c.x1 - x, y - c.y0, c.y1 - y})
                             : std::hypot(std::max({c.x0 - x, 0.0, x - c.x1}), std::max({c.y0 - y, 0.0, y - c.y1})));
    }
    for (const auto& h : spec.holes) d = std::min(d, std::abs(std::hypot(x - h.x, y - h.y) - h.radius));
    return d;
  };
  int compared = 0, on_material = 0, off_material = 0;
  double worst_mm = 0, worst_distance_mm = 0;
  for (std::size_t i = 0; i < sprays.size(); ++i) {
    const Eigen::Isometry3d X_Panel_CamR = X_CamR_Panel_at(sprays[i].time).inverse();
    const Eigen::Vector3d o_P = X_Panel_CamR * sprays[i].X_CamR_Nozzle.translation();
    const Eigen::Vector3d d_P = X_Panel_CamR.linear() * -sprays[i].X_CamR_Nozzle.linear().col(2);
    const double t = spec.intersect(o_P, d_P);
    const rig::SprayResult& got = score.sprays[i];
    if (t > 0 && edge_distance((o_P + t * d_P).x(), (o_P + t * d_P).y()) < 0.002) continue;
    if (t <= 0 && edge_distance(aims[i].x(), aims[i].y()) < 0.002) continue;
    ++compared;
    INFO("spray " << i << " aimed at (" << aims[i].transpose() << ")");
    REQUIRE(got.on_panel == (t > 0));
    if (t <= 0) {
      ++off_material;
      continue;
    }
    ++on_material;
    const Eigen::Vector3d p_P = o_P + t * d_P;
    const Eigen::Vector3d got_P = X_Panel_CamR * got.p_CamR;
    CHECK((got_P - p_P).norm() < 1e-4);
    worst_mm = std::max(worst_mm, (got_P - p_P).norm() * 1000);
    // And the scored distance to the nearest defect, from the closed-form landing point.
    double nearest = 1e9;
    for (const auto& d : defects) nearest = std::min(nearest, (d.p_Panel - p_P).norm());
    CHECK(std::abs(got.distance - nearest) < 1e-4);
    worst_distance_mm = std::max(worst_distance_mm, std::abs(got.distance - nearest) * 1000);
  }
  CHECK(on_material > 300);
  CHECK(off_material > 20);  // the cut-out, the holes and past the outline
  CHECK(compared > static_cast<int>(sprays.size()) * 9 / 10);
  std::printf("hood scorer vs closed form: %d sprays compared (%d on material, %d off), landing points within %.4f mm, "
              "distances within %.4f mm\n",
              compared, on_material, off_material, worst_mm, worst_distance_mm);
}
