#include "markcell/rig/render.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>

#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>
#include <opencv2/imgproc.hpp>

#include "markcell/common/splitmix.hpp"

namespace markcell::rig {

Eigen::Vector2d project_point(const vision::CameraModel& c, const Eigen::Vector3d& p) {
  const double x = p.x() / p.z(), y = p.y() / p.z();
  double k1 = 0, k2 = 0, p1 = 0, p2 = 0, k3 = 0;
  const int n = c.distortion.empty() ? 0 : static_cast<int>(c.distortion.total());
  const auto d = [&](int i) { return i < n ? c.distortion.at<double>(i) : 0.0; };
  k1 = d(0);
  k2 = d(1);
  p1 = d(2);
  p2 = d(3);
  k3 = d(4);
  const double r2 = x * x + y * y;
  const double radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
  const double xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x);
  const double yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y;
  return {c.K(0, 0) * xd + c.K(0, 1) * yd + c.K(0, 2), c.K(1, 1) * yd + c.K(1, 2)};
}

namespace {
// 8 samples per pixel, stratified: sample s lies in column s of an 8x8 grid and in a row
// of its own (n-rooks), jittered inside its cell, with the rows' order and the jitter
// drawn per pixel from a fixed generator. A sensor's pixel integrates light over its area;
// one pattern shared by every pixel would quantise an axis-aligned edge to steps of 1/8
// pixel in every pixel along it alike, a bias of up to 0.06 px that no window averages
// away (0.05 px of disparity, 1 mm of depth at 3.1 m); per-pixel patterns make that error
// independent from pixel to pixel, so an edge's position comes out unbiased.
constexpr int kSamples = 8;
constexpr int kEdgeGrid = 8;         // an edge pixel's samples: kEdgeGrid^2
constexpr float kEdgeSpread = 2.0f;  // grey levels between a pixel's samples that mark an edge

// Calls f(d_Cam) with the unit ray of each of an edge pixel's kEdgeGrid^2 samples: a
// jittered grid whose pattern is fixed per pixel, each ray the bilinear blend of the
// pixel's corner coordinates (`corners`: the camera's normalised corner grid).
template <typename F>
void for_each_edge_ray(const cv::Mat& corners, int camera, int u, int v, F&& f) {
  const cv::Vec2d c00 = corners.at<cv::Vec2d>(v, u), c10 = corners.at<cv::Vec2d>(v, u + 1), c01 = corners.at<cv::Vec2d>(v + 1, u),
                  c11 = corners.at<cv::Vec2d>(v + 1, u + 1);
  SplitMix rng{(static_cast<std::uint64_t>(camera) << 40) ^ (static_cast<std::uint64_t>(v) << 20) ^ static_cast<std::uint64_t>(u)};
  for (int i = 0; i < kEdgeGrid; ++i)
    for (int j = 0; j < kEdgeGrid; ++j) {
      const double a = (i + rng.unit()) / kEdgeGrid;
      const double b = (j + rng.unit()) / kEdgeGrid;
      const cv::Vec2d q = (c00 * (1 - a) + c10 * a) * (1 - b) + (c01 * (1 - a) + c11 * a) * b;
      f(Eigen::Vector3d(q[0], q[1], 1.0).normalized());
    }
}
}  // namespace

