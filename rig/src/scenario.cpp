#include "markcell/rig/scenario.hpp"
#include "markcell/host/stop_signal.hpp"

#include <cmath>
#include <random>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <stdexcept>

#include "markcell/vision/recording.hpp"

namespace markcell::rig {

// The rig runs the service's cell: its configuration, its cell and their helpers.
using namespace markcell::host;

namespace {

Eigen::Isometry3d facing(double x, double y, double z) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::Vector3d(1, -1, -1).asDiagonal();  // panel y up, z towards the cameras
  X.translation() = Eigen::Vector3d(x, y, z);
  return X;
}

// The middle between the marking station's cameras, 3.1 m away: the paper's set-up.
constexpr double kCentreX = -0.2225;
constexpr double kDistance = 3.1;

Scenario paper_line(const std::string& name, const std::string& panel, std::uint64_t seed) {
  Scenario s;
  s.name = name;
  s.panel_type = panel;
  s.seed = seed;
  s.speed.kind = SpeedKind::kFluctuating;
  s.speed.min_speed = 0.012;
  s.speed.max_speed = 0.016;
  s.speed.seed = seed;
  s.duration = seconds(36);
  // About half a metre of travel in 36 s. Both views overlap over about 1.29 m at 3.1 m;
  // the 1.1 m door fits whole only over 19 cm of it, so it starts with its trailing
  // corners just outside the right view and ends with its leading ones outside the left.
  s.path.X_CamR_Line = facing(kCentreX - 0.14, 0.0, kDistance);
  Eigen::Isometry3d X_SL_Panel = facing(0.15, 0.02, 2.0);
  X_SL_Panel.linear() = X_SL_Panel.linear() * Eigen::AngleAxisd(0.08, Eigen::Vector3d::UnitY()).toRotationMatrix();
  s.X_SL_Panel = X_SL_Panel;
  return s;
}

}  // namespace

const std::vector<std::string>& scenario_names() {
  static const std::vector<std::string> kNames = {"paper-door", "paper-fender", "paper-curved", "line-fast",
                                                  "occlusion-person", "frame-drops", "nine-defects",
                                                  "calibration-board"};
  return kNames;
}

Scenario make_scenario(const std::string& name, std::uint64_t seed) {
  if (name == "paper-door" || name == "occlusion-person" || name == "frame-drops" || name == "paper-curved") {
    Scenario s = paper_line(name, "door", seed);
    s.defects = {{1, 0.12, -0.12}, {2, -0.18, -0.22}, {3, 0.38, -0.25}};  // three dings about 30 cm apart
    if (name == "occlusion-person")
      // Across the view at a brisk walk while the dings are marked (the first spray comes
      // about 0.7 s in): in front of the door's MFs from about 0.6 to 2.2 s.
      s.people = {{seconds(0), seconds(3), Eigen::Vector3d(-1.4, -0.1, 2.2), Eigen::Vector3d(1.0, -0.1, 2.2)}};
    if (name == "frame-drops") {
      s.drop_ratio = 0.10;
      s.drop_burst_start = 45;  // half a second lost 1.5 s in, while the arm approaches
      s.drop_burst_length = 15;
    }
    if (name == "paper-curved") {
      s.path.curve_start_m = 0.02;  // turning while the dings are marked
      s.path.curvature = 0.35;  // turns up to about 8 degrees about the vertical axis
    }
    return s;
  }
  if (name == "paper-fender") {
    Scenario s = paper_line(name, "fender", seed);
    s.defects = {{1, -0.25, 0.15}, {2, 0.05, 0.20}, {3, 0.30, -0.05}, {4, 0.0, -0.20}};
    return s;
  }
  if (name == "line-fast") {
    Scenario s = paper_line(name, "door", seed);
    s.speed.min_speed = 0.135;
    s.speed.max_speed = 0.165;
    // From entering the right camera's view to leaving the left one's: about 2.4 m.
    s.path.X_CamR_Line = facing(-1.45, 0.0, kDistance);
    s.duration = seconds(16);
    s.defects = {{1, 0.12, -0.12}, {2, -0.18, -0.22}, {3, 0.38, -0.25}};
    return s;
  }
  if (name == "nine-defects") {
    Scenario s = paper_line(name, "door", seed);
    int id = 1;
    for (double y : {-0.28, -0.06})  // two rows below the window, one beside it
      for (double x : {-0.45, -0.15, 0.15, 0.45}) s.defects.push_back({id++, x, y});
    s.defects.push_back({id, 0.42, 0.22});
    return s;
  }
  std::string known;
  if (name == "calibration-board") {
    Scenario s;
    s.name = name;
    s.seed = seed;
    s.board_only = true;
    std::mt19937_64 rng(seed * 7919 + 17);
    std::uniform_real_distribution<double> t(-0.02, 0.02), a(-1.0, 1.0);
    const Eigen::Vector3d axis = Eigen::Vector3d(a(rng), a(rng), a(rng)).normalized();
    s.X_CamRnominal_CamR.linear() = Eigen::AngleAxisd(0.015 * (0.5 + 0.5 * std::abs(a(rng))), axis).toRotationMatrix();
    s.X_CamRnominal_CamR.translation() = Eigen::Vector3d(t(rng), t(rng), t(rng));
    return s;
  }
  for (const auto& n : scenario_names()) known += (known.empty() ? "" : ", ") + n;
  throw std::invalid_argument("unknown scenario '" + name + "' (known: " + known + ")");
}

