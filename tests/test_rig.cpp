// The rig's line motion and its scoring, against closed-form answers.
#include <catch2/catch.hpp>
#include <sys/stat.h>
#include <cmath>

#include "markcell/rig/line_motion.hpp"
#include "markcell/rig/scoring.hpp"
#include "sheet_mesh.hpp"

using namespace markcell;
using namespace markcell::rig;

namespace {

Eigen::Isometry3d facing(double x, double y, double z) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::Vector3d(1, -1, -1).asDiagonal();
  X.translation() = Eigen::Vector3d(x, y, z);
  return X;
}

}  // namespace

TEST_CASE("constant speed: distance is speed times time") {
  SpeedProfile s;
  s.min_speed = s.max_speed = 0.014;
  const LineMotion m(s, LinePath{}, seconds(36));
  CHECK(m.distance(seconds(36)) == Approx(0.014 * 36).epsilon(1e-9));
  CHECK(m.distance(millis(12'500)) == Approx(0.014 * 12.5).epsilon(1e-9));
  CHECK(m.X_Line_Panel(seconds(10)).translation().x() == Approx(0.14).epsilon(1e-9));
  CHECK(m.X_Line_Panel(seconds(10)).linear().isIdentity());
}

TEST_CASE("fluctuating speed stays in its band, is the same for the same seed, differs for another") {
  SpeedProfile s;
  s.kind = SpeedKind::kFluctuating;
  s.min_speed = 0.012;
  s.max_speed = 0.016;
  s.seed = 5;
  const LineMotion a(s, LinePath{}, seconds(36)), b(s, LinePath{}, seconds(36));
  s.seed = 6;
  const LineMotion c(s, LinePath{}, seconds(36));
  double lo = 1, hi = 0;
  bool differs = false;
  for (Nanos t = 0; t <= seconds(36); t += millis(1)) {
    lo = std::min(lo, a.speed(t));
    hi = std::max(hi, a.speed(t));
    CHECK(a.distance(t) == b.distance(t));
    differs |= a.speed(t) != c.speed(t);
  }
  CHECK(lo >= 0.012);
  CHECK(hi <= 0.016);
  CHECK(hi - lo > 0.002);  // it does fluctuate, over most of the band
  CHECK(differs);
  const double mean = a.distance(seconds(36)) / 36;
  CHECK(mean > 0.012);
  CHECK(mean < 0.016);
}

TEST_CASE("stop-and-go: stops, runs at full speed, never accelerates harder than allowed") {
  SpeedProfile s;
  s.kind = SpeedKind::kStopAndGo;
  s.max_speed = 0.15;
  s.accel = 0.3;
  s.stop_and_go_run_s = 3;
  s.stop_and_go_stop_s = 1.5;
  const LineMotion m(s, LinePath{}, seconds(20));
  bool stopped = false, full = false;
  for (Nanos t = millis(1); t <= seconds(20); t += millis(1)) {
    stopped |= m.speed(t) == 0.0 && t > seconds(4);
    full |= m.speed(t) == 0.15;
    CHECK(std::abs(m.speed(t) - m.speed(t - millis(1))) <= 0.3e-3 + 1e-15);
  }
  CHECK(stopped);
  CHECK(full);
}

TEST_CASE("a curved section turns the panel about the vertical axis on a circle") {
  SpeedProfile s;
  s.min_speed = s.max_speed = 0.02;
  LinePath path;
  path.curve_start_m = 0.2;
  path.curvature = 0.5;  // radius 2 m, towards the cameras
  const LineMotion m(s, path, seconds(40));
  // Straight for the first 10 s.
  CHECK(m.heading(seconds(10)) == 0.0);
  const Eigen::Isometry3d straight = m.X_Line_Panel(seconds(5));
  CHECK(straight.translation().isApprox(Eigen::Vector3d(0.1, 0, 0), 1e-9));
  // Then an arc: centre at (0.2, 0, 2); heading = k (s - 0.2).
  for (Nanos t : {seconds(15), seconds(25), seconds(40)}) {
    const double sd = m.distance(t);
    const Eigen::Isometry3d X = m.X_Line_Panel(t);
    CHECK((X.translation() - Eigen::Vector3d(0.2, 0, 2.0)).norm() == Approx(2.0).epsilon(1e-9));
    CHECK(m.heading(t) == Approx(0.5 * (sd - 0.2)).epsilon(1e-12));
    // The panel's x axis is the path's tangent; y stays vertical.
    const double th = m.heading(t);
    CHECK(X.linear().col(0).isApprox(Eigen::Vector3d(std::cos(th), 0, std::sin(th)), 1e-12));
    CHECK(X.linear().col(1).isApprox(Eigen::Vector3d::UnitY(), 1e-12));
  }
}

namespace {

// A nozzle `standoff` in front of panel point (x, y) (flat panel), looking straight at it.
Spray nozzle_over(const Eigen::Isometry3d& X_CamR_Panel, double x, double y, double standoff, Nanos t = 0) {
  Eigen::Isometry3d X_Panel_Nozzle = Eigen::Isometry3d::Identity();
  X_Panel_Nozzle.translation() = Eigen::Vector3d(x, y, standoff);
  return Spray{t, X_CamR_Panel * X_Panel_Nozzle};
}

}  // namespace

TEST_CASE("scoring: hit, miss, false spray, spray through a hole, skipped defect") {
  markcell::test::SheetSpec flat = markcell::test::door_sheet();
  flat.bend_x = 0;
  const markcell::rig::Panel door = markcell::test::sheet_panel("door", flat, {});
  const Eigen::Isometry3d X = facing(-0.2, 0.0, 3.1);
  const auto still = [&](Nanos) { return X; };
  const std::vector<TrueDefect> defects = {{1, {0.1, -0.1, 0}}, {2, {-0.2, -0.25, 0}}, {3, {0.4, 0.25, 0}}};
  const std::vector<Spray> sprays = {
      nozzle_over(X, 0.105, -0.1, 0.2),      // 5 mm from defect 1: hit
      nozzle_over(X, -0.2, -0.235, 0.2),     // 15 mm from defect 2: miss, a false spray
      nozzle_over(X, 0.0, 0.2, 0.2),         // into the window opening: not on the panel
  };
  const Score s = score_sprays(door, still, defects, sprays, {{3, "beyond the arm's reach before the panel leaves"}}, 0.010);
  REQUIRE(s.sprays.size() == 3);
  CHECK(s.sprays[0].hit);
  CHECK(s.sprays[0].nearest_defect == 1);
  CHECK(s.sprays[0].distance == Approx(0.005).epsilon(1e-9));
  CHECK(s.sprays[0].p_CamR.isApprox(X * Eigen::Vector3d(0.105, -0.1, 0), 1e-12));
  CHECK_FALSE(s.sprays[1].hit);
  CHECK(s.sprays[1].distance == Approx(0.015).epsilon(1e-9));
  CHECK_FALSE(s.sprays[2].on_panel);
  CHECK(s.false_sprays == 2);
  CHECK(s.planned == 2);
  CHECK(s.marked == 1);
  CHECK(s.skipped == 1);
  CHECK(s.defects[2].skipped_reason == "beyond the arm's reach before the panel leaves");
  CHECK(s.error_max == Approx(0.005).epsilon(1e-9));
  CHECK(s.error_rms == Approx(0.005).epsilon(1e-9));
}

TEST_CASE("scoring on the aim alone: the axis's distance from each centre, whatever surface there is or is not") {
  const Eigen::Isometry3d X = facing(-0.2, 0.0, 3.1);
  const auto still = [&](Nanos) { return X; };
  // Defect 1 sits 30 mm proud of the plane the nozzles stand over (a bulged skin): on the
  // aim, a nozzle right above it hits it exactly, wherever the surface is.
  const std::vector<TrueDefect> defects = {{1, {0.1, -0.1, 0.03}}, {2, {-0.2, -0.25, 0}}};
  Spray tilted = nozzle_over(X, 0.0, 0.2, 0.2);  // turned -30 deg about x: its axis misses both
  tilted.X_CamR_Nozzle = tilted.X_CamR_Nozzle * Eigen::AngleAxisd(-M_PI / 6, Eigen::Vector3d::UnitX());
  const std::vector<Spray> sprays = {
      nozzle_over(X, 0.1, -0.1, 0.2),     // on defect 1's axis
      nozzle_over(X, -0.2, -0.243, 0.2),  // 7 mm beside defect 2: hit within 10 mm
      nozzle_over(X, 0.0, 0.2, 0.2),      // over the window opening: no panel, but scored on the aim
      nozzle_over(X, 0.1, -0.1, -0.2),    // behind defect 1 (it is behind the nozzle): no hit
      tilted,
  };
  const Score s = score_sprays_by_aim(still, defects, sprays, {}, 0.010);
  CHECK(s.scored_on == ScoredOn::kAim);
  REQUIRE(s.sprays.size() == 5);
  CHECK(s.sprays[0].hit);
  CHECK(s.sprays[0].distance == Approx(0.0).margin(1e-12));
  CHECK(s.sprays[0].p_CamR.isApprox(X * Eigen::Vector3d(0.1, -0.1, 0.03), 1e-12));  // the axis's point nearest the centre
  CHECK(s.sprays[1].hit);
  CHECK(s.sprays[1].nearest_defect == 2);
  CHECK(s.sprays[1].distance == Approx(0.007).epsilon(1e-9));
  CHECK_FALSE(s.sprays[2].hit);
  CHECK_FALSE(s.sprays[2].on_panel);
  // Over the window, straight down: defect 1 is sqrt(0.1^2 + 0.3^2) from its axis.
  CHECK(s.sprays[2].distance == Approx(std::hypot(0.1, 0.3)).epsilon(1e-9));
  CHECK_FALSE(s.sprays[3].hit);
  // Tilted: the axis from (0, 0.2, 0.2) along -z turned by -30 deg about x, i.e. towards
  // (0, -sin 30, -cos 30), both centres in front; their distances from it in closed form.
  const Eigen::Vector3d o(0.0, 0.2, 0.2), d(0.0, -0.5, -std::sqrt(3.0) / 2), c2(-0.2, -0.25, 0.0), c1(0.1, -0.1, 0.03);
  const auto from_axis = [&](const Eigen::Vector3d& c) { return ((c - o) - (c - o).dot(d) * d).norm(); };
  CHECK(s.sprays[4].distance == Approx(std::min(from_axis(c1), from_axis(c2))).epsilon(1e-9));
  CHECK_FALSE(s.sprays[4].hit);
  CHECK(s.marked == 2);
  CHECK(s.false_sprays == 3);
  CHECK(s.error_max == Approx(0.007).epsilon(1e-9));
}

TEST_CASE("scoring: the panel where it is at the moment of spraying, tilted nozzles, bent panels") {
  // The shipped door: its mesh of the sheet z = -0.12 x^2 on a 10 mm grid.
  const markcell::rig::Panel door = markcell::test::shipped_panel("door");
  SpeedProfile speed;
  speed.min_speed = speed.max_speed = 0.012;  // 12 mm per second
  LinePath path;
  path.X_CamR_Line = facing(-0.2, 0.0, 3.1);
  const LineMotion motion(speed, path, seconds(10));
  const auto at = [&](Nanos t) { return motion.X_CamR_Panel(t); };
  const double z03 = markcell::test::door_sheet().z(0.3, 0.0);
  const std::vector<TrueDefect> defects = {{7, {0.3, 0.0, z03}}};
  // Aimed where the defect was at t = 0, sprayed at t = 1 s: the panel has moved 12 mm.
  Spray late = nozzle_over(at(0), 0.3, 0.0, 0.2, seconds(1));
  // Aimed where it is at t = 1 s.
  Spray on_time = nozzle_over(at(seconds(1)), 0.3, 0.0, 0.2, seconds(1));
  // Tilted 20 degrees about the panel's y axis from straight above (0.3 - 0.2 tan 20deg, 0):
  // lands at x = 0.3 on the bent surface only approximately; compute it in closed form.
  Eigen::Isometry3d X_Panel_Tilted = Eigen::Isometry3d::Identity();
  X_Panel_Tilted.linear() = Eigen::AngleAxisd(-20.0 * M_PI / 180, Eigen::Vector3d::UnitY()).toRotationMatrix();
  X_Panel_Tilted.translation() = Eigen::Vector3d(0.3 - 0.2 * std::tan(20.0 * M_PI / 180), 0.0, 0.2);
  const Spray tilted{seconds(1), at(seconds(1)) * X_Panel_Tilted};
  const Score s = score_sprays(door, at, defects, {late, on_time, tilted}, {}, 0.010);
  // It lands 12 mm short along x on the bent sheet: (0.288, 0, -k 0.288^2).
  // (The mesh's chord error below 3 um: 0.12 * 0.01^2 / 4.)
  CHECK(s.sprays[0].distance == Approx(std::hypot(0.012, 0.12 * (0.3 * 0.3 - 0.288 * 0.288))).margin(5e-6));
  CHECK_FALSE(s.sprays[0].hit);
  CHECK(s.sprays[1].distance < 5e-6);  // straight down onto the bent surface: on it, to the chord
  CHECK(s.sprays[1].hit);
  // Closed form for the tilted axis: from o = (x0, 0, 0.2) along d = (sin a, 0, -cos a),
  // meet z = -k x^2.
  const double a = 20.0 * M_PI / 180, k = 0.12, x0 = 0.3 - 0.2 * std::tan(a);
  const double A = k * std::sin(a) * std::sin(a), B = 2 * k * x0 * std::sin(a) - std::cos(a), C = k * x0 * x0 + 0.2;
  const double t = (-B - std::sqrt(B * B - 4 * A * C)) / (2 * A);
  const Eigen::Vector3d expected(x0 + t * std::sin(a), 0.0, 0.2 - t * std::cos(a));
  CHECK(s.sprays[2].distance == Approx((expected - defects[0].p_Panel).norm()).margin(5e-6));
  CHECK(s.marked == 1);
  CHECK(s.false_sprays == 1);
}

#include "markcell/rig/inspection.hpp"
#include "test_files.hpp"

TEST_CASE("the inspection station's defect clusters: points of each ding on the surface, pressed in, in CamL_SL") {
  // (The macro-features are measured by the station itself on the scanner's rendered
  // views: test_inspection_station.)
  const markcell::rig::Panel door = markcell::test::shipped_panel("door");
  Eigen::Isometry3d X_SL_Panel = facing(0.15, 0.02, 2.0);
  X_SL_Panel.linear() = X_SL_Panel.linear() * Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const std::vector<DefectSpec> defects = {{1, 0.1, -0.1, 0.012}, {2, -0.25, -0.2, 0.025}, {3, 0.35, 0.25, 0.006}};
  InspectionNoise none;
  none.depth_sigma = 0;
  const auto exact = sample_defect_points(door, defects, X_SL_Panel, none, 1);
  REQUIRE(exact.size() == 3);
  for (std::size_t d = 0; d < 3; ++d) {
    CHECK(exact[d].id == defects[d].id);
    REQUIRE(exact[d].points_SL.size() == 60);
    double widest = 0;
    for (const auto& p_SL : exact[d].points_SL) {
      const Eigen::Vector3d p = X_SL_Panel.inverse() * p_SL;
      widest = std::max(widest, std::hypot(p.x() - defects[d].x, p.y() - defects[d].y));
      CHECK(std::hypot(p.x() - defects[d].x, p.y() - defects[d].y) <= defects[d].radius + 1e-6);  // within the ding (plus its slope)
      const double below = markcell::test::door_sheet().z(p.x(), p.y()) - p.z();  // pressed in, never out
      CHECK(below >= -5e-6);  // the mesh's chord below the sheet
      CHECK(below <= none.ding_depth + 1e-6);
    }
    CHECK(widest > 0.7 * defects[d].radius);  // each ding as wide as its own radius
  }
  // The depth noise moves points along the normal only: the same seed, the same draws.
  const auto noisy = sample_defect_points(door, defects, X_SL_Panel, InspectionNoise{}, 1);
  double rms = 0;
  int n = 0;
  for (std::size_t d = 0; d < 3; ++d)
    for (std::size_t i = 0; i < noisy[d].points_SL.size(); ++i, ++n) rms += (noisy[d].points_SL[i] - exact[d].points_SL[i]).squaredNorm();
  rms = std::sqrt(rms / n);
  CHECK(rms > 0.5 * InspectionNoise{}.depth_sigma);
  CHECK(rms < 1.5 * InspectionNoise{}.depth_sigma);
}

#include "markcell/rig/scenario.hpp"
#include "markcell/vision/recording.hpp"

namespace {
const std::string& shipped_scenarios() {
  static const std::string folder = markcell::test::source_path("config/scenarios");
  return folder;
}
Scenario shipped_scenario(const std::string& name, std::uint64_t seed) {
  return find_scenario(name, shipped_scenarios(), seed);
}
}  // namespace

TEST_CASE("scenarios: every shipped file loads, unknown names are listed, drops are deterministic") {
  const std::vector<std::string> names = scenario_names(shipped_scenarios());
  CHECK(names == std::vector<std::string>{"calibration-board", "frame-drops", "line-fast", "nine-defects",
                                          "occlusion-person", "paper-curved", "paper-door", "paper-fender"});
  for (const auto& name : names) {
    const Scenario s = shipped_scenario(name, 3);
    CHECK(s.name == name);
    if (s.board_only) {  // calibration-board: a camera pose to find, no panel
      CHECK(s.defects.empty());
      CHECK(s.X_CamRnominal_CamR.translation().norm() > 0.001);
      continue;
    }
    CHECK_FALSE(s.defects.empty());
    const markcell::rig::Panel panel = markcell::test::shipped_panel(s.panel_type);
    for (const auto& d : s.defects) CHECK(panel.solid(d.x, d.y));
  }
  CHECK(shipped_scenario("nine-defects", 1).defects.size() == 9);
  CHECK(shipped_scenario("paper-fender", 1).defects.size() == 4);
  CHECK_THROWS_WITH(shipped_scenario("paper-dor", 1),
                    "unknown scenario 'paper-dor': no " + shipped_scenarios() +
                        "/paper-dor.yaml (known: calibration-board, frame-drops, line-fast, nine-defects, "
                        "occlusion-person, paper-curved, paper-door, paper-fender)");
  const Scenario drops = shipped_scenario("frame-drops", 11);
  int dropped = 0;
  for (std::uint64_t i = 0; i < 20'000; ++i) dropped += frame_dropped(drops, i) ? 1 : 0;
  CHECK(dropped > 20'000 * 0.085 + 15);
  CHECK(dropped < 20'000 * 0.115 + 15);
  for (std::uint64_t i = 45; i < 60; ++i) CHECK(frame_dropped(drops, i));
  CHECK_FALSE(frame_dropped(shipped_scenario("paper-door", 11), 45));
}

TEST_CASE("a scenario file with an error is refused naming its file, line and key") {
  markcell::test::TempDir dir;
  const std::string door = markcell::test::read_file(shipped_scenarios() + "/paper-door.yaml");
  // Each case: the shipped door with one line replaced, the message expected.
  const auto edited = [&](const std::string& from, const std::string& to) {
    const std::size_t at = door.find(from);
    REQUIRE(at != std::string::npos);
    std::string text = door;
    text.replace(at, from.size(), to);
    return dir.write("edited.yaml", text);
  };
  const auto line_of = [&](const std::string& what) {
    const std::size_t at = door.find(what);
    REQUIRE(at != std::string::npos);
    return std::to_string(1 + std::count(door.begin(), door.begin() + static_cast<std::ptrdiff_t>(at), '\n'));
  };
  const std::string file = (dir.path() / "edited.yaml").string();
  SECTION("an unknown key") {
    const std::string line = line_of("exposure_drift:");
    CHECK_THROWS_WITH(load_scenario(edited("exposure_drift:", "exposure_drfit:")),
                      file + ":" + line + ": exposure_drfit: unknown key (known: kind, panel_type, seed, duration_s, "
                                          "fps, speed, line, defects, people, frame_drops, exposure_drift, inspection, "
                                          "plc_script)");
  }
  SECTION("a rotation that is not one") {
    const std::string line = line_of("rotation: [[1, 0, 0]");
    CHECK_THROWS_WITH(load_scenario(edited("[0, -1, 0], [0, 0, -1]]", "[0, -1, 0], [0, 0, 1]]")),
                      Catch::StartsWith(file + ":" + line + ": line.X_CamR_Line.rotation: is not a rotation"));
  }
  SECTION("a defect id used twice") {
    const std::string line = line_of("{id: 2,");
    CHECK_THROWS_WITH(load_scenario(edited("{id: 2,", "{id: 1,")),
                      file + ":" + line + ": defects[1].id: id 1 is used twice");
  }
  SECTION("a number out of its range") {
    const std::string line = line_of("fps: 30");
    CHECK_THROWS_WITH(load_scenario(edited("fps: 30", "fps: -30")),
                      Catch::StartsWith(file + ":" + line + ": fps: -30.000000 is outside ["));
  }
  SECTION("a PLC script outside the scenario's folder") {
    const std::string line = line_of("exposure_drift:");
    CHECK_THROWS_WITH(load_scenario(edited("exposure_drift:", "plc_script: ../../etc/passwd\nexposure_drift:")),
                      file + ":" + line + ": plc_script: '../../etc/passwd' leaves the scenario file's folder (..)");
  }
  SECTION("not YAML") {
    CHECK_THROWS_WITH(load_scenario(edited("defects:", "defects: [")), Catch::StartsWith(file + ":"));
  }
  SECTION("a FIFO is not read") {
    const std::string fifo = (dir.path() / "fifo.yaml").string();
    REQUIRE(::mkfifo(fifo.c_str(), 0600) == 0);
    CHECK_THROWS_WITH(load_scenario(fifo), fifo + ": a FIFO, not read (a scenario file must be a regular file)");
  }
  SECTION("a file the shipped folder does not have is found by its path, with its PLC script beside it") {
    dir.write("go.plc", "0.5 ready 1\n");
    const std::string written = edited("exposure_drift:", "plc_script: go.plc\nexposure_drift:");
    const Scenario s = find_scenario(written, shipped_scenarios(), 4);
    CHECK(s.name == "edited");
    CHECK(s.seed == 4);
    CHECK(s.plc_script == (dir.path() / "go.plc").string());
    CHECK(s.defects.size() == 3);
    CHECK(s.defects[2].radius == 0.012);
  }
}

TEST_CASE("a scenario generates the same recording twice, with its truth and the inspection record") {
  namespace v = markcell::vision;
  const auto marking = v::load_stereo_calibration(markcell::test::source_path("config/calibration/marking_stereo.yaml"));
  const auto scanner = v::load_stereo_calibration(markcell::test::source_path("config/calibration/inspection_stereo.yaml"));
  markcell::test::TempDir dir;
  const Scenario s = shipped_scenario("paper-door", 21);
  GenerateOptions o;
  o.max_duration = seconds(1);
  o.fps = 5;
  const std::string a = (dir.path() / "a").string(), b = (dir.path() / "b").string();
  const rig::Panel door = test::shipped_panel("door");
  REQUIRE(generate_recording(s, door, a, marking, scanner, rig::RenderSettings{}, o) == 6);
  REQUIRE(generate_recording(s, door, b, marking, scanner, rig::RenderSettings{}, o) == 6);
  const v::Recording ra = v::Recording::open(a), rb = v::Recording::open(b);
  REQUIRE(ra.size() == 6);
  CHECK(ra.manifest().scenario == "paper-door");
  CHECK(ra.manifest().seed == std::optional<std::uint64_t>(21));
  // The panel goes with the recording: its mesh, byte for byte, and its MFs' true places.
  CHECK(ra.manifest().panel_mesh == "panel.ply");
  CHECK(markcell::test::read_file(a + "/panel.ply") == markcell::test::read_file(door.mesh_file));
  REQUIRE(ra.manifest().macro_features_Panel.size() == 10);
  for (std::size_t i = 0; i < 10; ++i) CHECK((ra.manifest().macro_features_Panel[i] - door.macro_features[i]).norm() < 1e-15);
  const LineMotion motion(s.speed, s.path, s.duration);
  for (std::size_t i = 0; i < 6; ++i) {
    const auto fa = ra.read(i), fb = rb.read(i);
    REQUIRE_FALSE(fa.dropped);
    CHECK(fa.time == static_cast<Nanos>(i) * 200'000'000LL);
    CHECK(cv::norm(fa.left, fb.left, cv::NORM_INF) == 0);
    CHECK(cv::norm(fa.right, fb.right, cv::NORM_INF) == 0);
    CHECK((ra.truth()[i].X_CamR_Panel.matrix() - motion.X_CamR_Panel(fa.time).matrix()).norm() < 1e-9);
  }
  CHECK(markcell::test::read_file(a + "/truth.csv") == markcell::test::read_file(b + "/truth.csv"));
  CHECK(markcell::test::read_file(a + "/inspection.yaml") == markcell::test::read_file(b + "/inspection.yaml"));
  REQUIRE(ra.defects().size() == 3);
  CHECK(ra.defects()[0].p_Panel.isApprox(door.surface_point(0.12, -0.12), 1e-12));
  CHECK(v::load_stereo_calibration(ra.calibration_path()).baseline() == Approx(0.445));
  // The first frame: the door's macro-features in view, where the truth puts them.
  const rig::StereoRenderer r(marking, rig::RenderSettings{});
  int visible = 0;
  for (const auto& mf : door.macro_features) {
    const Eigen::Vector2d px = r.project(1, ra.truth()[0].X_CamR_Panel * mf);
    visible += px.x() >= 0 && px.x() < 640 && px.y() >= 0 && px.y() < 480;
  }
  CHECK(visible >= 8);
}

#include "alloc_guard.hpp"
#include "markcell/rig/arm_view.hpp"
#include "markcell/vision/calibration_io.hpp"

TEST_CASE("the simulated arm's links: equal links meet at an elbow above the reach, the tool along the nozzle's +Z") {
  using markcell::rig::ArmShape;
  const ArmShape shape;
  const Eigen::Isometry3d identity = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d X_Base_Nozzle = Eigen::Isometry3d::Identity();
  X_Base_Nozzle.linear() = Eigen::AngleAxisd(-M_PI / 2, Eigen::Vector3d::UnitY()).toRotationMatrix();  // +Z towards -X
  X_Base_Nozzle.translation() = Eigen::Vector3d(0.9, 0.3, 0.8);
  const auto c = markcell::rig::arm_occluders(shape, identity, X_Base_Nozzle);
  const Eigen::Vector3d wrist = X_Base_Nozzle.translation() + shape.tool * X_Base_Nozzle.linear().col(2);
  CHECK((c[2].b_CamR - X_Base_Nozzle.translation()).norm() < 1e-12);
  CHECK((c[2].a_CamR - wrist).norm() < 1e-12);
  CHECK((wrist - Eigen::Vector3d(0.65, 0.3, 0.8)).norm() < 1e-12);
  CHECK((c[0].a_CamR - shape.shoulder_Base).norm() < 1e-12);
  const Eigen::Vector3d elbow = c[0].b_CamR;
  CHECK((c[1].a_CamR - elbow).norm() < 1e-12);
  CHECK((elbow - shape.shoulder_Base).norm() == Approx(shape.upper_arm).epsilon(1e-9));
  CHECK((wrist - elbow).norm() == Approx(shape.forearm).epsilon(1e-9));
  // Bent upwards: above the straight line from shoulder to wrist.
  CHECK(elbow.z() > (shape.shoulder_Base + (wrist - shape.shoulder_Base) * 0.5).z());
  // Out of reach: stretched straight, the elbow halfway.
  X_Base_Nozzle.translation() = Eigen::Vector3d(2.5, 0, 0.45);
  const auto far = markcell::rig::arm_occluders(shape, identity, X_Base_Nozzle);
  CHECK((far[0].b_CamR - (shape.shoulder_Base + far[1].b_CamR) / 2).norm() < 1e-12);
}

TEST_CASE("painting capsules over a rendered pair matches ray-casting them with the panel, without heap use") {
  const auto cal = markcell::vision::load_stereo_calibration(markcell::test::source_path("config/calibration/marking_stereo.yaml"));
  markcell::rig::RenderSettings settings;
  settings.noise_sigma = 0;  // the two paths must see the same pixels
  settings.blur_sigma_px = 0;
  const markcell::rig::StereoRenderer renderer(cal, settings);
  const auto panel = markcell::test::shipped_panel("door");
  Eigen::Isometry3d X_CamR_Panel = Eigen::Isometry3d::Identity();
  X_CamR_Panel.translation() = Eigen::Vector3d(-0.4, -0.3, 3.1);
  const std::vector<markcell::rig::Occluder> occ{  // an upper arm and a tool that do not touch
      {Eigen::Vector3d(0.3, 0.9, 2.5), Eigen::Vector3d(0.0, 0.1, 2.7), 0.06, 70},
      {Eigen::Vector3d(-0.1, -0.1, 2.8), Eigen::Vector3d(-0.35, -0.2, 2.9), 0.03, 35}};
  cv::Mat cast_l, cast_r, plain_l, plain_r;
  renderer.render(panel, X_CamR_Panel, 1.0, 1, occ, cast_l, cast_r);
  renderer.render(panel, X_CamR_Panel, 1.0, 1, {}, plain_l, plain_r);
  std::size_t allocations = 0;
  {
    markcell::test::AllocationGuard guard;
    renderer.paint_occluders(occ.data(), occ.size(), plain_l, plain_r);
    allocations = guard.allocations();
  }
  CHECK(allocations == 0);
  for (const auto& [cast, painted] : {std::pair{&cast_l, &plain_l}, std::pair{&cast_r, &plain_r}}) {
    cv::Mat diff;
    cv::absdiff(*cast, *painted, diff);
    // The same capsules, the same sample rays: equal up to the rounding of a blend, except
    // where a capsule's edge crosses an edge of the panel inside one pixel (the painter
    // blends the pixel's mean, the ray-cast the samples the capsule leaves): a handful.
    const int off = cv::countNonZero(diff > 1);
    INFO("pixels off by more than 1 grey level: " << off);
    CHECK(off <= 20);
    CHECK(cv::countNonZero(*cast == 70) > 1500);  // the arm really is in the view
    CHECK(cv::countNonZero(*cast == 35) > 200);
    CHECK(std::abs(cv::countNonZero(*cast == 70) - cv::countNonZero(*painted == 70)) <= 5);
  }
}