StereoRenderer::StereoRenderer(vision::StereoCalibration cameras, RenderSettings settings)
    : cameras_(std::move(cameras)), settings_(std::move(settings)) {
  for (int cam = 0; cam < 2; ++cam) {
    const vision::CameraModel& c = cam == 0 ? cameras_.left : cameras_.right;
    std::vector<cv::Point2f> pixels;
    pixels.reserve(static_cast<std::size_t>(c.width) * static_cast<std::size_t>(c.height) * kSamples);
    SplitMix rng{0x6d61726b63656c6cull + static_cast<std::uint64_t>(cam)};  // "markcell"
    std::array<int, kSamples> rows{};
    for (int v = 0; v < c.height; ++v)
      for (int u = 0; u < c.width; ++u) {
        for (int s = 0; s < kSamples; ++s) rows[static_cast<std::size_t>(s)] = s;
        for (int s = kSamples - 1; s > 0; --s)  // Fisher-Yates
          std::swap(rows[static_cast<std::size_t>(s)], rows[static_cast<std::size_t>(rng.below(static_cast<std::size_t>(s + 1)))]);
        for (int s = 0; s < kSamples; ++s) {  // pixel (u, v) covers [u - 0.5, u + 0.5] x [v - 0.5, v + 0.5]
          const double jx = rng.unit(), jy = rng.unit();  // in this order on every compiler
          pixels.emplace_back(static_cast<float>(u - 0.5 + (s + jx) / kSamples),
                              static_cast<float>(v - 0.5 + (rows[static_cast<std::size_t>(s)] + jy) / kSamples));
        }
      }
    cv::Mat K;
    cv::eigen2cv(c.K, K);
    std::vector<cv::Point2f> normalised;
    cv::undistortPoints(pixels, normalised, K, c.distortion.empty() ? cv::Mat() : c.distortion);
    cv::Mat rays(c.height, c.width * kSamples, CV_32FC3);
    std::size_t i = 0;
    for (int v = 0; v < c.height; ++v) {
      cv::Vec3f* row = rays.ptr<cv::Vec3f>(v);
      for (int k = 0; k < c.width * kSamples; ++k, ++i) {
        const auto& q = normalised[i];
        const double norm = std::sqrt(q.x * q.x + q.y * q.y + 1.0);
        row[k] = cv::Vec3f(static_cast<float>(q.x / norm), static_cast<float>(q.y / norm), static_cast<float>(1.0 / norm));
      }
    }
    rays_.push_back(rays);
    // The normalised image coordinates (x, y, 1) of every pixel corner, for edge pixels'
    // extra samples: undistortion is smooth at the scale of a pixel, so a bilinear blend
    // of a pixel's four corners gives any ray inside it (exactly, without distortion).
    std::vector<cv::Point2f> corner_px;
    corner_px.reserve(static_cast<std::size_t>(c.width + 1) * static_cast<std::size_t>(c.height + 1));
    for (int v = 0; v <= c.height; ++v)
      for (int u = 0; u <= c.width; ++u) corner_px.emplace_back(static_cast<float>(u - 0.5), static_cast<float>(v - 0.5));
    std::vector<cv::Point2f> corner_n;
    cv::undistortPoints(corner_px, corner_n, K, c.distortion.empty() ? cv::Mat() : c.distortion);
    cv::Mat grid(c.height + 1, c.width + 1, CV_64FC2);
    for (int v = 0; v <= c.height; ++v)
      for (int u = 0; u <= c.width; ++u) {
        const auto& q = corner_n[static_cast<std::size_t>(v) * static_cast<std::size_t>(c.width + 1) + static_cast<std::size_t>(u)];
        grid.at<cv::Vec2d>(v, u) = cv::Vec2d(q.x, q.y);
      }
    corners_.push_back(grid);
  }
}

Eigen::Vector2d StereoRenderer::project(int camera, const Eigen::Vector3d& p_CamR) const {
  if (camera == 1) return project_point(cameras_.right, p_CamR);
  return project_point(cameras_.left, cameras_.X_CamR_CamL.inverse() * p_CamR);
}

