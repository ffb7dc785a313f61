#include "markcell/vision/optical_flow.hpp"

#include <algorithm>
#include <cmath>

#include "markcell/common/check.hpp"

namespace markcell::vision {

namespace {
int reflect101(int i, int n) {
  if (i < 0) return -i;
  if (i >= n) return 2 * n - 2 - i;
  return i;
}
constexpr std::array<float, 5> kBinomial{1.f / 16, 4.f / 16, 6.f / 16, 4.f / 16, 1.f / 16};

// Smaller eigenvalue of [[a b] [b c]].
double min_eigen(double a, double b, double c) { return 0.5 * ((a + c) - std::sqrt((a - c) * (a - c) + 4 * b * b)); }
}  // namespace

Pyramid::Pyramid(int width, int height, int levels) : levels_(levels) {
  MARKCELL_THROW_UNLESS(levels >= 1 && levels <= kMaxPyramidLevels, "levels=" << levels);
  MARKCELL_THROW_UNLESS(width >= 16 && height >= 16, "width=" << width << " height=" << height);
  int w = width, h = height;
  for (int l = 0; l < levels; ++l) {
    const auto k = static_cast<std::size_t>(l);
    w_[k] = w;
    h_[k] = h;
    data_[k].assign(static_cast<std::size_t>(w) * static_cast<std::size_t>(h), 0.f);
    w = (w + 1) / 2;
    h = (h + 1) / 2;
  }
  scratch_.assign(static_cast<std::size_t>(width) * static_cast<std::size_t>(height), 0.f);
}

void Pyramid::build(const cv::Mat& gray8) {
  MARKCELL_THROW_UNLESS(gray8.type() == CV_8UC1 && gray8.cols == w_[0] && gray8.rows == h_[0],
                        "image " << gray8.cols << "x" << gray8.rows << " type " << gray8.type() << ", pyramid "
                                 << w_[0] << "x" << h_[0] << " CV_8UC1");
  // OpenCV's vectorised conversion into our own storage (a header over it: no allocation,
  // the destination already has the size and type convertTo asks for).
  cv::Mat level0(h_[0], w_[0], CV_32F, data_[0].data());
  gray8.convertTo(level0, CV_32F);
  for (int l = 1; l < levels_; ++l) {
    const auto s = static_cast<std::size_t>(l - 1), d = static_cast<std::size_t>(l);
    const int sw = w_[s], sh = h_[s], dw = w_[d], dh = h_[d];
    const float* src = data_[s].data();
    float* dst = data_[d].data();
    float* tmp = scratch_.data();  // one filtered source row
    for (int y = 0; y < dh; ++y) {
      // Vertical first, over whole contiguous rows (vectorises), at the even rows only ...
      const float* rows[5];
      for (int k = 0; k < 5; ++k) rows[k] = src + static_cast<std::size_t>(reflect101(2 * y + k - 2, sh)) * static_cast<std::size_t>(sw);
      for (int x = 0; x < sw; ++x)
        tmp[x] = kBinomial[0] * (rows[0][x] + rows[4][x]) + kBinomial[1] * (rows[1][x] + rows[3][x]) + kBinomial[2] * rows[2][x];
      // ... then horizontal at the even columns; the reflected border only at the ends.
      float* out = dst + static_cast<std::size_t>(y) * static_cast<std::size_t>(dw);
      for (int x = 0; x < dw; ++x) {
        const int c = 2 * x;
        if (c >= 2 && c + 2 < sw) {
          out[x] = kBinomial[0] * (tmp[c - 2] + tmp[c + 2]) + kBinomial[1] * (tmp[c - 1] + tmp[c + 1]) + kBinomial[2] * tmp[c];
        } else {
          float acc = 0;
          for (int k = 0; k < 5; ++k) acc += kBinomial[static_cast<std::size_t>(k)] * tmp[reflect101(c + k - 2, sw)];
          out[x] = acc;
        }
      }
    }
  }
}

float Pyramid::sample(int level, double x, double y) const {
  const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
  const auto fx = static_cast<float>(x - x0), fy = static_cast<float>(y - y0);
  const float* r0 = row(level, y0) + x0;
  const float* r1 = row(level, y0 + 1) + x0;
  return (1 - fy) * ((1 - fx) * r0[0] + fx * r0[1]) + fy * ((1 - fx) * r1[0] + fx * r1[1]);
}

LkResult track_point(const Pyramid& from, const Pyramid& to, const Eigen::Vector2d& p, const Eigen::Vector2d& guess,
                     const LkParams& params) {
  LkResult result;
  const int r = std::clamp(params.radius, 1, kMaxLkRadius);
  const int n = 2 * r + 1;
  std::array<float, (2 * kMaxLkRadius + 1) * (2 * kMaxLkRadius + 1)> I{}, Ix{}, Iy{};
  std::array<float, (2 * kMaxLkRadius + 3) * (2 * kMaxLkRadius + 3)> P{};
  const int top = std::min({from.levels(), to.levels(), params.max_levels > 0 ? params.max_levels : kMaxPyramidLevels}) - 1;
  Eigen::Vector2d g = (guess - p) / static_cast<double>(1 << top);  // displacement at the top level
  const double margin = r + 2;
  for (int level = top; level >= 0; --level) {
    const double scale = 1.0 / static_cast<double>(1 << level);
    const Eigen::Vector2d pl = p * scale;
    const bool last = level == 0;
    if (!from.inside(level, pl.x(), pl.y(), margin)) {
      if (last) return result;  // kOutside
      g *= 2;
      continue;
    }
    // The window plus a one-pixel border, sampled once; gradients by central differences.
    const int np = n + 2;
    for (int j = 0; j < np; ++j)
      for (int i = 0; i < np; ++i)
        P[static_cast<std::size_t>(j * np + i)] = from.sample(level, pl.x() + i - r - 1, pl.y() + j - r - 1);
    double a = 0, b = 0, c = 0;
    for (int j = 0, k = 0; j < n; ++j)
      for (int i = 0; i < n; ++i, ++k) {
        const auto ku = static_cast<std::size_t>(k);
        const auto at = [&](int di, int dj) { return P[static_cast<std::size_t>((j + 1 + dj) * np + (i + 1 + di))]; };
        I[ku] = at(0, 0);
        Ix[ku] = 0.5f * (at(1, 0) - at(-1, 0));
        Iy[ku] = 0.5f * (at(0, 1) - at(0, -1));
        a += Ix[ku] * Ix[ku];
        b += Ix[ku] * Iy[ku];
        c += Iy[ku] * Iy[ku];
      }
    const double area = static_cast<double>(n * n);
    const double det = a * c - b * b;
    if (min_eigen(a, b, c) / area < params.min_eigen || det <= 0) {
      if (last) {
        result.status = LkStatus::kFlat;
        return result;
      }
      g *= 2;
      continue;
    }
    Eigen::Vector2d v = Eigen::Vector2d::Zero();
    bool outside = false;
    for (int it = 0; it < params.max_iterations; ++it) {
      const Eigen::Vector2d q = pl + g + v;
      if (!to.inside(level, q.x(), q.y(), margin - 1)) {
        outside = true;
        break;
      }
      // Every window pixel shares q's fractional offset: one set of bilinear weights.
      const double qx = q.x() - r, qy = q.y() - r;
      const int x0 = static_cast<int>(std::floor(qx)), y0 = static_cast<int>(std::floor(qy));
      const auto fx = static_cast<float>(qx - x0), fy = static_cast<float>(qy - y0);
      const float w00 = (1 - fx) * (1 - fy), w01 = fx * (1 - fy), w10 = (1 - fx) * fy, w11 = fx * fy;
      double bx = 0, by = 0;
      for (int j = 0, k = 0; j < n; ++j) {
        const float* r0 = to.row(level, y0 + j) + x0;
        const float* r1 = to.row(level, y0 + j + 1) + x0;
        float sx = 0, sy = 0;
        for (int i = 0; i < n; ++i, ++k) {
          const auto ku = static_cast<std::size_t>(k);
          const float J = w00 * r0[i] + w01 * r0[i + 1] + w10 * r1[i] + w11 * r1[i + 1];
          const float diff = I[ku] - J;
          sx += diff * Ix[ku];
          sy += diff * Iy[ku];
        }
        bx += sx;
        by += sy;
      }
      const Eigen::Vector2d step((c * bx - b * by) / det, (a * by - b * bx) / det);
      v += step;
      if (step.squaredNorm() < params.epsilon * params.epsilon) break;
    }
    if (outside) {
      if (last) return result;
      g *= 2;
      continue;
    }
    g = last ? Eigen::Vector2d(g + v) : Eigen::Vector2d(2 * (g + v));
  }
  result.point = p + g;
  if (!to.inside(0, result.point.x(), result.point.y(), margin - 1)) return result;
  double err = 0;
  for (int j = -r, k = 0; j <= r; ++j)
    for (int i = -r; i <= r; ++i, ++k)
      err += std::abs(I[static_cast<std::size_t>(k)] - to.sample(0, result.point.x() + i, result.point.y() + j));
  result.error = err / (n * n);
  result.status = LkStatus::kOk;
  return result;
}

namespace {
// The corner refinement's Gaussian window weights for every radius, computed once when
// the program loads rather than on every call of the real-time path.
using CornerWeights = std::array<float, (2 * kMaxLkRadius + 1) * (2 * kMaxLkRadius + 1)>;
const std::array<CornerWeights, kMaxLkRadius + 1> kCornerWeights = [] {
  std::array<CornerWeights, kMaxLkRadius + 1> all{};
  for (int radius = 1; radius <= kMaxLkRadius; ++radius) {
    const int n = 2 * radius + 1;
    const double sigma2 = 0.5 * radius * radius;
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i)
        all[static_cast<std::size_t>(radius)][static_cast<std::size_t>(j * n + i)] =
            static_cast<float>(std::exp(-((i - radius) * (i - radius) + (j - radius) * (j - radius)) / (2 * sigma2)));
  }
  return all;
}();
}  // namespace

