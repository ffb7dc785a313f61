// Triangulation against cv::triangulatePoints and exact projections; the rigid fit
// against Eigen::umeyama and known transforms, with noise, reflections and outliers;
// neither allocates.
#include <catch2/catch.hpp>
#include <random>

#include <Eigen/Geometry>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>

#include "draw.hpp"
#include "alloc_guard.hpp"
#include "markcell/common/geometry.hpp"
#include "markcell/common/splitmix.hpp"
#include "markcell/vision/calibration_io.hpp"
#include "markcell/rig/render.hpp"
#include "sheet_mesh.hpp"
#include "test_files.hpp"

using namespace markcell;
using namespace markcell::geometry;
using namespace markcell::vision;
using namespace markcell::rig;  // the renderer the tests draw their frames with

namespace {

Eigen::Isometry3d random_pose(std::mt19937& rng, double translation) {
  std::uniform_real_distribution<double> u(-1, 1);
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  const Eigen::Vector4d q = test::draw(rng, u, u, u, u);
  X.linear() = Eigen::Quaterniond(q(0), q(1), q(2), q(3)).normalized().toRotationMatrix();
  X.translation() = test::draw(rng, u, u, u) * translation;
  return X;
}

struct Rig {
  Rig() : calibration(load_stereo_calibration(test::source_path("config/calibration/marking_stereo.yaml"))) {
    P_left = calibration.left.K * calibration.X_CamR_CamL.inverse().matrix().topRows<3>();
    P_right.setZero();
    P_right.leftCols<3>() = calibration.right.K;
  }
  StereoCalibration calibration;
  ProjectionMatrix P_left, P_right;  // points in CamR
};

}  // namespace

TEST_CASE("triangulation recovers points from their exact projections") {
  const Rig rig;
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> xy(-0.7, 0.7), z(2.6, 3.6);
  for (int i = 0; i < 100; ++i) {
    const Eigen::Vector3d p = test::draw(rng, xy, xy, z);
    const Eigen::Vector2d xl = project_point(rig.calibration.left, rig.calibration.X_CamR_CamL.inverse() * p);
    const Eigen::Vector2d xr = project_point(rig.calibration.right, p);
    CHECK((triangulate(rig.P_left, rig.P_right, xl, xr) - p).norm() < 1e-9);
  }
}

TEST_CASE("triangulation agrees with cv::triangulatePoints on noisy correspondences") {
  const Rig rig;
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> xy(-0.7, 0.7), z(2.6, 3.6);
  std::normal_distribution<double> noise(0.0, 0.3);
  cv::Mat P1, P2;
  cv::eigen2cv(Eigen::Matrix<double, 3, 4>(rig.P_left), P1);
  cv::eigen2cv(Eigen::Matrix<double, 3, 4>(rig.P_right), P2);
  for (int i = 0; i < 100; ++i) {
    const Eigen::Vector3d p = test::draw(rng, xy, xy, z);
    Eigen::Vector2d xl = project_point(rig.calibration.left, rig.calibration.X_CamR_CamL.inverse() * p);
    Eigen::Vector2d xr = project_point(rig.calibration.right, p);
    xl += test::draw(rng, noise, noise);
    xr += test::draw(rng, noise, noise);
    cv::Mat X;
    cv::triangulatePoints(P1, P2, cv::Mat(cv::Point2d(xl.x(), xl.y())), cv::Mat(cv::Point2d(xr.x(), xr.y())), X);
    X.convertTo(X, CV_64F);
    const Eigen::Vector3d ref(X.at<double>(0) / X.at<double>(3), X.at<double>(1) / X.at<double>(3), X.at<double>(2) / X.at<double>(3));
    const Eigen::Vector3d ours = triangulate(rig.P_left, rig.P_right, xl, xr);
    CHECK((ours - ref).norm() < 1e-6 * ref.norm());
  }
}