namespace {

// A faint texture fixed to the panel: smooth value noise on a 2 cm lattice.
double texture(double x, double y) {
  const auto hash = [](std::int64_t i, std::int64_t j) {
    std::uint64_t h = static_cast<std::uint64_t>(i) * 0x9E3779B97F4A7C15ULL ^ static_cast<std::uint64_t>(j) * 0xC2B2AE3D27D4EB4FULL;
    h ^= h >> 29;
    h *= 0xBF58476D1CE4E5B9ULL;
    h ^= h >> 32;
    return static_cast<double>(h & 0xFFFF) / 65535.0 * 2.0 - 1.0;
  };
  const double s = 50.0;  // cells per metre
  const double fx = x * s, fy = y * s;
  const auto i = static_cast<std::int64_t>(std::floor(fx)), j = static_cast<std::int64_t>(std::floor(fy));
  const double tx = fx - std::floor(fx), ty = fy - std::floor(fy);
  const double sx = tx * tx * (3 - 2 * tx), sy = ty * ty * (3 - 2 * ty);
  const double a = hash(i, j), b = hash(i + 1, j), c = hash(i, j + 1), d = hash(i + 1, j + 1);
  return (a * (1 - sx) + b * sx) * (1 - sy) + (c * (1 - sx) + d * sx) * sy;
}

// The closest approach of the ray {s d: s >= 0} (d unit, from the camera's centre) and the
// segment [a, b]: their distance, and how far along the ray it is. Alternating
// projection, twice: exact for a non-parallel pair, within a hair otherwise.
struct RaySegment {
  double distance = 0;
  double along = 0;
};
RaySegment ray_segment(const Eigen::Vector3d& d, const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  const Eigen::Vector3d v = b - a;
  const double vv = std::max(v.squaredNorm(), 1e-12);
  double s = std::max(0.0, d.dot(a));
  double t = 0;
  for (int k = 0; k < 2; ++k) {
    t = std::clamp((s * d - a).dot(v) / vv, 0.0, 1.0);
    s = std::max(0.0, d.dot(a + t * v));
  }
  return {(s * d - (a + t * v)).norm(), s};
}

// Distance along a unit ray from the camera's centre to a capsule (an occluder in that
// camera's frame), or -1 when it misses.
double hit_capsule(const Eigen::Vector3d& d, const Occluder& c) {
  const RaySegment r = ray_segment(d, c.a_CamR, c.b_CamR);
  if (r.distance >= c.radius) return -1;
  const double t = r.along - std::sqrt(c.radius * c.radius - r.distance * r.distance);
  return t > 0 ? t : -1;
}

}  // namespace

// Casts every sample ray of `camera` in the object's frame; `shade(o, d, d_Cam)` returns
// the grey of a ray (origin o and direction d in the object's frame, d_Cam in the
// camera's). Then averages the samples, blurs, exposes and adds the seeded noise.
template <typename Shade>
void StereoRenderer::cast(int camera, const Eigen::Isometry3d& X_CamR_Object, std::uint64_t seed, double exposure,
                          Shade&& shade, cv::Mat& out) const {
  const vision::CameraModel& c = camera == 0 ? cameras_.left : cameras_.right;
  const Eigen::Isometry3d X_Cam_CamR = camera == 0 ? cameras_.X_CamR_CamL.inverse() : Eigen::Isometry3d::Identity();
  const Eigen::Isometry3d X_Cam_Object = X_Cam_CamR * X_CamR_Object;
  const Eigen::Matrix3d R_Object_Cam = X_Cam_Object.linear().transpose();
  const Eigen::Vector3d o = -(R_Object_Cam * X_Cam_Object.translation());
  const cv::Mat& rays = rays_[static_cast<std::size_t>(camera)];
  cv::Mat fine(rays.rows, rays.cols, CV_32F);
  for (int v = 0; v < rays.rows; ++v) {
    const cv::Vec3f* rr = rays.ptr<cv::Vec3f>(v);
    float* row = fine.ptr<float>(v);
    for (int u = 0; u < rays.cols; ++u) {
      const Eigen::Vector3d d_Cam(rr[u][0], rr[u][1], rr[u][2]);
      row[u] = static_cast<float>(shade(o, R_Object_Cam * d_Cam, d_Cam) * exposure);
    }
  }
  cv::Mat image;
  cv::reduce(fine.reshape(1, c.width * c.height), image, 1, cv::REDUCE_AVG);  // the samples' mean, per pixel
  image = image.reshape(1, c.height);
  // Where a pixel's samples disagree, an edge or a corner crosses it: 8 samples place the
  // edge only to about 1/8 pixel there, so such a pixel is integrated again with 64
  // samples on a jittered 8x8 grid (the pattern fixed per pixel, like the sensor's).
  const cv::Mat& grid = corners_[static_cast<std::size_t>(camera)];
  for (int v = 0; v < c.height; ++v) {
    const float* samples = fine.ptr<float>(v);
    float* pixel = image.ptr<float>(v);
    for (int u = 0; u < c.width; ++u) {
      const auto [lo, hi] = std::minmax_element(samples + u * kSamples, samples + (u + 1) * kSamples);
      if (*hi - *lo <= kEdgeSpread * exposure) continue;
      double sum = 0;
      for_each_edge_ray(grid, camera, u, v, [&](const Eigen::Vector3d& d_Cam) { sum += shade(o, R_Object_Cam * d_Cam, d_Cam); });
      pixel[u] = static_cast<float>(sum / (kEdgeGrid * kEdgeGrid) * exposure);
    }
  }
  if (settings_.blur_sigma_px > 0) cv::GaussianBlur(image, image, cv::Size(0, 0), settings_.blur_sigma_px);
  if (settings_.noise_sigma > 0) {
    cv::RNG rng(seed * 2 + static_cast<std::uint64_t>(camera) + 1);
    cv::Mat noise(image.size(), CV_32F);
    rng.fill(noise, cv::RNG::NORMAL, 0.0, settings_.noise_sigma);
    image += noise;
  }
  image.convertTo(out, CV_8U);  // rounds and saturates
}

