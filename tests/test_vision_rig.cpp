// The rig's cameras: the renderer against OpenCV's projection and corner refinement,
// its determinism, and the recording format round trip with every bad-frame report.
#include <catch2/catch.hpp>
#include <sys/stat.h>
#include <cmath>
#include <filesystem>
#include <ctime>
#include <fstream>
#include <iostream>
#include <cstdio>
#include <random>

#include <Eigen/Geometry>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "draw.hpp"
#include "sheet_mesh.hpp"
#include "markcell/common/file_history.hpp"
#include "markcell/vision/calibration_io.hpp"
#include "markcell/vision/recording.hpp"
#include "markcell/rig/render.hpp"
#include "test_files.hpp"

using namespace markcell;
using namespace markcell::vision;
using namespace markcell::rig;  // the renderer the tests draw their frames with

namespace {

// A 64x48 recording of `frames` grey pairs at 1 us steps, in `folder`; returns the image.
cv::Mat small_recording(const std::string& folder, int frames) {
  RecordingManifest m;
  m.panel_type = "door";
  m.frame_rate_hz = 30;
  m.image_width = 64;
  m.image_height = 48;
  m.calibration = "stereo.yaml";
  const cv::Mat img(48, 64, CV_8UC1, cv::Scalar(100));
  RecordingWriter w(folder, m);
  for (int i = 0; i < frames; ++i) w.add(static_cast<std::uint64_t>(i), 1000 * (i + 1), img, img);
  return img;
}

StereoCalibration paper_rig() { return load_stereo_calibration(test::source_path("config/calibration/marking_stereo.yaml")); }

// The panel facing the cameras at about 3.1 m: panel y up, z towards the cameras.
Eigen::Isometry3d facing(double x, double y, double z) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::Vector3d(1, -1, -1).asDiagonal();
  X.translation() = Eigen::Vector3d(x, y, z);
  return X;
}

cv::Point2d cv_project(const CameraModel& c, const Eigen::Isometry3d& X_Cam_World, const Eigen::Vector3d& p_World) {
  cv::Mat R, rvec, tvec, K;
  cv::eigen2cv(Eigen::Matrix3d(X_Cam_World.linear()), R);
  cv::Rodrigues(R, rvec);
  cv::eigen2cv(Eigen::Vector3d(X_Cam_World.translation()), tvec);
  cv::eigen2cv(c.K, K);
  std::vector<cv::Point3d> in{{p_World.x(), p_World.y(), p_World.z()}};
  std::vector<cv::Point2d> out;
  cv::projectPoints(in, rvec, tvec, K, c.distortion, out);
  return out[0];
}

}  // namespace

TEST_CASE("the camera model projects as OpenCV's projectPoints, distortion included") {
  CameraModel c;
  c.K << 1150.0, 0.0, 322.5, 0.0, 1148.0, 236.25, 0.0, 0.0, 1.0;
  c.distortion = (cv::Mat_<double>(1, 5) << -0.21, 0.13, 0.0012, -0.0008, 0.02);
  c.width = 640;
  c.height = 480;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> xy(-0.7, 0.7), z(2.5, 3.5);
  for (int i = 0; i < 200; ++i) {
    const Eigen::Vector3d p = test::draw(rng, xy, xy, z);
    const Eigen::Vector2d ours = project_point(c, p);
    const cv::Point2d ref = cv_project(c, Eigen::Isometry3d::Identity(), p);
    CHECK(std::abs(ours.x() - ref.x) < 1e-9);
    CHECK(std::abs(ours.y() - ref.y) < 1e-9);
  }
  // The left camera goes through X_CamL_CamR.
  const StereoRenderer r(paper_rig(), RenderSettings{});
  const Eigen::Vector3d p(0.3, -0.2, 3.1);
  const cv::Point2d left = cv_project(r.cameras().left, r.cameras().X_CamR_CamL.inverse(), p);
  CHECK(r.project(0, p).x() == Approx(left.x).margin(1e-9));
  CHECK(r.project(0, p).y() == Approx(left.y).margin(1e-9));
  // Nominal rig: a point straight ahead of CamR at 3.1 m sits 0.445 * f / 3.1 px to the
  // right in the left view (disparity).
  const double f = 8.5e-3 / 7.4e-6;
  CHECK(r.project(0, {0, 0, 3.1}).x() - r.project(1, {0, 0, 3.1}).x() == Approx(0.445 * f / 3.1).epsilon(1e-12));
}