TEST_CASE("the rigid fit recovers known transforms and agrees with Eigen::umeyama under noise") {
  std::mt19937 rng(5);
  std::normal_distribution<double> noise(0.0, 0.002);
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  for (int trial = 0; trial < 50; ++trial) {
    const Eigen::Isometry3d X = random_pose(rng, 2.0);
    std::vector<Eigen::Vector3d> a, b, b_noisy;
    for (int i = 0; i < 10; ++i) {
      a.push_back(test::draw(rng, u, u, u));
      b.push_back(X * a.back());
      b_noisy.push_back(b.back() + test::draw(rng, noise, noise, noise));
    }
    const RigidFit exact = fit_rigid(a, b);
    REQUIRE(exact.valid);
    CHECK((exact.X_B_A.matrix() - X.matrix()).norm() < 1e-9);
    CHECK(exact.rms < 1e-9);
    const RigidFit fit = fit_rigid(a, b_noisy);
    Eigen::Matrix<double, 3, Eigen::Dynamic> A(3, 10), B(3, 10);
    for (int i = 0; i < 10; ++i) {
      A.col(i) = a[static_cast<std::size_t>(i)];
      B.col(i) = b_noisy[static_cast<std::size_t>(i)];
    }
    const Eigen::Matrix4d ref = Eigen::umeyama(A, B, false);
    CHECK((fit.X_B_A.matrix() - ref).norm() < 1e-9);
  }
}

TEST_CASE("the rigid fit stays a rotation where a reflection would fit better, and refuses collinear sets") {
  // Four coplanar points mirrored through their plane: the best orthogonal fit is a
  // reflection; the fit must return the best rotation instead (det +1), as umeyama does.
  const std::vector<Eigen::Vector3d> a = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0.0}};
  std::vector<Eigen::Vector3d> b;
  for (const auto& p : a) b.emplace_back(p.x(), p.y(), -p.z() + 0.001 * (p.x() - p.y()));
  const RigidFit fit = fit_rigid(a, b);
  REQUIRE(fit.valid);
  CHECK(fit.X_B_A.linear().determinant() == Approx(1.0).epsilon(1e-12));
  Eigen::Matrix<double, 3, 4> A, B;
  for (int i = 0; i < 4; ++i) {
    A.col(i) = a[static_cast<std::size_t>(i)];
    B.col(i) = b[static_cast<std::size_t>(i)];
  }
  CHECK((fit.X_B_A.matrix() - Eigen::umeyama(A, B, false)).norm() < 1e-9);
  const std::vector<Eigen::Vector3d> line = {{0, 0, 0}, {1, 0, 0}, {2, 0, 0}, {3, 0, 0}};
  CHECK_FALSE(fit_rigid(line, line).valid);
  CHECK_FALSE(fit_rigid(std::span<const Eigen::Vector3d>(a.data(), 2), std::span<const Eigen::Vector3d>(b.data(), 2)).valid);
}

TEST_CASE("the robust fit finds the transform and the outliers among ten macro-features") {
  std::mt19937 rng(6);
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  const std::vector<Eigen::Vector3d> door_mfs = test::door_sheet_corners();
  for (int trial = 0; trial < 20; ++trial) {
    const Eigen::Isometry3d X = random_pose(rng, 3.0);
    std::vector<Eigen::Vector3d> a(door_mfs.begin(), door_mfs.end()), b;
    for (const auto& p : a) b.push_back(X * p);
    // Three wrong correspondences (a mismatched corner, an occluded one re-found elsewhere).
    const std::array<std::size_t, 3> wrong = {1, 4, 8};
    for (std::size_t w : wrong) {
      const Eigen::Vector3d direction = test::draw(rng, u, u, u);
      b[w] += direction.normalized() * (0.05 + std::abs(u(rng)));
    }
    std::array<bool, 10> inlier{};
    const RigidFit fit = fit_rigid_robust(a, b, RobustFitOptions{0.005, 300, 1 + static_cast<std::uint64_t>(trial)}, inlier);
    REQUIRE(fit.valid);
    CHECK(fit.used == 7);
    CHECK((fit.X_B_A.matrix() - X.matrix()).norm() < 1e-9);
    for (std::size_t i = 0; i < 10; ++i) CHECK(inlier[i] == (std::find(wrong.begin(), wrong.end(), i) == wrong.end()));
  }
}