void StereoRenderer::render_view(int camera, const Panel& panel, const Eigen::Isometry3d& X_CamR_Panel, double exposure,
                                 std::uint64_t seed, const std::vector<Occluder>& occluders, cv::Mat& out) const {
  const Eigen::Isometry3d X_Cam_CamR = camera == 0 ? cameras_.X_CamR_CamL.inverse() : Eigen::Isometry3d::Identity();
  const Eigen::Matrix3d R_Panel_Cam = (X_Cam_CamR * X_CamR_Panel).linear().transpose();
  const Eigen::Vector3d light_Panel = (R_Panel_Cam * X_Cam_CamR.linear() * settings_.light_CamR).normalized();
  std::vector<Occluder> occ_Cam;
  for (const auto& o : occluders) occ_Cam.push_back(Occluder{X_Cam_CamR * o.a_CamR, X_Cam_CamR * o.b_CamR, o.radius, o.grey});
  const auto shade = [&](const Eigen::Vector3d& o_Panel, const Eigen::Vector3d& d, const Eigen::Vector3d& d_Cam) {
    double grey = settings_.background_grey;
    double depth = 1e9;
    const MeshHit hit = panel.surface->intersect(o_Panel, d);
    if (hit.hit()) {
      // The triangle's normal: the meshes' facets turn by milliradians, a tenth of a grey level.
      const double lambert = std::max(0.0, hit.normal.dot(light_Panel));
      grey = settings_.panel_grey * (0.55 + 0.45 * lambert) + settings_.texture_amplitude * texture(hit.p.x(), hit.p.y());
      depth = hit.t;
    }
    for (const auto& oc : occ_Cam) {
      const double to = hit_capsule(d_Cam, oc);
      if (to > 0 && to < depth) {
        depth = to;
        grey = oc.grey;
      }
    }
    return grey;
  };
  cast(camera, X_CamR_Panel, seed, exposure, shade, out);
}

bool hides(const Occluder& c, const Eigen::Vector3d& p_Cam) {
  const double range = p_Cam.norm();
  if (range < 1e-9) return false;
  const RaySegment r = ray_segment(p_Cam / range, c.a_CamR, c.b_CamR);
  return r.distance < c.radius && r.along < range;
}

