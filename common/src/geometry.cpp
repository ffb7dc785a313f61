#include "markcell/common/geometry.hpp"

#include <algorithm>
#include <cmath>

#include <Eigen/SVD>

#include "markcell/common/splitmix.hpp"

namespace markcell::geometry {

Eigen::Vector3d triangulate(const ProjectionMatrix& P1, const ProjectionMatrix& P2, const Eigen::Vector2d& x1,
                            const Eigen::Vector2d& x2) {
  Eigen::Matrix4d A;
  A.row(0) = x1.x() * P1.row(2) - P1.row(0);
  A.row(1) = x1.y() * P1.row(2) - P1.row(1);
  A.row(2) = x2.x() * P2.row(2) - P2.row(0);
  A.row(3) = x2.y() * P2.row(2) - P2.row(1);
  const Eigen::JacobiSVD<Eigen::Matrix4d> svd(A, Eigen::ComputeFullV);
  const Eigen::Vector4d X = svd.matrixV().col(3);
  return X.head<3>() / X(3);
}

RigidFit fit_rigid(std::span<const Eigen::Vector3d> a, std::span<const Eigen::Vector3d> b) {
  RigidFit fit;
  const std::size_t n = std::min(a.size(), b.size());
  if (n < 3) return fit;
  Eigen::Vector3d ca = Eigen::Vector3d::Zero(), cb = Eigen::Vector3d::Zero();
  for (std::size_t i = 0; i < n; ++i) {
    ca += a[i];
    cb += b[i];
  }
  ca /= static_cast<double>(n);
  cb /= static_cast<double>(n);
  Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
  for (std::size_t i = 0; i < n; ++i) H += (a[i] - ca) * (b[i] - cb).transpose();
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
  // Collinear (or coincident) points leave the rotation about their line undetermined.
  const auto& sv = svd.singularValues();
  if (sv(0) <= 0 || sv(1) < 1e-12 * sv(0)) return fit;
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  // A reflection would fit better when the points are coplanar and noisy, or just wrong:
  // flip the axis of the smallest singular value to stay a rotation.
  if ((svd.matrixV() * svd.matrixU().transpose()).determinant() < 0) D(2, 2) = -1;
  const Eigen::Matrix3d R = svd.matrixV() * D * svd.matrixU().transpose();
  fit.X_B_A.linear() = R;
  fit.X_B_A.translation() = cb - R * ca;
  double sum = 0;
  for (std::size_t i = 0; i < n; ++i) sum += (fit.X_B_A * a[i] - b[i]).squaredNorm();
  fit.rms = std::sqrt(sum / static_cast<double>(n));
  fit.used = static_cast<int>(n);
  fit.valid = true;
  return fit;
}


RigidFit fit_rigid_robust(std::span<const Eigen::Vector3d> a, std::span<const Eigen::Vector3d> b,
                          const RobustFitOptions& options, std::span<bool> inlier) {
  const std::size_t n = std::min({a.size(), b.size(), inlier.size(), kMaxFitPoints});
  std::fill(inlier.begin(), inlier.end(), false);
  if (n < 3) return RigidFit{};
  markcell::SplitMix rng{options.seed};
  const double thr2 = options.inlier_threshold * options.inlier_threshold;
  std::array<bool, kMaxFitPoints> best{};
  std::size_t best_count = 0;
  double best_error = 0;
  std::array<Eigen::Vector3d, 3> sa, sb;
  for (int it = 0; it < options.max_iterations; ++it) {
    std::size_t i = rng.below(n), j = rng.below(n), k = rng.below(n);
    if (i == j || j == k || i == k) continue;
    sa = {a[i], a[j], a[k]};
    sb = {b[i], b[j], b[k]};
    const RigidFit trial = fit_rigid(sa, sb);
    if (!trial.valid) continue;
    std::array<bool, kMaxFitPoints> mask{};
    std::size_t count = 0;
    double error = 0;
    for (std::size_t p = 0; p < n; ++p) {
      const double e2 = (trial.X_B_A * a[p] - b[p]).squaredNorm();
      if (e2 <= thr2) {
        mask[p] = true;
        ++count;
        error += e2;
      }
    }
    if (count > best_count || (count == best_count && error < best_error)) {
      best = mask;
      best_count = count;
      best_error = error;
    }
    if (best_count == n) break;  // everyone agrees: no better set exists
  }
  if (best_count < 3) return RigidFit{};
  std::array<Eigen::Vector3d, kMaxFitPoints> ia, ib;
  std::size_t m = 0;
  for (std::size_t p = 0; p < n; ++p)
    if (best[p]) {
      ia[m] = a[p];
      ib[m] = b[p];
      inlier[p] = true;
      ++m;
    }
  return fit_rigid(std::span<const Eigen::Vector3d>(ia.data(), m), std::span<const Eigen::Vector3d>(ib.data(), m));
}

}  // namespace markcell::geometry