bool refine_corner(const Pyramid& image, Eigen::Vector2d& p, int radius, int max_iterations, double epsilon) {
  radius = std::clamp(radius, 1, kMaxLkRadius);
  const int n = 2 * radius + 1, np = n + 2;
  const auto& weight = kCornerWeights[static_cast<std::size_t>(radius)];
  std::array<float, (2 * kMaxLkRadius + 3) * (2 * kMaxLkRadius + 3)> P{};
  Eigen::Vector2d q = p;
  for (int it = 0; it < max_iterations; ++it) {
    if (!image.inside(0, q.x(), q.y(), radius + 2)) return false;
    for (int j = 0; j < np; ++j)
      for (int i = 0; i < np; ++i)
        P[static_cast<std::size_t>(j * np + i)] = image.sample(0, q.x() + i - radius - 1, q.y() + j - radius - 1);
    double a = 0, b = 0, c = 0, b1 = 0, b2 = 0;
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        const auto at = [&](int di, int dj) { return P[static_cast<std::size_t>((j + 1 + dj) * np + (i + 1 + di))]; };
        const double w = weight[static_cast<std::size_t>(j * n + i)];
        const double gx = 0.5 * (at(1, 0) - at(-1, 0)), gy = 0.5 * (at(0, 1) - at(0, -1));
        const double gxx = gx * gx * w, gxy = gx * gy * w, gyy = gy * gy * w;
        const double x = q.x() + i - radius, y = q.y() + j - radius;
        a += gxx;
        b += gxy;
        c += gyy;
        b1 += gxx * x + gxy * y;
        b2 += gxy * x + gyy * y;
      }
    const double det = a * c - b * b;
    if (!(det > 1e-9 * (a + c) * (a + c))) return false;
    const Eigen::Vector2d next((c * b1 - b * b2) / det, (a * b2 - b * b1) / det);
    const double moved = (next - q).norm();
    q = next;
    if ((q - p).norm() > radius) return false;  // wandered off: no corner here
    if (moved < epsilon) break;
  }
  p = q;
  return true;
}