void StereoRenderer::paint_view(int camera, const Occluder* occluders, std::size_t count, cv::Mat& image) const noexcept {
  const vision::CameraModel& c = camera == 0 ? cameras_.left : cameras_.right;
  if (image.type() != CV_8UC1 || image.cols != c.width || image.rows != c.height) return;
  const Eigen::Isometry3d X_Cam_CamR = camera == 0 ? cameras_.X_CamR_CamL.inverse() : Eigen::Isometry3d::Identity();
  const cv::Mat& rays = rays_[static_cast<std::size_t>(camera)];
  const double f = c.K(0, 0);
  for (std::size_t k = 0; k < count; ++k) {
    const Occluder& o = occluders[k];
    const Eigen::Vector3d a = X_Cam_CamR * o.a_CamR, b = X_Cam_CamR * o.b_CamR;
    if (a.z() < 0.1 || b.z() < 0.1) continue;  // at or behind the lens: not a rig arm
    // The image box: both ends' projections, grown by the radius at the nearer end.
    const Eigen::Vector2d pa = project_point(c, a), pb = project_point(c, b);
    const double grow = f * o.radius / std::min(a.z(), b.z()) + 3.0;
    const int u0 = std::max(0, static_cast<int>(std::floor(std::min(pa.x(), pb.x()) - grow)));
    const int u1 = std::min(c.width - 1, static_cast<int>(std::ceil(std::max(pa.x(), pb.x()) + grow)));
    const int v0 = std::max(0, static_cast<int>(std::floor(std::min(pa.y(), pb.y()) - grow)));
    const int v1 = std::min(c.height - 1, static_cast<int>(std::ceil(std::max(pa.y(), pb.y()) + grow)));
    const double pixel = std::max(a.z(), b.z()) / f * 1.5;  // a pixel's footprint at the capsule, generously
    for (int v = v0; v <= v1; ++v) {
      const cv::Vec3f* rr = rays.ptr<cv::Vec3f>(v);
      std::uint8_t* row = image.ptr<std::uint8_t>(v);
      for (int u = u0; u <= u1; ++u) {
        // The pixel's middle sample decides inside and outside; only edge pixels sample all 8.
        const cv::Vec3f& m = rr[u * kSamples + kSamples / 2];
        const double dm = ray_segment(Eigen::Vector3d(m[0], m[1], m[2]), a, b).distance;
        int covered = 0;
        if (dm < o.radius - pixel) covered = kSamples;
        else if (dm < o.radius + pixel)
          for (int sidx = 0; sidx < kSamples; ++sidx) {
            const cv::Vec3f& r = rr[u * kSamples + sidx];
            covered += ray_segment(Eigen::Vector3d(r[0], r[1], r[2]), a, b).distance < o.radius ? 1 : 0;
          }
        if (covered == 0) continue;
        if (covered == kSamples) {
          row[u] = o.grey;
          continue;
        }
        // An edge pixel: its 64 samples, as the ray-caster takes them.
        covered = 0;
        for_each_edge_ray(corners_[static_cast<std::size_t>(camera)], camera, u, v,
                          [&](const Eigen::Vector3d& d) { covered += ray_segment(d, a, b).distance < o.radius ? 1 : 0; });
        constexpr int kEdge = kEdgeGrid * kEdgeGrid;
        row[u] = static_cast<std::uint8_t>((row[u] * (kEdge - covered) + o.grey * covered + kEdge / 2) / kEdge);
      }
    }
  }
}

void StereoRenderer::paint_occluders(const Occluder* occluders, std::size_t count, cv::Mat& left, cv::Mat& right) const noexcept {
  paint_view(0, occluders, count, left);
  paint_view(1, occluders, count, right);
}

void StereoRenderer::render_board(int cols, int rows, double square, const Eigen::Isometry3d& X_CamR_Board,
                                  std::uint64_t seed, cv::Mat& left, cv::Mat& right) const {
  // Printed black on white, one white square of margin around the pattern.
  const double x0 = -2 * square, x1 = (cols + 1) * square, y0 = -2 * square, y1 = (rows + 1) * square;
  const auto shade = [&](const Eigen::Vector3d& o, const Eigen::Vector3d& d, const Eigen::Vector3d&) {
    if (std::abs(d.z()) < 1e-12) return settings_.background_grey;
    const double t = -o.z() / d.z();
    if (t <= 0) return settings_.background_grey;
    const double x = o.x() + t * d.x(), y = o.y() + t * d.y();
    if (x < x0 || x > x1 || y < y0 || y > y1) return settings_.background_grey;
    if (x < -square || x > cols * square || y < -square || y > rows * square) return 220.0;  // margin
    const auto i = static_cast<long>(std::floor(x / square)), j = static_cast<long>(std::floor(y / square));
    return ((i + j) & 1) == 0 ? 20.0 : 220.0;
  };
  cast(0, X_CamR_Board, seed, 1.0, shade, left);
  cast(1, X_CamR_Board, seed, 1.0, shade, right);
}

void StereoRenderer::render(const Panel& panel, const Eigen::Isometry3d& X_CamR_Panel, double exposure, std::uint64_t seed,
                            const std::vector<Occluder>& occluders, cv::Mat& left, cv::Mat& right) const {
  render_view(0, panel, X_CamR_Panel, exposure, seed, occluders, left);
  render_view(1, panel, X_CamR_Panel, exposure, seed, occluders, right);
}

}  // namespace markcell::rig
