// The inspection station (host/inspection_station.hpp, `markcell inspect`): its MFs measured
// on the scanner's rendered views against the rig's ground truth, the record it writes
// read back by the marking station's own reader, and every refusal with its reason.
#include <catch2/catch.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>

#include <opencv2/imgcodecs.hpp>

#include "markcell/host/config.hpp"
#include "markcell/host/inspection_record.hpp"
#include "markcell/host/inspection_station.hpp"
#include "markcell/rig/inspection.hpp"
#include "markcell/vision/calibration_io.hpp"
#include "sheet_mesh.hpp"
#include "test_files.hpp"

using namespace markcell;
using namespace markcell::test;
namespace fs = std::filesystem;

namespace {
const std::string kMarkcell = MARKCELL_BINARY;

vision::StereoCalibration scanner() {
  return vision::load_stereo_calibration(source_path("config/calibration/inspection_stereo.yaml"));
}

// The panel at the inspection station as the shipped scenarios put it: 2 m from the
// scanner, turned about its vertical axis (centimetres and degrees off the reference pose
// its MFs were picked at).
Eigen::Isometry3d X_SL_Panel(double yaw, double x, double y, double z) {
  Eigen::Isometry3d X = rig::scanner_reference_pose();
  X.translation() = Eigen::Vector3d(x, y, z);
  X.linear() = X.linear() * Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitY()).toRotationMatrix();
  return X;
}

std::vector<host::PanelTypeConfig> marking_types(const std::string& name) {
  host::PanelTypeConfig t;
  t.name = name;
  t.macro_features = 10;
  return {t};
}

std::string run(const std::string& args, int expected_exit) {
  const auto r = run_command(kMarkcell + " " + args + " 2>&1");
  INFO(args << "\n" << r.output);
  CHECK(r.exit_code == expected_exit);
  return r.output;
}
}  // namespace

TEST_CASE("the inspection station measures every MF of the door and the fender within 1.5 mm of the truth in CamL_SL") {
  struct Pose {
    double yaw, x, y, z;
  };
  for (const std::string& name : std::vector<std::string>{"door", "fender"})
    for (const Pose pose : {Pose{0.08, 0.15, 0.02, 2.0}, Pose{-0.06, 0.09, -0.03, 2.1}}) {
      TempDir dir;
      const rig::Panel panel = shipped_panel(name);
      // Two dings on each panel's skin (its scenario's).
      const std::vector<rig::DefectSpec> defects = name == "door"
                                                       ? std::vector<rig::DefectSpec>{{1, 0.12, -0.12, 0.012}, {2, -0.18, -0.22, 0.012}}
                                                       : std::vector<rig::DefectSpec>{{1, -0.25, 0.15, 0.012}, {2, 0.3, -0.05, 0.012}};
      const Eigen::Isometry3d X = X_SL_Panel(pose.yaw, pose.x, pose.y, pose.z);
      const rig::InspectionRun r =
          rig::run_inspection_station(dir.path().string(), "P-1", panel, defects, scanner(), X, rig::InspectionNoise{}, {}, 5);
      INFO(name << " yaw " << pose.yaw << ": " << r.outcome.problem);
      REQUIRE(r.outcome.ok());
      REQUIRE(r.error_mm.size() == 10);
      for (std::size_t i = 0; i < 10; ++i) {
        INFO("MF " << i);
        const vision::MfMeasurement& m = r.outcome.measurement.mfs[i];
        REQUIRE(m.found);
        // Against the rig's truth: the mesh's MF where the panel stands.
        CHECK((m.p_CamL - X * panel.macro_features[i]).norm() < 0.0015);
        CHECK(r.error_mm[i] == Approx((m.p_CamL - X * panel.macro_features[i]).norm() * 1e3).margin(1e-9));
        CHECK(m.epipolar_px < 1.0);
        CHECK((m.corner_response > 0 || m.hole_rms_px > 0));
      }
      // The record, read back by the marking station's reader: the same MFs and defects.
      const control::PanelJob job = host::read_inspection_record(r.record_path, marking_types(name));
      CHECK(std::string(job.panel_id.c_str()) == "P-1");
      REQUIRE(job.mfs_SL.size() == 10);
      for (std::size_t i = 0; i < 10; ++i) CHECK((job.mfs_SL[i] - r.outcome.measurement.mfs[i].p_CamL).norm() < 1e-8);
      REQUIRE(job.defects.size() == 2);
      const auto sampled = rig::sample_defect_points(panel, defects, X, rig::InspectionNoise{}, 5);
      for (std::size_t d = 0; d < 2; ++d) {
        CHECK(job.defects[d].id == defects[d].id);
        REQUIRE(job.defects[d].points_SL.size() == sampled[d].points_SL.size());
        for (std::size_t k = 0; k < sampled[d].points_SL.size(); ++k)
          CHECK((job.defects[d].points_SL[k] - sampled[d].points_SL[k]).norm() < 1e-8);
      }
    }
}