double shi_tomasi(const Pyramid& image, int x, int y, int radius) {
  if (!image.inside(0, x, y, radius + 1)) return 0;
  double a = 0, b = 0, c = 0;
  for (int j = -radius; j <= radius; ++j)
    for (int i = -radius; i <= radius; ++i) {
      const double gx = 0.5 * (image.at(0, x + i + 1, y + j) - image.at(0, x + i - 1, y + j));
      const double gy = 0.5 * (image.at(0, x + i, y + j + 1) - image.at(0, x + i, y + j - 1));
      a += gx * gx;
      b += gx * gy;
      c += gy * gy;
    }
  return min_eigen(a, b, c) / ((2 * radius + 1) * (2 * radius + 1));
}

bool extract_patch(const Pyramid& image, int level, const Eigen::Vector2d& centre, int radius, Patch& out) {
  radius = std::clamp(radius, 1, kMaxPatchRadius);
  if (!image.inside(level, centre.x(), centre.y(), radius + 1)) return false;
  out.radius = radius;
  for (int j = -radius, k = 0; j <= radius; ++j)
    for (int i = -radius; i <= radius; ++i, ++k)
      out.v[static_cast<std::size_t>(k)] = image.sample(level, centre.x() + i, centre.y() + j);
  return true;
}

double ncc(const Patch& patch, const Pyramid& image, int level, int cx, int cy) {
  const int r = patch.radius;
  if (!image.inside(level, cx, cy, r)) return -1;
  double sa = 0, sb = 0, saa = 0, sbb = 0, sab = 0;
  for (int j = -r, k = 0; j <= r; ++j) {
    const float* row = image.row(level, cy + j) + cx;
    for (int i = -r; i <= r; ++i, ++k) {
      const double va = patch.v[static_cast<std::size_t>(k)], vb = row[i];
      sa += va;
      sb += vb;
      saa += va * va;
      sbb += vb * vb;
      sab += va * vb;
    }
  }
  const double n = (2 * r + 1) * (2 * r + 1);
  const double va = saa - sa * sa / n, vb = sbb - sb * sb / n;
  if (va <= 1e-6 || vb <= 1e-6) return -1;
  return (sab - sa * sb / n) / std::sqrt(va * vb);
}

}  // namespace markcell::vision
