#include "markcell/rig/render.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <exception>
#include <stdexcept>
#include <thread>

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
// A pixel integrates light over its area. Inside a surface the shading is smooth at the
// scale of a pixel (a 2 cm texture, facets that turn by milliradians), so the ray
// through the pixel's centre gives its mean to second order. Where an edge crosses a
// pixel (its centre's ray meets another thing, or another grey, than a neighbour's) the
// pixel is integrated with kEdgeGrid^2 jittered samples, the pattern fixed per pixel:
// one pattern shared by every pixel would quantise an axis-aligned edge to steps of
// 1/kEdgeGrid pixel in every pixel along it alike, a bias no window averages away; a
// pattern of its own per pixel makes that error independent from pixel to pixel.
constexpr int kEdgeGrid = 8;         // an edge pixel's samples: kEdgeGrid^2
constexpr float kEdgeSpread = 2.0f;  // grey levels between neighbours' centres that mark an edge

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
    pixels.reserve(static_cast<std::size_t>(c.width) * static_cast<std::size_t>(c.height));
    for (int v = 0; v < c.height; ++v)
      for (int u = 0; u < c.width; ++u) pixels.emplace_back(static_cast<float>(u), static_cast<float>(v));
    cv::Mat K;
    cv::eigen2cv(c.K, K);
    std::vector<cv::Point2f> normalised;
    cv::undistortPoints(pixels, normalised, K, c.distortion.empty() ? cv::Mat() : c.distortion);
    std::vector<Eigen::Vector3d> rays;
    rays.reserve(normalised.size());
    for (const auto& q : normalised) rays.push_back(Eigen::Vector3d(q.x, q.y, 1.0).normalized());
    centres_.push_back(std::move(rays));
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