TEST_CASE("markcell inspect: a record from the scanner's files, or a precise refusal and no record") {
  TempDir dir;
  const rig::Panel door = shipped_panel("door");
  const rig::InspectionRun made = rig::run_inspection_station(dir.path().string(), "P-1", door, {{1, 0.12, -0.12, 0.012}},
                                                              scanner(), X_SL_Panel(0.08, 0.15, 0.02, 2.0), {}, {}, 5);
  REQUIRE(made.outcome.ok());
  const fs::path in = dir.path() / "inspection";
  const std::string station = (in / "station.yaml").string();
  // As the rig ran it: the same record, byte for byte, and the Fig. 5 plot.
  const std::string out = (dir.path() / "by-hand.yaml").string();
  const std::string plot = (dir.path() / "fig5.png").string();
  const std::string said = run("inspect --config " + station + " --images " + in.string() + " --defects " +
                                   (in / "defects.csv").string() + " --panel-id P-1 --out " + out + " --plot " + plot,
                               0);
  CHECK_THAT(said, Catch::Contains("panel P-1 (door): 10 of 10 macro-features, 1 defect(s); record " + out));
  CHECK(read_file(out) == read_file(made.record_path));
  const cv::Mat fig = cv::imread(plot);
  CHECK(fig.cols == 2 * 1392);
  CHECK(fig.rows == 1040);
  CHECK_THAT(run("check-config " + station, 0), Catch::Contains("valid (an inspection station: markcell inspect)"));

  // A missing image, an image of the wrong size, a defects file with NaN: exit 2, no record.
  const fs::path bad = dir.path() / "P-2";
  fs::create_directories(bad);
  fs::copy_file(in / "left.png", bad / "left.png");
  const std::string no_record = (dir.path() / "none.yaml").string();
  const std::string base = "inspect --config " + station + " --images " + bad.string() + " --out " + no_record;
  CHECK_THAT(run(base, 2), Catch::Contains((bad / "right.png").string() + ": cannot open: No such file or directory"));
  cv::Mat small(480, 640, CV_8U, cv::Scalar(90));
  cv::imwrite((bad / "right.png").string(), small);
  CHECK_THAT(run(base, 2), Catch::Contains((bad / "right.png").string() +
                                           ": 640x480, the scanner's cameras are 1392x1040 (its calibration)"));
  fs::copy_file(in / "right.png", bad / "right.png", fs::copy_options::overwrite_existing);
  const std::string nan = dir.write("nan.csv", "defect_id,x_m,y_m,z_m\n1,0.1,0.1,2.0\n1,nan,0.1,2.0\n1,0.1,0.11,2.0\n");
  CHECK_THAT(run(base + " --defects " + nan, 2), Catch::Contains(nan + ":3: "));
  CHECK_FALSE(fs::exists(no_record));
  // The panel id comes from the folder's name: P-2.
  CHECK_THAT(run(base, 0), Catch::Contains("panel P-2 (door): 10 of 10 macro-features, 0 defect(s)"));
  CHECK(host::read_inspection_record(no_record, marking_types("door")).defects.empty());
}

TEST_CASE("a fender in front of a station told to expect a door: no record, the reason said") {
  TempDir dir;
  const rig::InspectionRun door = rig::run_inspection_station(dir.path().string(), "P-1", shipped_panel("door"), {}, scanner(),
                                                              X_SL_Panel(0.0, 0.12, 0.0, 2.05), {}, {}, 5);
  REQUIRE(door.outcome.ok());
  TempDir other;
  const rig::InspectionRun fender = rig::run_inspection_station(other.path().string(), "P-2", shipped_panel("fender"), {},
                                                                scanner(), X_SL_Panel(0.05, 0.14, 0.01, 2.0), {}, {}, 5);
  REQUIRE(fender.outcome.ok());
  const std::string station = (dir.path() / "inspection" / "station.yaml").string();
  const std::string out = (dir.path() / "wrong.yaml").string();
  const std::string said = run("inspect --config " + station + " --images " + (other.path() / "inspection").string() +
                                   " --panel-id P-2 --panel-type door --out " + out,
                               1);
  CHECK_THAT(said, Catch::Contains("markcell inspect: no record for panel P-2: "));
  CHECK_THAT(said, Catch::Contains("macro-features of a door measured, at least 4 needed"));
  CHECK_FALSE(fs::exists(out));
}

