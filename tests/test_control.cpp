// The marking side of control against closed-form answers: the inter-calibration and
// its Table I metrics, the tool pose on known planes, and both predictors on known
// motions, without allocating.
#include <algorithm>
#include <catch2/catch.hpp>
#include <cmath>
#include <random>
#include <vector>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include "draw.hpp"
#include "alloc_guard.hpp"
#include "markcell/control/intercalibration.hpp"
#include "markcell/control/planner.hpp"
#include "markcell/control/predictor.hpp"
#include "markcell/control/tool_pose.hpp"

using namespace markcell;
using namespace markcell::control;

namespace {
Eigen::Isometry3d pose(double rx, double ry, double rz, const Eigen::Vector3d& t) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = (Eigen::AngleAxisd(rz, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(ry, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(rx, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  X.translation() = t;
  return X;
}
}  // namespace

TEST_CASE("inter-calibration: recovers X_P_SL, reports Table I metrics per axis, drops an outlier") {
  const Eigen::Isometry3d X_P_SL = pose(0.1, -0.3, 0.05, {-0.4, 0.1, 1.2});
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  std::normal_distribution<double> noise(0.0, 0.001);
  std::vector<Eigen::Vector3d> sl(10), p(10), noise_P(10);
  bool known[10];
  for (int i = 0; i < 10; ++i) {
    sl[static_cast<std::size_t>(i)] = {u(rng), u(rng), 2.0 + 0.1 * u(rng)};
    noise_P[static_cast<std::size_t>(i)] = {noise(rng), noise(rng), noise(rng)};
    p[static_cast<std::size_t>(i)] = X_P_SL * sl[static_cast<std::size_t>(i)] + noise_P[static_cast<std::size_t>(i)];
    known[i] = i != 3;  // one MF the marking station did not find
  }
  p[7] += Eigen::Vector3d(0.05, 0, 0);  // a wrong correspondence
  IntercalibrationLimits limits;
  limits.inlier_threshold = 0.01;
  test::AllocationGuard guard;
  const Intercalibration r = intercalibrate(sl, p, std::span(known, 10), limits);
  CHECK(guard.allocations() == 0);
  REQUIRE(r.status == IntercalibrationStatus::kOk);
  CHECK(r.paired == 9);
  CHECK(r.inliers == 8);
  // On the panel (2 m from SL's origin, where a rotation error is leveraged) the fitted
  // transform is within the noise of the true one.
  for (const auto& q : sl) CHECK((r.X_P_SL * q - X_P_SL * q).norm() < 0.002);
  // The metrics are those of the residuals of the fitted transform, axis by axis.
  Eigen::Vector3d max_abs = Eigen::Vector3d::Zero(), sq = Eigen::Vector3d::Zero();
  for (int i : {0, 1, 2, 4, 5, 6, 8, 9}) {
    const Eigen::Vector3d e = r.X_P_SL * sl[static_cast<std::size_t>(i)] - p[static_cast<std::size_t>(i)];
    max_abs = max_abs.cwiseMax(e.cwiseAbs());
    sq += e.cwiseAbs2();
  }
  CHECK((r.max_abs - max_abs).norm() < 1e-12);
  CHECK((r.rms - (sq / 8).cwiseSqrt()).norm() < 1e-12);
  CHECK(r.max_abs.maxCoeff() < 0.004);

  limits.max_abs_error = 0.0005;
  CHECK(intercalibrate(sl, p, std::span(known, 10), limits).status == IntercalibrationStatus::kAboveLimit);
  bool few[10] = {true, true, true, false, false, false, false, false, false, false};
  CHECK(intercalibrate(sl, p, std::span(few, 10), limits).status == IntercalibrationStatus::kTooFewPoints);
}

TEST_CASE("inter-calibration: a defect's placement uncertainty from the MFs' layout matches the scatter of repeated fits") {
  // Five MFs in a 12 cm band (a panel entering the view) and a defect 0.6 m beyond them:
  // the fit's rotation error is levered out to the defect. 400 fits with fresh 1 mm noise
  // on the marking side give the defect's placement scatter (the reference); each fit's
  // own placement_sigma must agree with it, and with ten MFs spread over the panel the
  // same defect is placed several times more surely.
  const Eigen::Isometry3d X_P_SL = pose(0.05, -0.2, 0.1, {0.3, -0.1, 0.4});
  const double sigma = 0.001;
  std::mt19937 rng(11);
  std::normal_distribution<double> noise(0.0, sigma);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  auto scatter = [&](const std::vector<Eigen::Vector3d>& sl, const Eigen::Vector3d& defect_SL, double& mean_sigma) {
    IntercalibrationLimits limits;
    limits.point_sigma = 0.0001;  // below the noise: the residuals decide
    bool known[kMaxIntercalibrationPoints];
    std::fill(std::begin(known), std::end(known), true);
    const Eigen::Vector3d truth = X_P_SL * defect_SL;
    Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
    mean_sigma = 0;
    const int trials = 400;
    for (int t = 0; t < trials; ++t) {
      std::vector<Eigen::Vector3d> p(sl.size());
      for (std::size_t i = 0; i < sl.size(); ++i) {
        const double nx = noise(rng), ny = noise(rng), nz = noise(rng);
        p[i] = X_P_SL * sl[i] + Eigen::Vector3d(nx, ny, nz);
      }
      const Intercalibration r = intercalibrate(sl, p, std::span(known, sl.size()), limits);
      REQUIRE(r.status == IntercalibrationStatus::kOk);
      const Eigen::Vector3d e = r.X_P_SL * defect_SL - truth;
      cov += e * e.transpose() / trials;
      mean_sigma += r.placement_sigma(r.X_P_SL * defect_SL) / trials;
    }
    return std::sqrt(Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(cov).eigenvalues().maxCoeff());
  };
  std::vector<Eigen::Vector3d> band;
  for (int i = 0; i < 5; ++i) {
    const double a = u(rng), b = u(rng), c = u(rng);
    band.push_back({0.5 + 0.06 * a, 0.15 * b, 2.0 + 0.01 * c});
  }
  const Eigen::Vector3d defect(-0.1, 0.05, 2.0);
  double predicted_band = 0;
  const double observed_band = scatter(band, defect, predicted_band);
  INFO("band: observed " << observed_band * 1000 << " mm, predicted " << predicted_band * 1000 << " mm");
  CHECK(predicted_band > 0.75 * observed_band);
  CHECK(predicted_band < 1.33 * observed_band);
  CHECK(observed_band > 3 * sigma);  // the lever: well above one MF's noise

  std::vector<Eigen::Vector3d> spread;
  for (int i = 0; i < 10; ++i) {
    const double a = u(rng), b = u(rng), c = u(rng);
    spread.push_back({0.5 * a, 0.3 * b, 2.0 + 0.01 * c});
  }
  double predicted_spread = 0;
  const double observed_spread = scatter(spread, defect, predicted_spread);
  INFO("spread: observed " << observed_spread * 1000 << " mm, predicted " << predicted_spread * 1000 << " mm");
  CHECK(predicted_spread > 0.75 * observed_spread);
  CHECK(predicted_spread < 1.33 * observed_spread);
  CHECK(predicted_spread * 3 < predicted_band);
}

TEST_CASE("tool pose: plane normal towards the cameras, centre, contact point, stand-off: degenerate clusters rejected") {
  // A plane through c with normal n (tilted, facing the camera at the origin), a ding in it.
  const Eigen::Vector3d n = Eigen::Vector3d(0.2, -0.1, -1.0).normalized();
  const Eigen::Vector3d c(0.3, -0.2, 3.0);
  const Eigen::Vector3d a = n.unitOrthogonal(), b = n.cross(a);
  std::vector<Eigen::Vector3d> pts;
  for (int i = -4; i <= 4; ++i)
    for (int j = -4; j <= 4; ++j) {
      const double s = i * 0.003, t = j * 0.003;
      const double dent = 0.0004 * std::exp(-(s * s + t * t) / (2 * 0.006 * 0.006));
      pts.push_back(c + s * a + t * b - dent * n);
    }
  const DefectToolPose r = tool_pose(pts, 0.2);
  REQUIRE(r.status == ToolPoseStatus::kOk);
  CHECK(r.normal.dot(n) > 0.9999);  // oriented out of the surface, towards the cameras
  CHECK((r.centre - c).norm() < 0.0005);
  // The contact point is the point with the smallest depth.
  double zmin = 1e9;
  for (const auto& p : pts) zmin = std::min(zmin, p.z());
  CHECK(r.contact.z() == zmin);
  // O_V is right-handed with Z = normal; the nozzle sits on Z, at least the stand-off from
  // every point along it, and looks back at the centre.
  CHECK((r.X_P_Tool.linear().col(2) - r.normal).norm() < 1e-12);
  CHECK(std::abs(r.X_P_Tool.linear().determinant() - 1) < 1e-12);
  const Eigen::Vector3d nozzle = r.X_P_Nozzle.translation();
  CHECK(((nozzle - r.centre).normalized() - r.normal).norm() < 1e-9);
  for (const auto& p : pts) CHECK((nozzle - p).dot(r.normal) >= 0.2 - 1e-12);
  CHECK((nozzle - r.centre).norm() < 0.2 + 0.0006);

  std::vector<Eigen::Vector3d> line;
  for (int i = 0; i < 10; ++i) line.push_back(c + i * 0.002 * a);
  CHECK(tool_pose(line, 0.2).status == ToolPoseStatus::kCollinear);
  CHECK(tool_pose(std::span(pts.data(), 3), 0.2).status == ToolPoseStatus::kTooFewPoints);
  std::vector<Eigen::Vector3d> edge_on;  // a plane containing the line of sight
  for (int i = -3; i <= 3; ++i)
    for (int j = -3; j <= 3; ++j) edge_on.push_back(Eigen::Vector3d(0, 0, 3) + i * 0.003 * Eigen::Vector3d::UnitY() + j * 0.003 * Eigen::Vector3d::UnitZ());
  CHECK(tool_pose(edge_on, 0.2).status == ToolPoseStatus::kFacingAway);
}

TEST_CASE("two-frame predictor: applying the last motion twice, as the paper") {
  PredictorParams params;
  params.kind = PredictorKind::kTwoFrame;
  PosePredictor predictor(params);
  const Eigen::Vector3d anchor(0.1, 0.0, 3.1);
  predictor.reset(anchor);
  const Eigen::Isometry3d X1 = pose(0, 0.01, 0, {0.02, 0, 0});
  const Eigen::Isometry3d M = pose(0, 0.004, 0, {0.012, 0.001, -0.002});  // the motion between frames, in CamR
  const Eigen::Isometry3d X2 = M * X1;
  predictor.update(seconds(10), X1);
  CHECK_FALSE(predictor.ready());
  predictor.update(seconds(12), X2);
  REQUIRE(predictor.ready());
  test::AllocationGuard guard;
  const Eigen::Isometry3d X = predictor.predict(seconds(16));  // two intervals on
  CHECK(guard.allocations() == 0);
  // The anchor moves by the anchor's displacement twice, the rotation turns twice.
  const Eigen::Vector3d expected_anchor = X2 * anchor + 2 * (X2 * anchor - X1 * anchor);
  CHECK((X * anchor - expected_anchor).norm() < 1e-12);
  CHECK(Eigen::AngleAxisd(X.linear().transpose() * (M.linear() * M.linear() * X2.linear())).angle() < 1e-12);
}

TEST_CASE("Kalman predictor: constant speed with a turn, through noise, predicts half a second ahead within a millimetre") {
  // Over many noise realisations, not one: a single run's error is one draw of a spread
  // about as wide as the bound, and which draw a seed gives is the generator's business.
  const Eigen::Vector3d anchor(-0.2, 0.0, 3.1);
  const Eigen::Vector3d q = anchor + Eigen::Vector3d(0.4, 0.1, 0);  // 40 cm off the anchor
  auto truth = [&](double t) { return pose(0, 0.01 * t, 0, {0.015 * t, 0, 0.002 * t}); };
  constexpr int kRuns = 100;
  Eigen::Vector3d sum_sq = Eigen::Vector3d::Zero();
  double sum_sq_q = 0;
  std::size_t allocations = 0;
  for (int run = 0; run < kRuns; ++run) {
    PosePredictor predictor(PredictorParams{});
    predictor.reset(anchor);
    std::mt19937 rng(static_cast<unsigned>(9 + run));
    std::normal_distribution<double> lat(0, 0.0004), dep(0, 0.002), rot(0, 0.001);
    for (int k = 0; k <= 300; ++k) {  // 10 s at 30 Hz
      const double t = k / 30.0;
      Eigen::Isometry3d m = truth(t);
      m.linear() = (Eigen::AngleAxisd(rot(rng), Eigen::Vector3d::UnitY()) * m.linear()).eval();
      m.translation() += test::draw(rng, lat, lat, dep) - (m.linear() - truth(t).linear()) * anchor;
      test::AllocationGuard guard;
      predictor.update(static_cast<Nanos>(std::llround(t * 1e9)), m);
      allocations += guard.allocations();
    }
    const Eigen::Isometry3d X = predictor.predict(millis(10500));
    sum_sq += (X * anchor - truth(10.5) * anchor).cwiseAbs2();
    sum_sq_q += (X * q - truth(10.5) * q).squaredNorm();
  }
  CHECK(allocations == 0);
  const Eigen::Vector3d rms = (sum_sq / kRuns).cwiseSqrt();
  const double rms_q = std::sqrt(sum_sq_q / kRuns);
  INFO("rms prediction error at the anchor over " << kRuns << " runs: " << rms.transpose() * 1000 << " mm; 40 cm off it: " << rms_q * 1000 << " mm");
  CHECK(rms.x() < 0.001);
  CHECK(rms.y() < 0.001);
  CHECK(rms.z() < 0.002);
  CHECK(rms_q < 0.003);  // a point off the anchor rotates with the panel
}

TEST_CASE("Kalman predictor: poses fitted to MFs on one line leave the rotation about it to the filter") {
  // The panel moves along x at 15 cm/s without turning. Two seconds of poses fitted to ten
  // MFs around the anchor, then two seconds fitted to four MFs on one vertical line 45 cm
  // to the side (the rest out of view): their depth noise turns the pose about that line
  // (here 10 mrad rms), which moves the anchor by 4.5 mm. With the MFs given, the filter
  // keeps its own rotation; with the fixed noise it follows the measurement.
  const Eigen::Vector3d anchor(0.0, 0.0, 3.1);
  std::vector<Eigen::Vector3d> all, line;
  for (int i = 0; i < 10; ++i) all.emplace_back(0.45 * std::cos(i * 0.628), 0.3 * std::sin(i * 0.628), 3.1);
  for (int i = 0; i < 4; ++i) line.emplace_back(-0.45, -0.3 + 0.2 * i, 3.1);
  auto truth = [](double t) { return pose(0, 0, 0, {0.15 * t, 0, 0}); };
  auto run = [&](bool give_mfs) {
    PosePredictor predictor(PredictorParams{});
    predictor.reset(anchor);
    std::mt19937 rng(4);
    std::normal_distribution<double> turn(0, 0.01);
    double worst = 0;
    for (int k = 0; k <= 120; ++k) {
      const double t = k / 30.0;
      Eigen::Isometry3d m = truth(t);
      const bool few = k > 60;
      if (few) {  // turned about the vertical line through the four MFs (where they are now)
        const Eigen::Vector3d pivot = m * Eigen::Vector3d(-0.45, 0, 3.1);
        Eigen::Isometry3d spin = Eigen::Isometry3d::Identity();
        spin.linear() = Eigen::AngleAxisd(turn(rng), Eigen::Vector3d::UnitY()).toRotationMatrix();
        spin.translation() = pivot - spin.linear() * pivot;
        m = spin * m;
      }
      const Nanos time = static_cast<Nanos>(std::llround(t * 1e9));
      predictor.update(time, m, give_mfs ? std::span<const Eigen::Vector3d>(few ? line : all) : std::span<const Eigen::Vector3d>());
      if (few) worst = std::max(worst, (predictor.predict(time + millis(100)) * anchor - truth(t + 0.1) * anchor).norm());
    }
    return worst;
  };
  const double with_mfs = run(true), fixed = run(false);
  INFO("worst prediction error 0.1 s ahead at the anchor: " << with_mfs * 1000 << " mm with the MFs, " << fixed * 1000
                                                             << " mm with the fixed noise");
  CHECK(with_mfs < 0.001);
  CHECK(fixed > 0.002);
}

// ---------------------------------------------------------------------------------
// The planner: closed-form cases.

TEST_CASE("planner: rest-to-rest move times, triangle and trapezoid") {
  control::ArmTimingModel arm;
  arm.max_speed = 1.0;
  arm.max_accel = 4.0;
  CHECK(control::move_seconds(arm, 0.0) == 0.0);
  CHECK(control::move_seconds(arm, 0.16) == Approx(0.4));        // 2 sqrt(0.16 / 4): never reaches 1 m/s
  CHECK(control::move_seconds(arm, 0.25) == Approx(0.5));        // exactly reaches it
  CHECK(control::move_seconds(arm, 1.25) == Approx(1.25 + 0.25));  // d / v + v / a
}

TEST_CASE("planner: a standing panel: the times add up move by move") {
  control::ArmTimingModel arm;
  arm.settle = millis(300);
  arm.pulse = millis(100);
  const std::array<control::PlanDefect, 3> defects{{{0, {1.0, 0.0, 0.5}, true}, {1, {1.0, 0.25, 0.5}, true}, {2, {1.0, 0.25, 0.66}, false}}};
  std::array<control::PlanEntry, 3> out{};
  const auto plan = control::plan_marking(defects, Eigen::Vector3d(1.0, -1.25, 0.5), Eigen::Vector3d::Zero(), arm, out);
  CHECK(plan.feasible == 2);
  CHECK(plan.infeasible == 0);
  CHECK(out[0].verdict == control::PlanVerdict::kFeasible);
  CHECK(out[0].spray_time == Approx(1.5 + 0.3));               // 1.25 m: 1.5 s, then settle
  CHECK(out[1].spray_time == Approx(1.8 + 0.1 + 0.5 + 0.3));   // pulse, 0.25 m: 0.5 s, settle
  CHECK(out[2].verdict == control::PlanVerdict::kNotPlanned);
  CHECK(plan.finish_time == Approx(2.7 + 0.1));
}

TEST_CASE("planner: the line brings a defect into reach, takes one out, and misses one") {
  control::ArmTimingModel arm;
  arm.reach = 1.0;
  arm.settle = millis(200);
  arm.pulse = millis(50);
  const Eigen::Vector3d v(0.0, 0.1, 0.0);  // 10 cm/s along +y
  // 0: just inside, about to leave: gone before the arm (0.9 m away) arrives.
  // 1: upstream at y = -2: enters the 1 m sphere at y = -sqrt(1 - 0.6^2) = -0.8, after 12 s.
  // 2: beside the line's path at x = 1.2: never within reach.
  const std::array<control::PlanDefect, 3> defects{{{7, {0.0, 0.99, 0.0}, true}, {8, {0.6, -2.0, 0.0}, true}, {9, {1.2, -3.0, 0.0}, true}}};
  std::array<control::PlanEntry, 3> out{};
  const auto plan = control::plan_marking(defects, Eigen::Vector3d(0.0, 0.0, 0.0), v, arm, out);
  CHECK(out[0].verdict == control::PlanVerdict::kLeavesReach);
  CHECK(out[1].verdict == control::PlanVerdict::kFeasible);
  CHECK(out[1].spray_time == Approx(12.0).margin(0.021));  // waits for it (search step 20 ms)
  CHECK(out[2].verdict == control::PlanVerdict::kNeverInReach);
  CHECK(out[0].index == 7);
  CHECK(plan.feasible == 1);
  CHECK(plan.infeasible == 2);
}

TEST_CASE("planner: allocation-free") {
  control::ArmTimingModel arm;
  std::array<control::PlanDefect, 4> defects{};
  for (int i = 0; i < 4; ++i) defects[static_cast<std::size_t>(i)] = {i, Eigen::Vector3d(0.5, 0.1 * i, 0.8), true};
  std::array<control::PlanEntry, 4> out{};
  test::AllocationGuard guard;
  const auto plan = control::plan_marking(defects, Eigen::Vector3d(0.3, 0, 0.6), Eigen::Vector3d(0, 0.015, 0), arm, out);
  CHECK(guard.allocations() == 0);
  CHECK(plan.feasible == 4);
}