TEST_CASE("rendered edges are where the camera model puts them, to the renderer's sampling") {
  // A flat door with no noise, blur or texture: across a vertical edge between two
  // uniform regions a pixel's grey is the covered fraction blended linearly, so the
  // edge's position inside the pixel follows in closed form. Compare it with where the
  // camera model projects the panel's outline.
  RenderSettings s;
  s.noise_sigma = 0;
  s.blur_sigma_px = 0;
  s.texture_amplitude = 0;
  const StereoRenderer r(paper_rig(), s);
  test::SheetSpec flat = test::door_sheet();
  flat.bend_x = 0;
  const Panel door = test::sheet_panel("door", flat, {});
  const Eigen::Isometry3d X_CamR_Panel = facing(-0.2225, 0.05, 3.1);  // between the cameras: both edges in both views
  cv::Mat left, right;
  r.render(door, X_CamR_Panel, 1.0, 1, {}, left, right);
  int checked = 0;
  for (int cam = 0; cam < 2; ++cam) {
    const cv::Mat& img = cam == 0 ? left : right;
    for (double x_panel : {-0.55, 0.55}) {
      for (double y_panel : {-0.3, -0.2, 0.0}) {  // rows clear of the cut-outs
        const Eigen::Vector2d edge = r.project(cam, X_CamR_Panel * Eigen::Vector3d(x_panel, y_panel, 0));
        const int row = static_cast<int>(std::lround(edge.y()));
        // The true edge x on this row (the outline is vertical in the image here).
        const int u = static_cast<int>(std::floor(edge.x() + 0.5));
        const double bg = img.at<std::uint8_t>(row, u - 4 * (x_panel < 0 ? 1 : -1));
        const double panel = img.at<std::uint8_t>(row, u + 4 * (x_panel < 0 ? 1 : -1));
        const double covered = (img.at<std::uint8_t>(row, u) - bg) / (panel - bg);
        // Pixel u spans [u - 0.5, u + 0.5]; the panel covers its right part on the left
        // edge, its left part on the right edge.
        const double measured = x_panel < 0 ? u + 0.5 - covered : u - 0.5 + covered;
        INFO("camera " << cam << " edge x=" << x_panel << " y=" << y_panel << ": expected " << edge.x() << ", measured " << measured);
        CHECK(std::abs(measured - edge.x()) < 0.08);  // 1/8-pixel sampling and 8-bit rounding
        ++checked;
      }
    }
  }
  CHECK(checked == 12);
}

TEST_CASE("centre rays plus 64 samples at edges give the area integral: every pixel within 1 grey of 64 samples everywhere") {
  // The renderer takes one ray per pixel inside a surface and 64 where an edge crosses;
  // its reference integrates every pixel with the 64 samples. Without blur or noise the two
  // differ only by the shading's curvature across a pixel (texture, facets): a missed edge
  // pixel would differ by tens of grey levels.
  RenderSettings fast;
  fast.noise_sigma = 0;
  fast.blur_sigma_px = 0;
  RenderSettings slow = fast;
  slow.every_pixel_at_64 = true;
  slow.threads = 2;  // and the second thread changes nothing
  const StereoRenderer a(paper_rig(), fast), b(paper_rig(), slow);
  const Panel door = test::shipped_panel("door");
  const Eigen::Isometry3d X_CamR_Panel = facing(-0.2, 0.03, 3.1) * Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitY());
  const std::vector<Occluder> bar{{Eigen::Vector3d(-0.6, 0.1, 2.0), Eigen::Vector3d(0.4, 0.3, 2.1), 0.05, 25}};
  cv::Mat al, ar, bl, br;
  a.render(door, X_CamR_Panel, 1.0, 1, bar, al, ar);
  b.render(door, X_CamR_Panel, 1.0, 1, bar, bl, br);
  for (const auto& [x, y] : {std::pair{al, bl}, std::pair{ar, br}}) {
    cv::Mat diff;
    cv::absdiff(x, y, diff);
    double worst = 0;
    cv::minMaxLoc(diff, nullptr, &worst);
    CHECK(worst <= 1);
    CHECK(static_cast<std::size_t>(cv::countNonZero(diff)) < diff.total() / 10);  // rounding apart, the same image
    CHECK(cv::norm(x, cv::NORM_L1) > 0);
  }
}

