#pragma once
// The geometry the pose estimator and the inter-calibrations stand on, in bounded time
// with no allocation: linear triangulation (Hartley and Zisserman's DLT) and the
// least-squares rigid fit of two point sets (Arun, Huang and Blostein), plain and
// robust to outliers (RANSAC over minimal triples, then a refit on the inliers).
#include <array>
#include <cstdint>
#include <span>

#include <Eigen/Geometry>

namespace markcell::geometry {

using ProjectionMatrix = Eigen::Matrix<double, 3, 4>;

// The 3D point whose projections through P1 and P2 are x1 and x2 (undistorted pixel
// coordinates), minimising the algebraic error (DLT, SVD of the 4x4 system).
Eigen::Vector3d triangulate(const ProjectionMatrix& P1, const ProjectionMatrix& P2, const Eigen::Vector2d& x1,
                            const Eigen::Vector2d& x2);

// Upper bound on the points a rigid fit takes (macro-features, checkerboard corners).
inline constexpr std::size_t kMaxFitPoints = 128;

struct RigidFit {
  Eigen::Isometry3d X_B_A = Eigen::Isometry3d::Identity();  // maps the A points onto the B points
  double rms = 0;        // residual of the points used, metres
  int used = 0;          // points used (the inliers, for the robust fit)
  bool valid = false;    // false: fewer than 3 points, or all (nearly) collinear
};

// Least squares: b_i ~ X_B_A * a_i (Arun et al. 1987, with the reflection case of
// Umeyama 1991 handled so that the result is always a rotation).
RigidFit fit_rigid(std::span<const Eigen::Vector3d> a, std::span<const Eigen::Vector3d> b);

struct RobustFitOptions {
  double inlier_threshold = 0.01;  // metres
  int max_iterations = 200;        // RANSAC rounds (bounded time)
  std::uint64_t seed = 1;          // the same inputs and seed give the same answer
};

// RANSAC over minimal triples, then the plain fit on the largest consensus set.
// `inlier` (same size as a, b) receives which points were used.
RigidFit fit_rigid_robust(std::span<const Eigen::Vector3d> a, std::span<const Eigen::Vector3d> b,
                          const RobustFitOptions& options, std::span<bool> inlier);

}  // namespace markcell::geometry
