#pragma once
// Synthetic views of the marking station's stereo pair: the rig's cameras.
//
// A panel is its mesh (panel.hpp), painted uniform grey e-coat with mild shading and a
// faint fixed texture, in front of a plain background. Each pixel's centre is ray-cast
// through the camera model (distortion included), pixels an edge crosses at 64 samples
// (render.cpp says why that is the pixel's area integral), then the image is blurred,
// scaled by the exposure and given sensor noise from a seeded generator: the same seed
// gives the same image.
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "markcell/rig/panel.hpp"
#include "markcell/vision/calibration_io.hpp"

namespace markcell::rig {

// A round obstacle between the cameras and the panel (the robot arm's links, a person):
// a capsule from a to b with the given radius, in the right camera's frame.
struct Occluder {
  Eigen::Vector3d a_CamR, b_CamR;
  double radius = 0.05;
  std::uint8_t grey = 25;
};

// True when the capsule (in a camera's frame) lies on the line of sight from that
// camera's centre to the point p_Cam, in front of it.
bool hides(const Occluder& capsule_Cam, const Eigen::Vector3d& p_Cam);

struct RenderSettings {
  double panel_grey = 150;      // e-coat albedo as the grey level under full light
  double background_grey = 40;
  double texture_amplitude = 3; // faint fixed texture of the e-coat, grey levels
  double blur_sigma_px = 0.6;   // optics; 0: none
  double noise_sigma = 1.5;     // sensor noise, grey levels; 0: none
  Eigen::Vector3d light_CamR{0.3, -1.0, -1.2};  // towards the light, camera frame: above, beside the cameras
  int threads = 1;              // 2: the two views on two threads (sim); the images do not depend on it
  bool every_pixel_at_64 = false;  // every pixel integrated at 64 samples: the slow reference of the tests
};

class StereoRenderer {
 public:
  StereoRenderer(vision::StereoCalibration cameras, RenderSettings settings);
  const vision::StereoCalibration& cameras() const { return cameras_; }
  // Renders both views of `panel` at X_CamR_Panel. `exposure` scales the light (1 =
  // nominal); `seed` makes the noise of this frame.
  void render(const Panel& panel, const Eigen::Isometry3d& X_CamR_Panel, double exposure, std::uint64_t seed,
              const std::vector<Occluder>& occluders, cv::Mat& left, cv::Mat& right) const;
  // A flat chessboard (calibration target): `cols` x `rows` inner corners, squares of
  // `square` metres, one white square of margin; its frame has the first inner corner
  // at the origin, x along the columns, y along the rows, z out of the printed face.
  void render_board(int cols, int rows, double square, const Eigen::Isometry3d& X_CamR_Board, std::uint64_t seed,
                    cv::Mat& left, cv::Mat& right) const;
  // Paints capsules (CamR frame) over two existing views, in front of whatever they show
  // (the rig's arm is always between the cameras and the panel): 64 samples per pixel at
  // their edges, flat grey, no noise. Bounded (the capsules' image boxes) and
  // allocation-free: for drawing the simulated arm into replayed frames in closed loop.
  void paint_occluders(const Occluder* occluders, std::size_t count, cv::Mat& left, cv::Mat& right) const noexcept;
  // Where the camera model puts a point (camera 0 = left, 1 = right), distortion included.
  Eigen::Vector2d project(int camera, const Eigen::Vector3d& p_CamR) const;

 private:
  struct Shaded {
    double grey;
    std::uint32_t label;  // what the ray met: pixels whose centres differ in it are edge pixels
  };
  template <typename Shade>
  void cast(int camera, const Eigen::Isometry3d& X_CamR_Object, std::uint64_t seed, double exposure, Shade&& shade,
            cv::Mat& out) const;
  void paint_view(int camera, const Occluder* occluders, std::size_t count, cv::Mat& image) const noexcept;
  void render_view(int camera, const Panel& panel, const Eigen::Isometry3d& X_CamR_Panel, double exposure,
                   std::uint64_t seed, const std::vector<Occluder>& occluders, cv::Mat& out) const;
  vision::StereoCalibration cameras_;
  RenderSettings settings_;
  // The unit ray through every pixel's centre, per camera, in that camera's frame, row-major.
  std::vector<std::vector<Eigen::Vector3d>> centres_;
  // Normalised image coordinates of every pixel corner, per camera (edge pixels' samples).
  std::vector<cv::Mat> corners_;  // CV_64FC2, (h + 1) x (w + 1)
};

// The pinhole-plus-Brown-Conrady model of one camera (k1 k2 p1 p2 k3), as OpenCV's.
Eigen::Vector2d project_point(const vision::CameraModel& camera, const Eigen::Vector3d& p_Cam);

}  // namespace markcell::rig