TEST_CASE("the inspection station's configuration: every error at its file, line and column") {
  TempDir dir;
  const rig::InspectionRun made = rig::run_inspection_station(dir.path().string(), "P-1", shipped_panel("door"), {}, scanner(),
                                                              X_SL_Panel(0.0, 0.12, 0.0, 2.05), {}, {}, 5);
  REQUIRE(made.outcome.ok());
  const fs::path in = dir.path() / "inspection";
  const std::string good = read_file((in / "station.yaml").string());
  const auto errors_of = [&](const std::string& text) {
    const std::string path = (in / "edited.yaml").string();
    std::ofstream(path) << text;
    std::string all;
    for (const auto& e : host::check_config(path, host::TaskTable{})) all += e.to_string() + "\n";
    return all;
  };
  CHECK(errors_of(good).empty());
  std::string text = good;
  replace_once(text, "    file: panel_type.yaml\n", "    file: panel_type.yaml\n    recipe: {pulse_ms: 60}\n");
  CHECK_THAT(errors_of(text), Catch::Contains("edited.yaml:10:13: panel_types.door.recipe: an inspection station does not spray"));
  text = good;
  replace_once(text, "  name: rig-scanner\n", "  name: rig-scanner\n  colour: blue\n");
  CHECK_THAT(errors_of(text), Catch::Contains("edited.yaml:5:3: inspection.colour: unknown key 'colour'"));
  text = good;
  replace_once(text, "  depth_max_m: 3.5\n", "  depth_max_m: 1.0\n");
  CHECK_THAT(errors_of(text), Catch::Contains("vision.depth_max_m: must be greater than depth_min_m"));
  // MFs picked on a marking camera's 640x480 image do not fit the scanner's 1392x1040.
  text = good;
  replace_once(text, "file: panel_type.yaml", "file: " + source_path("config/panels/door.yaml"));
  CHECK_THAT(errors_of(text), Catch::Contains("panel_types.door.file: its MFs were picked on a 640x480 image; the scanner's "
                                              "cameras are 1392x1040 (select-mfs on a scanner image)"));
  // A station's file given to the cell, and the cell's to the station.
  CHECK_THAT(run("run --config " + (in / "station.yaml").string(), 2),
             Catch::Contains("station: this is an inspection station's configuration: markcell inspect --config reads it"));
  CHECK_THAT(run("inspect --config " + source_path("config/cell.example.yaml") + " --images " + in.string(), 2),
             Catch::Contains("unknown key"));
}

TEST_CASE("an inspection record with MFs the station did not find: ~ is left out of the fit and fewer than 3 are refused") {
  const auto types = marking_types("door");
  std::string mfs = "macro_features:\n";
  for (int i = 0; i < 10; ++i) mfs += i < 7 ? "  - [0." + std::to_string(i) + ", 0.1, 2.0]\n" : "  - ~\n";
  const std::string head = "panel_id: P-9\npanel_type: door\nframe: CamL_SL\nunits: m\n";
  const std::string tail = "defects: []\n...\n";
  const control::PanelJob job = host::parse_inspection_record(head + mfs + tail, "r.yaml", types);
  REQUIRE(job.mfs_SL.size() == 10);
  CHECK(job.mfs_SL[6].allFinite());
  CHECK_FALSE(job.mfs_SL[7].allFinite());
  std::string two = "macro_features:\n";
  for (int i = 0; i < 10; ++i) two += i < 2 ? "  - [0." + std::to_string(i) + ", 0.1, 2.0]\n" : "  - ~\n";
  CHECK_THROWS_WITH(host::parse_inspection_record(head + two + tail, "r.yaml", types),
                    "r.yaml:6:3: macro_features: 2 measured (the rest ~), at least 3 are needed to place the panel");
  // The quality list: one entry per MF, ~ exactly where the MF is.
  std::string quality = "macro_feature_quality:\n";
  for (int i = 0; i < 10; ++i) quality += i < 6 ? "  - {epipolar_px: 0.1, left_px: [1, 2]}\n" : "  - ~\n";
  CHECK_THROWS_WITH(host::parse_inspection_record(head + mfs + quality + tail, "r.yaml", types),
                    "r.yaml:23:5: macro_feature_quality[6]: missing for a measured macro-feature");
}