TEST_CASE("the macro-features of the bent door are found by OpenCV's corner refinement where projected") {
  const StereoRenderer r(paper_rig(), RenderSettings{});  // nominal blur, noise and texture
  const Panel door = test::shipped_panel("door");
  REQUIRE(door.macro_features.size() == 10);
  const Eigen::Isometry3d X_CamR_Panel = facing(-0.2225, 0.05, 3.1);
  cv::Mat left, right;
  r.render(door, X_CamR_Panel, 1.0, 3, {}, left, right);
  for (int cam = 0; cam < 2; ++cam) {
    cv::Mat grey;
    (cam == 0 ? left : right).convertTo(grey, CV_32F);
    for (std::size_t i = 0; i < door.macro_features.size(); ++i) {
      const Eigen::Vector2d expected = r.project(cam, X_CamR_Panel * door.macro_features[i]);
      std::vector<cv::Point2f> pts{cv::Point2f(static_cast<float>(expected.x() + 1.0), static_cast<float>(expected.y() - 1.0))};
      cv::cornerSubPix(grey, pts, cv::Size(4, 4), cv::Size(-1, -1),
                       cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 100, 1e-4));
      INFO("camera " << cam << " macro-feature " << i << ": expected " << expected.transpose() << ", found " << pts[0]);
      // Not a measure of the renderer (the edge test is): cornerSubPix's own bias on a
      // sharp corner of a curved edge, with the e-coat texture and sensor noise, reaches
      // 0.3 px. What matters here is that every macro-feature is a corner OpenCV locks on.
      CHECK(std::hypot(pts[0].x - expected.x(), pts[0].y - expected.y()) < 0.4);
    }
  }
}

TEST_CASE("a render is identical for the same seed, different for another, noise as configured") {
  const StereoRenderer r(paper_rig(), RenderSettings{});
  const Panel fender = test::shipped_panel("fender");
  const Eigen::Isometry3d X = facing(0.0, 0.0, 3.1);
  cv::Mat l1, r1, l2, r2, l3, r3;
  r.render(fender, X, 1.0, 42, {}, l1, r1);
  r.render(fender, X, 1.0, 42, {}, l2, r2);
  r.render(fender, X, 1.0, 43, {}, l3, r3);
  CHECK(cv::norm(l1, l2, cv::NORM_INF) == 0);
  CHECK(cv::norm(r1, r2, cv::NORM_INF) == 0);
  CHECK(cv::norm(l1, l3, cv::NORM_INF) > 0);
  // On the plain background the difference of two seeds is noise alone: sigma * sqrt(2).
  cv::Mat a, b, diff;
  l1(cv::Rect(0, 0, 60, 60)).convertTo(a, CV_32F);
  l3(cv::Rect(0, 0, 60, 60)).convertTo(b, CV_32F);
  diff = a - b;
  cv::Scalar mean, stddev;
  cv::meanStdDev(diff, mean, stddev);
  CHECK(std::abs(mean[0]) < 0.2);
  CHECK(stddev[0] == Approx(1.5 * std::sqrt(2.0)).epsilon(0.15));
}

TEST_CASE("an occluder in front of the panel hides it") {
  RenderSettings s;
  s.noise_sigma = 0;
  const StereoRenderer r(paper_rig(), s);
  const Eigen::Isometry3d X = facing(0.0, 0.0, 3.1);
  // A vertical arm link 1 m in front of the right camera, straight ahead.
  const std::vector<Occluder> arm{{Eigen::Vector3d(0, -0.3, 2.0), Eigen::Vector3d(0, 0.3, 2.0), 0.06, 25}};
  cv::Mat l0, r0, l1, r1;
  const Panel door = test::shipped_panel("door");
  r.render(door, X, 1.0, 1, {}, l0, r0);
  r.render(door, X, 1.0, 1, arm, l1, r1);
  const Eigen::Vector2d centre = r.project(1, {0, -0.25, 2.0});
  CHECK(r0.at<std::uint8_t>(static_cast<int>(centre.y()), static_cast<int>(centre.x())) > 80);  // panel
  CHECK(r1.at<std::uint8_t>(static_cast<int>(centre.y()), static_cast<int>(centre.x())) == 25);  // the arm
}

