#include "markcell/vision/hole_fit.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>

#include <Eigen/Eigenvalues>

namespace markcell::vision {

std::string_view to_string(HoleFitStatus s) {
  switch (s) {
    case HoleFitStatus::kOk: return "ok";
    case HoleFitStatus::kOutside: return "its rays leave the image";
    case HoleFitStatus::kFewEdges: return "fewer than half of its rays meet a hole's edge";
    case HoleFitStatus::kNoEllipse: return "its edge points lie on no ellipse";
    case HoleFitStatus::kRagged: return "its edge points scatter about the ellipse";
  }
  return "?";
}

namespace {

constexpr double kStep = 0.25;  // along a ray, px
constexpr int kMaxSamples = static_cast<int>(kMaxHoleRadiusPx / kStep) + 2;

struct Directions {
  std::array<Eigen::Vector2d, kHoleRays> d;
  Directions() {
    for (int k = 0; k < kHoleRays; ++k) {
      const double a = 2 * std::numbers::pi * k / kHoleRays;
      d[static_cast<std::size_t>(k)] = {std::cos(a), std::sin(a)};
    }
  }
};
const Directions& directions() {
  static const Directions dirs;  // (built once, on the stack of no one: no allocation)
  return dirs;
}

struct EdgePoints {
  std::array<Eigen::Vector2d, kHoleRays> p;
  int n = 0;
};

// The edge on each ray from `c`; the polarity found when `polarity` is 0.
HoleFitStatus find_edges(const Pyramid& image, const Eigen::Vector2d& c, const HoleFitParams& params, int& polarity,
                         EdgePoints& out) {
  const double r0 = std::max(params.min_radius, kStep), r1 = std::min(params.max_radius, kMaxHoleRadiusPx);
  const int n = std::min(static_cast<int>((r1 - r0) / kStep) + 1, kMaxSamples);
  out.n = 0;
  if (n < 5 || !image.inside(0, c.x() - r1, c.y() - r1, 1.0) || !image.inside(0, c.x() + r1, c.y() + r1, 1.0))
    return n < 5 ? HoleFitStatus::kFewEdges : HoleFitStatus::kOutside;
  std::array<std::array<float, kMaxSamples>, kHoleRays> profile;
  double outward = 0;  // outer minus inner grey, summed over the rays
  for (int k = 0; k < kHoleRays; ++k) {
    const Eigen::Vector2d& d = directions().d[static_cast<std::size_t>(k)];
    auto& p = profile[static_cast<std::size_t>(k)];
    for (int i = 0; i < n; ++i) {
      const Eigen::Vector2d q = c + (r0 + i * kStep) * d;
      p[static_cast<std::size_t>(i)] = image.sample(0, q.x(), q.y());
    }
    outward += (p[static_cast<std::size_t>(n - 1)] + p[static_cast<std::size_t>(n - 2)]) - (p[0] + p[1]);
  }
  if (polarity == 0) polarity = outward >= 0 ? 1 : -1;
  const double s = polarity;
  for (int k = 0; k < kHoleRays; ++k) {
    const auto& p = profile[static_cast<std::size_t>(k)];
    // s * the grey's derivative along the ray, grey per px, at sample i (2 <= i <= n - 3).
    const auto slope = [&](int i) {
      return s * (p[static_cast<std::size_t>(i + 1)] - p[static_cast<std::size_t>(i - 1)]) / (2 * kStep);
    };
    int best = -1;
    double best_slope = params.min_step;
    for (int i = 2; i <= n - 3; ++i)
      if (const double g = slope(i); g > best_slope) best_slope = g, best = i;
    if (best < 0) continue;
    // The edge: where the profile crosses halfway between the grey inside (1.25 to 2 px
    // before the steepest point) and outside (as far after). A blurred step is linear
    // about that level, so interpolating linearly between samples there (and bilinearly
    // between pixels) is exact to first order; the steepest point itself, on a bilinear
    // profile, is biased towards pixel boundaries by up to a quarter pixel.
    const auto mean = [&](int from, int to) {
      from = std::clamp(from, 0, n - 1), to = std::clamp(to, 0, n - 1);
      double sum = 0;
      for (int i = from; i <= to; ++i) sum += p[static_cast<std::size_t>(i)];
      return sum / (to - from + 1);
    };
    const double level = 0.5 * (mean(best - 8, std::max(best - 5, 0)) + mean(std::min(best + 5, n - 1), best + 8));
    double at = -1;
    for (int i = std::max(best - 4, 0); i < std::min(best + 4, n - 1); ++i) {
      const double u = s * (p[static_cast<std::size_t>(i)] - level), v = s * (p[static_cast<std::size_t>(i + 1)] - level);
      if (u <= 0 && v > 0) {
        at = i + u / (u - v);
        if (std::abs(at - best) <= 1.5) break;  // the crossing next to the steepest point
      }
    }
    if (at < 0) continue;
    out.p[static_cast<std::size_t>(out.n++)] = c + (r0 + at * kStep) * directions().d[static_cast<std::size_t>(k)];
  }
  return out.n * 2 >= kHoleRays ? HoleFitStatus::kOk : HoleFitStatus::kFewEdges;
}

struct Ellipse {
  bool valid = false;
  Eigen::Matrix<double, 6, 1> conic;  // A x^2 + B xy + C y^2 + D x + E y + F, normalised coordinates
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  double scale = 1;
  Eigen::Vector2d centre = Eigen::Vector2d::Zero();  // px
  double semi_major = 0, semi_minor = 0;            // px
};

// Fitzgibbon, Pilu and Fisher's direct ellipse fit in Halir and Flusser's form, on the
// points `use` marks, in coordinates centred on their mean and scaled to unit rms.
Ellipse fit_ellipse(const EdgePoints& pts, const std::array<bool, kHoleRays>& use) {
  Ellipse e;
  int m = 0;
  for (int j = 0; j < pts.n; ++j)
    if (use[static_cast<std::size_t>(j)]) e.mean += pts.p[static_cast<std::size_t>(j)], ++m;
  if (m < 6) return e;
  e.mean /= m;
  double sq = 0;
  for (int j = 0; j < pts.n; ++j)
    if (use[static_cast<std::size_t>(j)]) sq += (pts.p[static_cast<std::size_t>(j)] - e.mean).squaredNorm();
  e.scale = std::sqrt(sq / m);
  if (!(e.scale > 1e-6)) return e;
  Eigen::Matrix3d S1 = Eigen::Matrix3d::Zero(), S2 = Eigen::Matrix3d::Zero(), S3 = Eigen::Matrix3d::Zero();
  for (int j = 0; j < pts.n; ++j) {
    if (!use[static_cast<std::size_t>(j)]) continue;
    const Eigen::Vector2d u = (pts.p[static_cast<std::size_t>(j)] - e.mean) / e.scale;
    const Eigen::Vector3d d1(u.x() * u.x(), u.x() * u.y(), u.y() * u.y()), d2(u.x(), u.y(), 1.0);
    S1 += d1 * d1.transpose();
    S2 += d1 * d2.transpose();
    S3 += d2 * d2.transpose();
  }
  const Eigen::FullPivLU<Eigen::Matrix3d> lu(S3);
  if (!lu.isInvertible()) return e;
  const Eigen::Matrix3d T = -lu.inverse() * S2.transpose();
  const Eigen::Matrix3d M = S1 + S2 * T;
  Eigen::Matrix3d N;  // C1^-1 M, C1 the constraint 4AC - B^2 = 1's matrix
  N.row(0) = M.row(2) / 2;
  N.row(1) = -M.row(1);
  N.row(2) = M.row(0) / 2;
  const Eigen::EigenSolver<Eigen::Matrix3d> solver(N);
  if (solver.info() != Eigen::Success) return e;
  int pick = -1;
  double best = 0;
  for (int i = 0; i < 3; ++i) {
    const Eigen::Vector3d v = solver.eigenvectors().col(i).real();
    const double c = 4 * v(0) * v(2) - v(1) * v(1);
    if (c > best) best = c, pick = i;
  }
  if (pick < 0) return e;
  const Eigen::Vector3d a1 = solver.eigenvectors().col(pick).real();
  e.conic << a1, T * a1;
  const double A = e.conic(0), B = e.conic(1), C = e.conic(2), D = e.conic(3), E = e.conic(4), F = e.conic(5);
  const double den = B * B - 4 * A * C;
  if (!(den < 0)) return e;
  const Eigen::Vector2d uc((2 * C * D - B * E) / den, (2 * A * E - B * D) / den);
  const double f0 = A * uc.x() * uc.x() + B * uc.x() * uc.y() + C * uc.y() * uc.y() + D * uc.x() + E * uc.y() + F;
  Eigen::Matrix2d Q;
  Q << A, B / 2, B / 2, C;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> q(Q);
  const double l0 = q.eigenvalues()(0), l1 = q.eigenvalues()(1);
  if (!(-f0 / l0 > 0) || !(-f0 / l1 > 0)) return e;
  const double s0 = std::sqrt(-f0 / l0), s1 = std::sqrt(-f0 / l1);
  e.centre = e.mean + e.scale * uc;
  e.semi_major = e.scale * std::max(s0, s1);
  e.semi_minor = e.scale * std::min(s0, s1);
  e.valid = std::isfinite(e.centre.x()) && std::isfinite(e.centre.y());
  return e;
}

// A point's distance from the ellipse, to first order (Sampson), px.
double distance(const Ellipse& e, const Eigen::Vector2d& p) {
  const Eigen::Vector2d u = (p - e.mean) / e.scale;
  const auto& c = e.conic;
  const double value = c(0) * u.x() * u.x() + c(1) * u.x() * u.y() + c(2) * u.y() * u.y() + c(3) * u.x() + c(4) * u.y() + c(5);
  const Eigen::Vector2d grad(2 * c(0) * u.x() + c(1) * u.y() + c(3), c(1) * u.x() + 2 * c(2) * u.y() + c(4));
  const double g = grad.norm();
  return g > 0 ? e.scale * std::abs(value) / g : 1e9;
}

// One pass from `c`: the edges, the fit, the points far from it left out and fitted again.
HoleFit fit_from(const Pyramid& image, const Eigen::Vector2d& c, const HoleFitParams& params, int polarity) {
  HoleFit out;
  EdgePoints pts;
  out.status = find_edges(image, c, params, polarity, pts);
  out.polarity = polarity;
  out.edges = pts.n;
  if (out.status != HoleFitStatus::kOk) return out;
  std::array<bool, kHoleRays> use{};
  for (int j = 0; j < pts.n; ++j) use[static_cast<std::size_t>(j)] = true;
  Ellipse e = fit_ellipse(pts, use);
  if (e.valid) {
    // Left out: a ray that met something else (a neighbouring edge, a scratch): farther
    // than five times the median distance, and than a quarter pixel.
    std::array<double, kHoleRays> dist{}, sorted{};
    for (int j = 0; j < pts.n; ++j) dist[static_cast<std::size_t>(j)] = sorted[static_cast<std::size_t>(j)] = distance(e, pts.p[static_cast<std::size_t>(j)]);
    std::nth_element(sorted.begin(), sorted.begin() + pts.n / 2, sorted.begin() + pts.n);
    const double limit = std::max(0.25, 5 * sorted[static_cast<std::size_t>(pts.n / 2)]);
    int kept = 0;
    for (int j = 0; j < pts.n; ++j) kept += (use[static_cast<std::size_t>(j)] = dist[static_cast<std::size_t>(j)] <= limit) ? 1 : 0;
    if (kept < pts.n && kept * 2 >= kHoleRays) e = fit_ellipse(pts, use);
    out.edges = kept;
    if (kept * 2 < kHoleRays) {
      out.status = HoleFitStatus::kFewEdges;
      return out;
    }
  }
  if (!e.valid || e.semi_minor < 0.5 || e.semi_major > kMaxHoleRadiusPx) {
    out.status = HoleFitStatus::kNoEllipse;
    return out;
  }
  double sq = 0;
  int m = 0;
  for (int j = 0; j < pts.n; ++j)
    if (use[static_cast<std::size_t>(j)]) sq += std::pow(distance(e, pts.p[static_cast<std::size_t>(j)]), 2), ++m;
  out.rms_px = std::sqrt(sq / std::max(m, 1));
  out.centre = e.centre;
  out.semi_major = e.semi_major;
  out.semi_minor = e.semi_minor;
  out.status = out.rms_px <= params.max_rms_px ? HoleFitStatus::kOk : HoleFitStatus::kRagged;
  return out;
}

}  // namespace

HoleFit fit_hole(const Pyramid& image, const Eigen::Vector2d& guess, const HoleFitParams& params) {
  // Rays from a guess off the centre meet the rim at uneven spacing; from the first fit's
  // centre, evenly: the second pass is the answer.
  const HoleFit first = fit_from(image, guess, params, params.polarity);
  if (!first.ok() || (first.centre - guess).norm() > params.max_radius) return first;
  return fit_from(image, first.centre, params, first.polarity);
}

}  // namespace markcell::vision
