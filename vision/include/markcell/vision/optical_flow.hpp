#pragma once
// Bounded-time image primitives of the tracker, with storage fixed at construction:
// a Gaussian image pyramid, pyramidal Lucas-Kanade for single points (Bouguet's
// formulation, as cv::calcOpticalFlowPyrLK), Shi-Tomasi sub-pixel corner refinement (the
// gradient-orthogonality iteration of cv::cornerSubPix) and normalised cross-correlation
// of small patches. OpenCV's own functions allocate on every call; these never do.
#include <array>
#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace markcell::vision {

inline constexpr int kMaxPyramidLevels = 4;
inline constexpr int kMaxLkRadius = 15;  // half window: up to 31x31 pixels

// A single-channel float image pyramid. Level 0 is the input; each level above it is
// blurred with the 5-tap binomial kernel and halved (cv::pyrDown's filter).
class Pyramid {
 public:
  Pyramid(int width, int height, int levels);
  // Builds every level from an 8-bit image of the constructed size. Allocation-free.
  void build(const cv::Mat& gray8);
  int levels() const { return levels_; }
  int width(int level) const { return w_[static_cast<std::size_t>(level)]; }
  int height(int level) const { return h_[static_cast<std::size_t>(level)]; }
  const float* row(int level, int y) const { return data_[static_cast<std::size_t>(level)].data() + static_cast<std::size_t>(y) * static_cast<std::size_t>(width(level)); }
  float at(int level, int x, int y) const { return row(level, y)[x]; }
  // Bilinear sample; the caller keeps (x, y) at least one pixel inside the image.
  float sample(int level, double x, double y) const;
  bool inside(int level, double x, double y, double margin) const {
    return x >= margin && y >= margin && x <= width(level) - 1 - margin && y <= height(level) - 1 - margin;
  }

 private:
  int levels_;
  std::array<int, kMaxPyramidLevels> w_{}, h_{};
  std::array<std::vector<float>, kMaxPyramidLevels> data_;
  std::vector<float> scratch_;
};

struct LkParams {
  int radius = 10;            // half window, pixels (21x21 as OpenCV's default)
  int max_iterations = 30;
  double epsilon = 0.01;      // stop when the update is below this, pixels
  double min_eigen = 1e-4;    // of the window's gradient matrix / window area (OpenCV's minEigThreshold)
  int max_levels = 0;         // use at most this many pyramid levels (0: all); a close guess needs only level 0
};

enum class LkStatus : std::uint8_t { kOk, kOutside, kFlat };

struct LkResult {
  LkStatus status = LkStatus::kOutside;
  Eigen::Vector2d point = Eigen::Vector2d::Zero();
  double error = 0;  // mean absolute difference over the window, grey levels
};

// Where the point `p` of `from` is in `to`, starting from `guess` (both level-0 pixels).
LkResult track_point(const Pyramid& from, const Pyramid& to, const Eigen::Vector2d& p, const Eigen::Vector2d& guess,
                     const LkParams& params);

// Moves `p` to the sub-pixel corner nearby: iterates q = (sum G)^-1 sum G x over a
// (2 radius + 1)^2 window, G the gradient outer products. Returns false when the window
// leaves the image or has no corner (singular system).
bool refine_corner(const Pyramid& image, Eigen::Vector2d& p, int radius, int max_iterations = 20, double epsilon = 0.01);

// The Shi-Tomasi score (smaller eigenvalue of the gradient matrix, per pixel) at an
// integer pixel of level 0.
double shi_tomasi(const Pyramid& image, int x, int y, int radius);

// A small square patch of a pyramid level, sampled at sub-pixel positions.
inline constexpr int kMaxPatchRadius = 10;
struct Patch {
  int radius = 0;
  std::array<float, (2 * kMaxPatchRadius + 1) * (2 * kMaxPatchRadius + 1)> v{};
};
// False when the patch would leave the image.
bool extract_patch(const Pyramid& image, int level, const Eigen::Vector2d& centre, int radius, Patch& out);
// Normalised cross-correlation of a patch with the image at an integer position of
// `level`; -1 when outside or flat.
double ncc(const Patch& patch, const Pyramid& image, int level, int cx, int cy);

}  // namespace markcell::vision