// Casts the centre ray of every pixel of `camera` in the object's frame, row by row:
// `shade(o, d, d_Cam, n, out)` shades n rays (origin o and directions d in the object's
// frame, d_Cam in the camera's) into out. Pixels whose centre differs from a neighbour's
// (another label, or another grey by more than kEdgeSpread) are integrated again with
// kEdgeGrid^2 samples. Then blurs, exposes and adds the seeded noise.
template <typename Shade>
void StereoRenderer::cast(int camera, const Eigen::Isometry3d& X_CamR_Object, std::uint64_t seed, double exposure,
                          Shade&& shade, cv::Mat& out) const {
  const vision::CameraModel& c = camera == 0 ? cameras_.left : cameras_.right;
  const Eigen::Isometry3d X_Cam_CamR = camera == 0 ? cameras_.X_CamR_CamL.inverse() : Eigen::Isometry3d::Identity();
  const Eigen::Isometry3d X_Cam_Object = X_Cam_CamR * X_CamR_Object;
  const Eigen::Matrix3d R_Object_Cam = X_Cam_Object.linear().transpose();
  const Eigen::Vector3d o = -(R_Object_Cam * X_Cam_Object.translation());
  const std::vector<Eigen::Vector3d>& rays = centres_[static_cast<std::size_t>(camera)];
  const auto w = static_cast<std::size_t>(c.width);
  cv::Mat image(c.height, c.width, CV_32F);
  std::vector<std::uint32_t> label(w * static_cast<std::size_t>(c.height));
  std::vector<Eigen::Vector3d> d(w);
  std::vector<Shaded> shaded(w);
  for (int v = 0; v < c.height; ++v) {
    const Eigen::Vector3d* d_Cam = rays.data() + static_cast<std::size_t>(v) * w;
    for (std::size_t u = 0; u < w; ++u) d[u] = R_Object_Cam * d_Cam[u];
    shade(o, d.data(), d_Cam, w, shaded.data());
    float* row = image.ptr<float>(v);
    for (std::size_t u = 0; u < w; ++u) {
      row[u] = static_cast<float>(shaded[u].grey * exposure);
      label[static_cast<std::size_t>(v) * w + u] = shaded[u].label;
    }
  }
  // Edge pixels: both pixels of any neighbouring pair (along a row, a column or a
  // diagonal) whose centres disagree.
  cv::Mat edge(c.height, c.width, CV_8U, cv::Scalar(settings_.every_pixel_at_64 ? 1 : 0));
  const float spread = kEdgeSpread * static_cast<float>(exposure);
  const auto differ = [&](int v0, int u0, int v1, int u1) {
    if (v1 < 0 || v1 >= c.height || u1 < 0 || u1 >= c.width) return;
    const std::size_t i0 = static_cast<std::size_t>(v0) * w + static_cast<std::size_t>(u0);
    const std::size_t i1 = static_cast<std::size_t>(v1) * w + static_cast<std::size_t>(u1);
    if (label[i0] != label[i1] || std::abs(image.at<float>(v0, u0) - image.at<float>(v1, u1)) > spread) {
      edge.at<std::uint8_t>(v0, u0) = 1;
      edge.at<std::uint8_t>(v1, u1) = 1;
    }
  };
  for (int v = 0; v < c.height; ++v)
    for (int u = 0; u < c.width; ++u) {
      differ(v, u, v, u + 1);
      differ(v, u, v + 1, u);
      differ(v, u, v + 1, u + 1);
      differ(v, u, v + 1, u - 1);
    }
  const cv::Mat& grid = corners_[static_cast<std::size_t>(camera)];
  constexpr int kEdgeSamples = kEdgeGrid * kEdgeGrid;
  std::array<Eigen::Vector3d, kEdgeSamples> e_Cam, e;
  std::array<Shaded, kEdgeSamples> e_shaded;
  for (int v = 0; v < c.height; ++v) {
    const std::uint8_t* is_edge = edge.ptr<std::uint8_t>(v);
    float* pixel = image.ptr<float>(v);
    for (int u = 0; u < c.width; ++u) {
      if (is_edge[u] == 0) continue;
      std::size_t k = 0;
      for_each_edge_ray(grid, camera, u, v, [&](const Eigen::Vector3d& d_Cam) { e_Cam[k++] = d_Cam; });
      for (std::size_t i = 0; i < e.size(); ++i) e[i] = R_Object_Cam * e_Cam[i];
      shade(o, e.data(), e_Cam.data(), e.size(), e_shaded.data());
      double sum = 0;
      for (const Shaded& x : e_shaded) sum += x.grey;
      pixel[u] = static_cast<float>(sum / kEdgeSamples * exposure);
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
  std::vector<MeshHit> hits;
  // Labels: 0 the background, 1 the panel, 2 + k occluder k.
  const auto shade = [&](const Eigen::Vector3d& o_Panel, const Eigen::Vector3d* d, const Eigen::Vector3d* d_Cam, std::size_t n,
                         Shaded* shaded) {
    hits.resize(n);
    panel.surface->intersect(o_Panel, d, n, hits.data());
    for (std::size_t i = 0; i < n; ++i) {
      Shaded s{settings_.background_grey, 0};
      double depth = 1e9;
      const MeshHit& hit = hits[i];
      if (hit.hit()) {
        // The triangle's normal: the meshes' facets turn by milliradians, a tenth of a grey level.
        const double lambert = std::max(0.0, hit.normal.dot(light_Panel));
        s = {settings_.panel_grey * (0.55 + 0.45 * lambert) + settings_.texture_amplitude * texture(hit.p.x(), hit.p.y()), 1};
        depth = hit.t;
      }
      for (std::size_t k = 0; k < occ_Cam.size(); ++k) {
        const double to = hit_capsule(d_Cam[i], occ_Cam[k]);
        if (to > 0 && to < depth) {
          depth = to;
          s = {static_cast<double>(occ_Cam[k].grey), static_cast<std::uint32_t>(2 + k)};
        }
      }
      shaded[i] = s;
    }
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
  const std::vector<Eigen::Vector3d>& rays = centres_[static_cast<std::size_t>(camera)];
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
      const Eigen::Vector3d* rr = rays.data() + static_cast<std::size_t>(v) * static_cast<std::size_t>(c.width);
      std::uint8_t* row = image.ptr<std::uint8_t>(v);
      for (int u = u0; u <= u1; ++u) {
        // The pixel's centre decides inside and outside; pixels near the outline take the
        // 64 samples the ray-caster takes at an edge.
        const double dm = ray_segment(rr[u], a, b).distance;
        if (dm >= o.radius + pixel) continue;
        if (dm < o.radius - pixel) {
          row[u] = o.grey;
          continue;
        }
        // Near the outline: its 64 samples, as the ray-caster takes them at an edge.
        int covered = 0;
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
  // Labels: 0 the background, 1 the margin and white squares, 2 the black squares.
  const auto shade_one = [&](const Eigen::Vector3d& o, const Eigen::Vector3d& d) -> Shaded {
    const Shaded background{settings_.background_grey, 0};
    if (std::abs(d.z()) < 1e-12) return background;
    const double t = -o.z() / d.z();
    if (t <= 0) return background;
    const double x = o.x() + t * d.x(), y = o.y() + t * d.y();
    if (x < x0 || x > x1 || y < y0 || y > y1) return background;
    if (x < -square || x > cols * square || y < -square || y > rows * square) return {220.0, 1};  // margin
    const auto i = static_cast<long>(std::floor(x / square)), j = static_cast<long>(std::floor(y / square));
    return ((i + j) & 1) == 0 ? Shaded{20.0, 2} : Shaded{220.0, 1};
  };
  const auto shade = [&](const Eigen::Vector3d& o, const Eigen::Vector3d* d, const Eigen::Vector3d*, std::size_t n, Shaded* out) {
    for (std::size_t i = 0; i < n; ++i) out[i] = shade_one(o, d[i]);
  };
  cast(0, X_CamR_Board, seed, 1.0, shade, left);
  cast(1, X_CamR_Board, seed, 1.0, shade, right);
}

void StereoRenderer::render(const Panel& panel, const Eigen::Isometry3d& X_CamR_Panel, double exposure, std::uint64_t seed,
                            const std::vector<Occluder>& occluders, cv::Mat& left, cv::Mat& right) const {
  if (settings_.threads < 2) {
    render_view(0, panel, X_CamR_Panel, exposure, seed, occluders, left);
    render_view(1, panel, X_CamR_Panel, exposure, seed, occluders, right);
    return;
  }
  // The right view on a second thread: each view is a function of its own inputs alone,
  // so the images are those of one thread. An exception there is carried back here.
  std::exception_ptr failed;
  std::thread second([&] {
    try {
      render_view(1, panel, X_CamR_Panel, exposure, seed, occluders, right);
    } catch (...) {
      failed = std::current_exception();
    }
  });
  try {
    render_view(0, panel, X_CamR_Panel, exposure, seed, occluders, left);
  } catch (...) {
    second.join();
    throw;
  }
  second.join();
  if (failed) std::rethrow_exception(failed);
}

}  // namespace markcell::rig