TEST_CASE("recordings round-trip: images, times, truth and defects") {
  test::TempDir dir;
  const std::string folder = (dir.path() / "rec").string();
  const StereoRenderer r(paper_rig(), RenderSettings{});
  const Panel door = test::shipped_panel("door");
  RecordingManifest m;
  m.panel_type = "door";
  m.frame_rate_hz = 30;
  m.image_width = 640;
  m.image_height = 480;
  m.calibration = "stereo.yaml";
  m.seed = 99;
  m.scenario = "unit";
  std::vector<cv::Mat> lefts, rights;
  std::vector<Eigen::Isometry3d> poses;
  {
    RecordingWriter w(folder, m);
    for (int i = 0; i < 3; ++i) {
      const Eigen::Isometry3d X = facing(-0.2 + 0.01 * i, 0.0, 3.1);
      cv::Mat left, right;
      r.render(door, X, 1.0, static_cast<std::uint64_t>(i), {}, left, right);
      w.add(static_cast<std::uint64_t>(10 + i), 1'000'000'000LL + i * 33'333'333LL, left, right);
      w.add_truth(static_cast<std::uint64_t>(10 + i), 1'000'000'000LL + i * 33'333'333LL, X);
      lefts.push_back(left);
      rights.push_back(right);
      poses.push_back(X);
    }
    w.set_defects({{1, door.surface_point(0.1, -0.1), 0.01}});
  }
  save_stereo_calibration(folder + "/stereo.yaml", paper_rig());
  const Recording rec = Recording::open(folder);
  CHECK(rec.size() == 3);
  CHECK(rec.index_problems().empty());
  CHECK(rec.manifest().panel_type == "door");
  CHECK(rec.manifest().seed == std::optional<std::uint64_t>(99));
  CHECK(load_stereo_calibration(rec.calibration_path()).baseline() == Approx(0.445));
  for (std::size_t i = 0; i < 3; ++i) {
    const ReplayFrame f = rec.read(i);
    REQUIRE_FALSE(f.dropped);
    CHECK(f.seq == 10 + i);
    CHECK(f.time == 1'000'000'000LL + static_cast<Nanos>(i) * 33'333'333LL);
    CHECK(cv::norm(f.left, lefts[i], cv::NORM_INF) == 0);
    CHECK(cv::norm(f.right, rights[i], cv::NORM_INF) == 0);
    CHECK((rec.truth()[i].X_CamR_Panel.matrix() - poses[i].matrix()).norm() < 1e-12);
  }
  REQUIRE(rec.defects().size() == 1);
  CHECK(rec.defects()[0].radius == 0.01);
}

TEST_CASE("bad frames are reported with their index and dropped, never a crash") {
  test::TempDir dir;
  const std::string folder = (dir.path() / "rec").string();
  const cv::Mat img = small_recording(folder, 4);
  // Break it the ways recordings break: a missing image, a wrong size, time going
  // backwards, a corrupt index line.
  std::filesystem::remove(folder + "/right/000001.png");
  cv::imwrite(folder + "/left/000002.png", cv::Mat(24, 32, CV_8UC1, cv::Scalar(0)));
  std::ofstream(folder + "/frames.csv") << "seq,time_ns,left,right\n"
                                        << "0,1000,left/000000.png,right/000000.png\n"
                                        << "1,2000,left/000001.png,right/000001.png\n"
                                        << "2,3000,left/000002.png,right/000002.png\n"
                                        << "3,2500,left/000003.png,right/000003.png\n"
                                        << "4,5000,left/000003.png\n";
  const Recording rec = Recording::open(folder);
  REQUIRE(rec.size() == 4);
  REQUIRE(rec.index_problems().size() == 1);
  CHECK(rec.index_problems()[0] == "frames.csv:6: expected 4 fields (seq,time_ns,left,right), got 3");
  CHECK_FALSE(rec.read(0).dropped);
  const auto f1 = rec.read(1), f2 = rec.read(2), f3 = rec.read(3), f9 = rec.read(9);
  CHECK(f1.dropped);
  CHECK(f1.problem ==
        "frame 1 (seq 1, frames.csv:3): right image right/000001.png is missing or unreadable (cannot open: No such file or directory)");
  CHECK(f2.dropped);
  CHECK(f2.problem == "frame 2 (seq 2, frames.csv:4): left image left/000002.png is 32x24, the recording says 64x48");
  CHECK(f3.dropped);
  CHECK(f3.problem == "frame 3 (seq 3, frames.csv:5): time 2500 ns is not after the previous frame's 3000 ns");
  CHECK(f9.dropped);
  CHECK(f9.problem == "frame index 9 is past the end (4 frames)");
  CHECK(f1.left.empty());

  std::filesystem::remove(folder + "/recording.yaml");
  CHECK_THROWS_WITH(Recording::open(folder), folder + "/recording.yaml: missing (is " + folder + " a recording?)");
}

TEST_CASE("hostile frames and index lines: a PNG bomb, 16-bit and 2-channel images, a FIFO, paths out of the folder, times at the limits") {
  test::TempDir dir;
  const std::string folder = (dir.path() / "rec").string();
  const cv::Mat img = small_recording(folder, 2);
  // A PNG whose header declares 60000x60000 (the file itself is small): refused from the
  // header, nothing decoded or allocated for its pixels.
  std::vector<uchar> png;
  cv::imencode(".png", cv::Mat(2, 2, CV_8UC1, cv::Scalar(1)), png);
  const auto put32 = [&](std::size_t at, std::uint32_t v) {
    for (int k = 0; k < 4; ++k) png[at + static_cast<std::size_t>(k)] = static_cast<uchar>(v >> (24 - 8 * k));
  };
  put32(16, 60000);
  put32(20, 60000);
  std::ofstream(folder + "/left/bomb.png", std::ios::binary).write(reinterpret_cast<const char*>(png.data()),
                                                                   static_cast<std::streamsize>(png.size()));
  cv::imwrite(folder + "/left/deep.png", cv::Mat(48, 64, CV_16UC1, cv::Scalar(1000)));
  std::vector<uchar> two_png;
  cv::imencode(".png", cv::Mat(48, 64, CV_8UC4, cv::Scalar(1, 2, 3, 4)), two_png);
  // (OpenCV writes no grey+alpha PNG: colour type 4 is patched into an RGBA one's header,
  // which is all the reader looks at before it refuses.)
  two_png[25] = 4;
  std::ofstream(folder + "/left/two.png", std::ios::binary).write(reinterpret_cast<const char*>(two_png.data()),
                                                                  static_cast<std::streamsize>(two_png.size()));
  REQUIRE(::mkfifo((folder + "/left/fifo.png").c_str(), 0600) == 0);
  std::filesystem::create_symlink("/etc", folder + "/out");
  std::ofstream(folder + "/frames.csv") << "seq,time_ns,left,right\n"
                                        << "0,1000,left/bomb.png,right/000000.png\n"
                                        << "1,2000,left/deep.png,right/000000.png\n"
                                        << "2,3000,left/two.png,right/000000.png\n"
                                        << "3,4000,left/fifo.png,right/000000.png\n"
                                        << "4,5000,../rec/left/000000.png,right/000000.png\n"
                                        << "5,6000,/etc/passwd,right/000000.png\n"
                                        << "6,7000,out/passwd,right/000000.png\n"
                                        << "7,9223372036854775807,left/000000.png,right/000000.png\n"
                                        << "8,-9223372036854775808,left/000000.png,right/000000.png\n";
  const Recording rec = Recording::open(folder);
  for (const auto& p : rec.index_problems()) UNSCOPED_INFO(p);
  REQUIRE(rec.index_problems().size() == 5);
  CHECK(rec.index_problems()[0] == "frames.csv:6: image path '../rec/left/000000.png' leaves the recording folder (..)");
  CHECK(rec.index_problems()[1] == "frames.csv:7: image path '/etc/passwd' is an absolute path (image paths are relative to the recording folder)");
  CHECK(rec.index_problems()[2] == "frames.csv:8: image path 'out/passwd' leads out of the recording folder (through a symbolic link)");
  CHECK(rec.index_problems()[3] == "frames.csv:9: time_ns 9223372036854775807 is out of range (at most 2^62 ns from 0)");
  CHECK(rec.index_problems()[4] == "frames.csv:10: time_ns -9223372036854775808 is out of range (at most 2^62 ns from 0)");
  REQUIRE(rec.size() == 4);
  CHECK(rec.read(0).problem == "frame 0 (seq 0, frames.csv:2): left image left/bomb.png is 60000x60000, the recording says 64x48");
  CHECK(rec.read(1).problem == "frame 1 (seq 1, frames.csv:3): left image left/deep.png is not 8-bit (16 bits a sample)");
  CHECK(rec.read(2).problem ==
        "frame 2 (seq 2, frames.csv:4): left image left/two.png has 2 channels (grey and alpha): expected grey, RGB or RGBA");
  CHECK(rec.read(3).problem == "frame 3 (seq 3, frames.csv:5): left image left/fifo.png is missing or unreadable (a FIFO, not read "
                               "(a recorded image must be a regular file))");
  for (std::size_t i = 0; i < 4; ++i) CHECK(rec.read(i).dropped);

  // The manifest: a frame rate that is not a number, and a calibration outside the folder.
  std::string manifest = test::read_file(folder + "/recording.yaml");
  const std::string rate = "frame_rate_hz: 30";
  REQUIRE(manifest.find(rate) != std::string::npos);
  std::ofstream(folder + "/recording.yaml") << std::string(manifest).replace(manifest.find(rate), rate.size(), "frame_rate_hz: .nan");
  CHECK_THROWS_WITH(Recording::open(folder), folder + "/recording.yaml: key 'frame_rate_hz': must be a number in (0, 10000], got .nan");
  const std::string cal = "calibration: stereo.yaml";
  REQUIRE(manifest.find(cal) != std::string::npos);
  std::ofstream(folder + "/recording.yaml") << std::string(manifest).replace(manifest.find(cal), cal.size(), "calibration: ../../x.yaml");
  CHECK_THROWS_WITH(Recording::open(folder), folder + "/recording.yaml: key 'calibration': '../../x.yaml' leaves the recording folder (..)");
}

TEST_CASE("calibrate-stereo recovers a known rig from rendered chessboard views") {
  const StereoCalibration truth = paper_rig();
  const StereoRenderer r(truth, RenderSettings{});
  test::TempDir dir;
  std::mt19937 rng(17);
  // Board centres where both views see the whole board, tilted up to about 23 degrees.
  std::uniform_real_distribution<double> x(-0.35, -0.10), y(-0.2, 0.2), z(2.4, 3.1), tilt(-0.4, 0.4);
  const int cols = 9, rows = 6;
  const double square = 0.05;
  for (int i = 0; i < 14; ++i) {
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    const Eigen::Vector2d tilts = test::draw(rng, tilt, tilt);
    X.linear() = (Eigen::AngleAxisd(tilts(0), Eigen::Vector3d::UnitX()) * Eigen::AngleAxisd(tilts(1), Eigen::Vector3d::UnitY()))
                     .toRotationMatrix() * Eigen::Vector3d(1, -1, -1).asDiagonal();
    const Eigen::Vector3d centre = test::draw(rng, x, y, z);
    X.translation() = centre - X.linear() * Eigen::Vector3d((cols - 1) * square / 2, (rows - 1) * square / 2, 0);
    cv::Mat left, right;
    r.render_board(cols, rows, square, X, static_cast<std::uint64_t>(i), left, right);
    char name[32];
    std::snprintf(name, sizeof name, "view%02d", i);
    cv::imwrite((dir.path() / (std::string(name) + "_left.png")).string(), left);
    cv::imwrite((dir.path() / (std::string(name) + "_right.png")).string(), right);
  }
  // A view without the board, and an image without its partner.
  const cv::Mat empty(480, 640, CV_8UC1, cv::Scalar(40));
  cv::imwrite((dir.path() / "noboard_left.png").string(), empty);
  cv::imwrite((dir.path() / "noboard_right.png").string(), empty);
  cv::imwrite((dir.path() / "lonely_left.png").string(), empty);
  const std::string out = (dir.path() / "stereo.yaml").string();
  const std::time_t before = std::time(nullptr);
  const auto run = test::run_command(std::string(MARKCELL_BINARY) + " calibrate-stereo --images " + dir.path().string() +
                                     " --board 9x6 --square 0.05 --out " + out + " --left-id CAM-L-0042 --right-id 'CAM R 7'");
  INFO(run.output);
  REQUIRE(run.exit_code == 0);
  // Its provenance: when (between the test's clock readings), by which build, for which
  // cameras, and the per-view RMS the command printed, view by view.
  const auto provenance = load_provenance(out);
  REQUIRE(provenance);
  std::tm when{};
  REQUIRE(::strptime(provenance->calibrated_utc.c_str(), "%Y-%m-%dT%H:%M:%SZ", &when) != nullptr);
  const std::time_t at = ::timegm(&when);
  CHECK(at >= before);
  CHECK(at <= std::time(nullptr));
  CHECK(provenance->tool.rfind("markcell 0.1.0 (commit ", 0) == 0);
  CHECK(provenance->tool.find(", calibrate-stereo)") != std::string::npos);
  CHECK(provenance->left_camera == "CAM-L-0042");
  CHECK(provenance->right_camera == "CAM R 7");
  CHECK(provenance->rms_unit == "px");
  REQUIRE(provenance->views.size() == 14);
  for (const auto& v : provenance->views) {
    char line[128];
    std::snprintf(line, sizeof line, "  %-24s reprojection RMS %.3f px\n", v.name.c_str(), v.rms);
    CHECK(run.output.find(line) != std::string::npos);
  }
  char overall[64];
  std::snprintf(overall, sizeof overall, "RMS reprojection error: %.3f px", provenance->rms);
  CHECK(run.output.find(overall) != std::string::npos);
  CHECK(run.output.find("skipped view noboard_.png: board not found in the left image") != std::string::npos);
  CHECK(run.output.find("unpaired image (skipped): lonely_left.png") != std::string::npos);
  CHECK(run.output.find("views used: 14") != std::string::npos);
  CHECK(run.output.find("RMS reprojection error: ") != std::string::npos);
  CHECK(run.output.find("mean epipolar error: ") != std::string::npos);
  const StereoCalibration got = load_stereo_calibration(out);
  CHECK(got.baseline() == Approx(0.445).epsilon(0.005));  // within 2.2 mm
  for (const CameraModel* c : {&got.left, &got.right}) {
    CHECK(c->K(0, 0) == Approx(truth.right.K(0, 0)).epsilon(0.01));
    CHECK(c->K(1, 1) == Approx(truth.right.K(1, 1)).epsilon(0.01));
    CHECK(std::abs(c->K(0, 2) - 319.5) < 5.0);
    CHECK(std::abs(c->K(1, 2) - 239.5) < 5.0);
  }
  const Eigen::AngleAxisd dR(got.X_CamR_CamL.linear() * truth.X_CamR_CamL.linear().transpose());
  CHECK(dR.angle() < 0.2 * M_PI / 180);
  // Calibrated again: the first version kept whole in history/ beside it, named by its date.
  const std::string first = [&] {
    std::ifstream in(out, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
  }();
  const auto again = test::run_command(std::string(MARKCELL_BINARY) + " calibrate-stereo --images " + dir.path().string() +
                                       " --board 9x6 --square 0.05 --out " + out);
  INFO(again.output);
  REQUIRE(again.exit_code == 0);
  const auto kept = markcell::file_history(out);
  REQUIRE(kept.size() == 1);
  CHECK(again.output.find("kept the previous stereo.yaml as " + kept[0].string()) != std::string::npos);
  std::ifstream kept_in(kept[0], std::ios::binary);
  CHECK(std::string(std::istreambuf_iterator<char>(kept_in), {}) == first);
  CHECK(load_provenance(out)->left_camera.empty());  // not given this time
  // Too few views: the command says how many it had and needed.
  test::TempDir few;
  cv::imwrite((few.path() / "a_left.png").string(), empty);
  cv::imwrite((few.path() / "a_right.png").string(), empty);
  const auto fail = test::run_command(std::string(MARKCELL_BINARY) + " calibrate-stereo --images " + few.path().string() +
                                      " --board 9x6 --square 0.07 --out " + (few.path() / "x.yaml").string());
  CHECK(fail.exit_code == 1);
  CHECK(fail.output.find("only 0 usable view(s), at least 6 needed; a_.png: board not found in the left image") != std::string::npos);
}

TEST_CASE("an absurd calibration is refused naming the key: a baseline of 1e300 m, a focal length of 1e-300 px, a nesting bomb, a FIFO") {
  test::TempDir dir;
  StereoCalibration c = paper_rig();
  const std::string path = (dir.path() / "stereo.yaml").string();
  c.X_CamR_CamL.translation() *= 1e300;
  save_stereo_calibration(path, c);
  CHECK_THROWS_WITH(load_stereo_calibration(path), Catch::Contains(path + ": key 'T': baseline ") &&
                                                       Catch::Contains("m: expected within [0.001, 100] m (T is in metres)"));
  c = paper_rig();
  c.left.K(0, 0) = 1e-300;
  save_stereo_calibration(path, c);
  CHECK_THROWS_WITH(load_stereo_calibration(path), Catch::Contains(path + ": key 'K1': focal lengths 1e-300, ") &&
                                                       Catch::Contains("px: expected within [1, 1e6] px"));
  std::ofstream(path) << "%YAML:1.0\n---\nK1: " << std::string(50'000, '[') << "\n";
  CHECK_THROWS_WITH(load_stereo_calibration(path), path + ":3: nested deeper than a calibration file is (16 levels)");
  const std::string fifo = (dir.path() / "fifo.yaml").string();
  REQUIRE(::mkfifo(fifo.c_str(), 0600) == 0);
  CHECK_THROWS_WITH(load_stereo_calibration(fifo), fifo + ": a FIFO, not read (a calibration file must be a regular file)");
}

TEST_CASE("a calibration's provenance round-trips, a file without one loads as before, a bad one is refused by key") {
  test::TempDir dir;
  const std::string path = (dir.path() / "stereo.yaml").string();
  CalibrationProvenance p;
  p.calibrated_utc = "2026-12-07T03:40:12Z";
  p.tool = "markcell 0.1.0 (commit abc, calibrate-stereo)";
  p.left_camera = "left: 1";  // YAML's own punctuation survives
  p.rms = 0.213;
  p.rms_unit = "px";
  p.views = {{"view01", 0.2}, {"view02", 0.25}};
  save_stereo_calibration(path, paper_rig(), &p);
  const auto back = load_provenance(path);
  REQUIRE(back);
  CHECK(back->calibrated_utc == p.calibrated_utc);
  CHECK(back->tool == p.tool);
  CHECK(back->left_camera == "left: 1");
  CHECK(back->right_camera.empty());
  CHECK(back->rms == p.rms);
  REQUIRE(back->views.size() == 2);
  CHECK(back->views[1].name == "view02");
  CHECK(back->views[1].rms == 0.25);
  CHECK(load_stereo_calibration(path).baseline() == Approx(paper_rig().baseline()));
  // The shipped calibrations have none.
  CHECK_FALSE(load_provenance(test::source_path("config/calibration/marking_stereo.yaml")));
  // Malformed: each named by file and key.
  const auto with = [&](const std::string& provenance) {
    std::ofstream(path) << "%YAML:1.0\n---\nprovenance:\n" << provenance;
    return path;
  };
  CHECK_THROWS_WITH(load_provenance(with("   rms: -1\n   rms_unit: px\n")),
                    path + ": key 'provenance.rms': expected a finite RMS of at least 0");
  CHECK_THROWS_WITH(load_provenance(with("   rms: 0.2\n   rms_unit: furlong\n")),
                    path + ": key 'provenance.rms_unit': expected px or mm");
  CHECK_THROWS_WITH(load_provenance(with("   rms: 0.2\n   rms_unit: px\n   views: 3\n")),
                    path + ": key 'provenance.views': expected a list");
  CHECK_THROWS_WITH(load_provenance(with("   tool: [1, 2]\n   rms: 0.2\n   rms_unit: px\n")),
                    path + ": key 'provenance.tool': expected a text");
}