vision::PanelTypeModel reference_panel_type(const Scenario& s, const rig::Panel& panel, const vision::StereoCalibration& marking,
                                            const rig::RenderSettings& render, cv::Mat* reference_left) {
  Eigen::Isometry3d X_CamR_Panel = s.path.X_CamR_Line;
  X_CamR_Panel.translation().x() = marking.X_CamR_CamL.translation().x();  // in front of the left camera
  const rig::StereoRenderer renderer(marking, render);
  cv::Mat left, right;
  renderer.render(panel, X_CamR_Panel, 1.0, s.seed * 7919ULL + 17, {}, left, right);
  std::vector<Eigen::Vector2d> px;
  for (const auto& mf : panel.macro_features) px.push_back(renderer.project(0, X_CamR_Panel * mf));
  if (reference_left != nullptr) *reference_left = left;
  // The line may bring the panel anywhere along its travel into view: search wide.
  return vision::make_panel_type(s.panel_type, left, px, 2, 400, 40);
}

bool frame_dropped(const Scenario& s, std::uint64_t index) {
  if (s.drop_burst_length > 0 && index >= s.drop_burst_start && index < s.drop_burst_start + s.drop_burst_length)
    return true;
  if (s.drop_ratio <= 0) return false;
  std::uint64_t h = (index + 1) * 0x9E3779B97F4A7C15ULL ^ s.seed * 0xD1B54A32D192ED03ULL;
  h ^= h >> 31;
  h *= 0xBF58476D1CE4E5B9ULL;
  h ^= h >> 29;
  return static_cast<double>(h % 1'000'000) < s.drop_ratio * 1'000'000;
}