TEST_CASE("triangulation and the fits allocate nothing") {
  const Rig rig;
  const std::vector<Eigen::Vector3d> door_mfs = test::door_sheet_corners();
  std::array<Eigen::Vector3d, 10> a{}, b{};
  for (std::size_t i = 0; i < 10; ++i) {
    a[i] = door_mfs[i];
    b[i] = a[i] + Eigen::Vector3d(0.1, 0.2, 3.0);
  }
  std::array<bool, 10> inlier{};
  std::size_t allocations = 0;
  double sink = 0;
  {
    test::AllocationGuard guard;
    for (int i = 0; i < 100; ++i) {
      sink += triangulate(rig.P_left, rig.P_right, {300.0, 200.0}, {140.0, 200.0}).z();
      sink += fit_rigid(a, b).rms;
      sink += fit_rigid_robust(a, b, RobustFitOptions{}, inlier).rms;
    }
    allocations = guard.allocations();
  }
  CHECK(allocations == 0);
  CHECK(std::isfinite(sink));
}

// The rig's generator and transforms (common/splitmix.hpp): the same bits on every
// compiler and architecture. References: Vigna's SplitMix64 test vector, and the same
// algorithm in Python's IEEE doubles (the hexadecimal constants below, computed by
// docs/determinism.md's script), std::log, and the normal distribution's closed-form CDF.
TEST_CASE("the rig's generator matches SplitMix64's reference and its transforms are exact") {
  SplitMix reference{1234567};
  const std::uint64_t expected[] = {6457827717110365317ULL, 3203168211198807973ULL, 9817491932198370423ULL,
                                    4593380528125082431ULL, 16408922859458223821ULL};
  for (const auto e : expected) CHECK(reference.next() == e);

  SplitMix rng{42};
  const double normals[] = {0x1.f8c80e851c08cp-2, -0x1.47f4af60c7f94p+0, -0x1.342959c9fa344p-1, -0x1.8ad8264f1e64dp+0};
  for (const double n : normals) CHECK(rng.normal() == n);
  CHECK(portable_log(0.3) == -0x1.34378fcbda720p+0);

  // Within 2 ulp of libm's log across the whole range a deviate can need, and beyond.
  SplitMix draw{7};
  double worst_ulp = 0;
  for (int i = 0; i < 100000; ++i) {
    const double x = std::ldexp(0.5 + draw.unit(), static_cast<int>(draw.below(2000)) - 1000);
    const double want = std::log(x);
    const double ulp = std::nextafter(std::abs(want), INFINITY) - std::abs(want);
    if (want != 0) worst_ulp = std::max(worst_ulp, std::abs(portable_log(x) - want) / ulp);
  }
  CHECK(worst_ulp <= 2.0);
  CHECK(portable_log(1.0) == 0.0);
}

TEST_CASE("the rig's normal deviates follow the closed-form normal distribution") {
  SplitMix rng{2024};
  constexpr int kN = 200000;
  std::vector<double> x(kN);
  double sum = 0, sum2 = 0;
  for (auto& v : x) {
    v = rng.normal(1.5, 0.25);
    sum += v;
    sum2 += v * v;
  }
  const double mean = sum / kN, var = sum2 / kN - mean * mean;
  CHECK(std::abs(mean - 1.5) < 4 * 0.25 / std::sqrt(kN));
  CHECK(std::abs(var - 0.0625) < 4 * 0.0625 * std::sqrt(2.0 / kN));
  // Kolmogorov-Smirnov against Phi((x - 1.5) / 0.25): below the 1 % critical value.
  std::sort(x.begin(), x.end());
  double d = 0;
  for (int i = 0; i < kN; ++i) {
    const double cdf = 0.5 * std::erfc(-(x[i] - 1.5) / 0.25 / std::sqrt(2.0));
    d = std::max({d, std::abs(cdf - static_cast<double>(i) / kN), std::abs(cdf - static_cast<double>(i + 1) / kN)});
  }
  CHECK(d < 1.63 / std::sqrt(kN));
  SplitMix u{5};
  for (int i = 0; i < 1000; ++i) {
    const double v = u.uniform(-2.0, 3.0);
    REQUIRE(v >= -2.0);
    REQUIRE(v < 3.0);
  }
}