std::size_t generate_recording(const Scenario& s, const rig::Panel& panel, const std::string& folder,
                               const vision::StereoCalibration& marking, const vision::StereoCalibration& scanner,
                               const rig::RenderSettings& render, const GenerateOptions& options) {
  if (s.board_only)
    throw std::invalid_argument("scenario '" + s.name + "' has no panel to record: markcell calibrate-base runs it");
  if (panel.name != s.panel_type)
    throw std::invalid_argument("scenario '" + s.name + "' is of a " + s.panel_type + ", not of the panel '" + panel.name + "' given");
  const Nanos duration = options.max_duration > 0 ? std::min(options.max_duration, s.duration) : s.duration;
  const double fps = options.fps > 0 ? options.fps : s.fps;
  const LineMotion motion(s.speed, s.path, s.duration);
  const rig::StereoRenderer renderer(marking, render);

  vision::RecordingManifest m;
  m.station = "marking";
  m.panel_type = s.panel_type;
  m.frame_rate_hz = fps;
  m.image_width = marking.left.width;
  m.image_height = marking.left.height;
  m.calibration = "stereo.yaml";
  m.seed = s.seed;
  m.scenario = s.name;
  m.generator = std::string(kRigGenerator);
  // The panel's surface goes with the recording: the replay scores sprays on it.
  const std::string mesh_ext = std::filesystem::path(panel.mesh_file).extension().string();
  m.panel_mesh = "panel" + mesh_ext;
  m.panel_mesh_metres_per_unit = panel.mesh_metres_per_unit;
  m.macro_features_Panel = panel.macro_features;
  std::size_t written = 0;
  {
    vision::RecordingWriter writer(folder, m);
    const auto frames = static_cast<std::uint64_t>(std::floor(to_seconds(duration) * fps)) + 1;
    for (std::uint64_t i = 0; i < frames; ++i) {
      if (const int sig = options.stop != nullptr ? options.stop->load(std::memory_order_acquire) : 0; sig != 0)
        throw GenerationStopped(folder + ": rendering stopped by " + signal_name(sig) + " after " + std::to_string(i) + " of " +
                                    std::to_string(frames) + " frames; the folder is not a recording (no recording.yaml)",
                                sig);
      const Nanos t = static_cast<Nanos>(std::llround(static_cast<double>(i) * 1e9 / fps));
      const Eigen::Isometry3d X = motion.X_CamR_Panel(t);
      writer.add_truth(i, t, X);
      if (frame_dropped(s, i)) continue;
      std::vector<rig::Occluder> occluders;
      for (const auto& p : s.people) {
        if (t < p.enter || t > p.leave) continue;
        const double f = static_cast<double>(t - p.enter) / static_cast<double>(p.leave - p.enter);
        const Eigen::Vector3d mid = p.from_CamR + f * (p.to_CamR - p.from_CamR);
        occluders.push_back({mid + Eigen::Vector3d(0, -0.45, 0), mid + Eigen::Vector3d(0, 0.45, 0), 0.2, 55});  // torso
        occluders.push_back({mid + Eigen::Vector3d(0, -0.75, 0), mid + Eigen::Vector3d(0, -0.65, 0), 0.12, 70});  // head
      }
      const double exposure = 1.0 + s.exposure_drift * std::sin(2 * M_PI * to_seconds(t) / 20.0);
      cv::Mat left, right;
      renderer.render(panel, X, exposure, s.seed * 1'000'003ULL + i, occluders, left, right);
      writer.add(i, t, left, right);
      ++written;
    }
    std::vector<vision::TruthDefect> truth;
    for (const auto& d : s.defects) truth.push_back({d.id, panel.surface_point(d.x, d.y), s.inspection.ding_radius});
    writer.set_defects(truth);
  }
  vision::save_stereo_calibration((std::filesystem::path(folder) / "stereo.yaml").string(), marking);
  std::filesystem::copy_file(panel.mesh_file, std::filesystem::path(folder) / m.panel_mesh,
                             std::filesystem::copy_options::overwrite_existing);

  // The inspection station's record for this panel, as it would send it.
  const InspectionRecord rec =
      simulate_inspection(s.name + "-" + std::to_string(s.seed), panel, s.defects, scanner, s.X_SL_Panel, s.inspection, s.seed);
  std::ofstream out(std::filesystem::path(folder) / "inspection.yaml");
  out << std::setprecision(9) << "panel_id: " << rec.panel_id << "\npanel_type: " << rec.panel_type
      << "\nframe: CamL_SL\nunits: m\nmacro_features:\n";
  for (const auto& p : rec.macro_features_SL) out << "  - [" << p.x() << ", " << p.y() << ", " << p.z() << "]\n";
  out << "defects:\n";
  for (const auto& d : rec.defects) {
    out << "  - id: " << d.id << "\n    points:\n";
    for (const auto& p : d.points_SL) out << "      - [" << p.x() << ", " << p.y() << ", " << p.z() << "]\n";
  }
  out << "...\n";  // the end of the record: a drop folder takes only a finished one
  return written;
}

}  // namespace markcell::rig
