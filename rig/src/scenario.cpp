#include "markcell/rig/scenario.hpp"
#include "markcell/host/stop_signal.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <stdexcept>

#include <yaml-cpp/yaml.h>

#include "markcell/common/bounded_file.hpp"
#include "markcell/common/confined_path.hpp"
#include "markcell/common/splitmix.hpp"
#include "markcell/vision/recording.hpp"

namespace markcell::rig {

// The rig runs the service's cell: its configuration, its cell and their helpers.
using namespace markcell::host;

namespace {

constexpr std::size_t kMaxScenarioBytes = 1 << 20;
constexpr std::size_t kMaxDefects = 64, kMaxPeople = 16;

// A strict reader of one scenario file: every key known, every value in its range, each
// error naming the file, the line and the key.
class ScenarioReader {
 public:
  explicit ScenarioReader(std::string file) : file_(std::move(file)) {}

  [[noreturn]] void fail(const YAML::Node& at, const std::string& key, const std::string& what) const {
    std::string where = file_;
    if (at.IsDefined() && at.Mark().line >= 0) where += ":" + std::to_string(at.Mark().line + 1);
    throw std::runtime_error(where + ": " + (key.empty() ? "" : key + ": ") + what);
  }
  // A map whose keys are all among `known`.
  void map(const YAML::Node& n, const std::string& key, std::initializer_list<std::string_view> known) const {
    if (!n.IsMap()) fail(n, key, "must be a map of keys");
    for (const auto& kv : n) {
      const std::string k = kv.first.as<std::string>();
      if (std::find(known.begin(), known.end(), k) == known.end()) {
        std::string list;
        for (const auto& x : known) list += (list.empty() ? "" : ", ") + std::string(x);
        fail(kv.first, join(key, k), "unknown key (known: " + list + ")");
      }
    }
  }
  static std::string join(const std::string& a, const std::string& b) { return a.empty() ? b : a + "." + b; }
  YAML::Node need(const YAML::Node& n, const std::string& parent, const char* key) const {
    const YAML::Node v = n[key];
    if (!v.IsDefined() || v.IsNull()) fail(n, join(parent, key), "missing");
    return v;
  }
  double number(const YAML::Node& v, const std::string& key, double lo, double hi) const {
    double x = 0;
    if (!v.IsScalar() || !YAML::convert<double>::decode(v, x) || !std::isfinite(x))
      fail(v, key, "must be a number, not '" + (v.IsScalar() ? v.Scalar() : std::string("a list or map")) + "'");
    if (x < lo || x > hi) fail(v, key, std::to_string(x) + " is outside [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
    return x;
  }
  double number(const YAML::Node& n, const std::string& parent, const char* key, double lo, double hi) const {
    return number(need(n, parent, key), join(parent, key), lo, hi);
  }
  double number_or(const YAML::Node& n, const std::string& parent, const char* key, double lo, double hi, double dflt) const {
    const YAML::Node v = n[key];
    return v.IsDefined() && !v.IsNull() ? number(v, join(parent, key), lo, hi) : dflt;
  }
  std::uint64_t count(const YAML::Node& v, const std::string& key, std::uint64_t hi) const {
    std::uint64_t x = 0;
    if (!v.IsScalar() || !YAML::convert<std::uint64_t>::decode(v, x) || v.Scalar().find_first_not_of("0123456789") != std::string::npos)
      fail(v, key, "must be a whole number >= 0, not '" + (v.IsScalar() ? v.Scalar() : std::string("a list or map")) + "'");
    if (x > hi) fail(v, key, std::to_string(x) + " is above " + std::to_string(hi));
    return x;
  }
  std::string text(const YAML::Node& n, const std::string& parent, const char* key) const {
    const YAML::Node v = need(n, parent, key);
    if (!v.IsScalar() || v.Scalar().empty() || v.Scalar().size() > 200) fail(v, join(parent, key), "must be a name");
    return v.Scalar();
  }
  Eigen::Vector3d point(const YAML::Node& v, const std::string& key, double limit) const {
    if (!v.IsSequence() || v.size() != 3) fail(v, key, "must be [x, y, z] in metres");
    Eigen::Vector3d p;
    for (std::size_t i = 0; i < 3; ++i) p(static_cast<Eigen::Index>(i)) = number(v[i], key, -limit, limit);
    return p;
  }
  // {translation: [x, y, z], rotation: [[r00, r01, r02], [...], [...]]}: a rotation
  // matrix (rows), orthonormal to 1e-6 with determinant +1.
  Eigen::Isometry3d pose(const YAML::Node& v, const std::string& key) const {
    map(v, key, {"translation", "rotation"});
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.translation() = point(need(v, key, "translation"), join(key, "translation"), 100.0);
    const YAML::Node r = need(v, key, "rotation");
    if (!r.IsSequence() || r.size() != 3) fail(r, join(key, "rotation"), "must be a 3x3 rotation matrix, as three rows");
    Eigen::Matrix3d R;
    for (std::size_t i = 0; i < 3; ++i) {
      if (!r[i].IsSequence() || r[i].size() != 3) fail(r[i], join(key, "rotation"), "must be a 3x3 rotation matrix, as three rows");
      for (std::size_t j = 0; j < 3; ++j)
        R(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) = number(r[i][j], join(key, "rotation"), -1.0, 1.0);
    }
    const double off = (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
    if (off > 1e-6 || R.determinant() < 0)
      fail(r, join(key, "rotation"), "is not a rotation (R^T R differs from I by " + std::to_string(off) + ", det " +
                                         std::to_string(R.determinant()) + ")");
    X.linear() = R;
    return X;
  }

 private:
  std::string file_;
};

Nanos to_nanos(double s) { return static_cast<Nanos>(std::llround(s * 1e9)); }

Scenario parse_scenario(const std::string& path, const std::string& text) {
  const ScenarioReader r(path);
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw std::runtime_error(path + ":" + std::to_string(e.mark.line + 1) + ": not YAML: " + e.msg);
  }
  Scenario s;
  s.name = std::filesystem::path(path).stem().string();
  if (!root.IsMap()) r.fail(root, "", "a scenario file is a map of keys");
  const YAML::Node kind = root["kind"];
  if (kind.IsDefined() && kind.IsScalar() && kind.Scalar() == "calibration-board") {
    r.map(root, "", {"kind", "seed", "camera_offset"});
    s.board_only = true;
    s.seed = root["seed"].IsDefined() ? r.count(root["seed"], "seed", ~0ULL >> 1) : 1;
    const YAML::Node off = r.need(root, "", "camera_offset");
    r.map(off, "camera_offset", {"translation_m", "angle_rad"});
    s.board_offset_m = r.number(off, "camera_offset", "translation_m", 0.0, 0.5);
    s.board_angle_rad = r.number(off, "camera_offset", "angle_rad", 0.0, 0.5);
    draw_board_offset(s);
    return s;
  }
  if (kind.IsDefined() && !(kind.IsScalar() && kind.Scalar() == "panel"))
    r.fail(kind, "kind", "must be 'panel' (the default) or 'calibration-board'");
  r.map(root, "", {"kind", "panel_type", "seed", "duration_s", "fps", "speed", "line", "defects", "people", "frame_drops",
                   "exposure_drift", "inspection", "plc_script"});
  s.panel_type = r.text(root, "", "panel_type");
  s.seed = root["seed"].IsDefined() ? r.count(root["seed"], "seed", ~0ULL >> 1) : 1;
  s.duration = to_nanos(r.number(root, "", "duration_s", 0.1, 3600.0));
  s.fps = r.number(root, "", "fps", 0.1, 1000.0);

  const YAML::Node speed = r.need(root, "", "speed");
  r.map(speed, "speed", {"kind", "min_m_per_s", "max_m_per_s", "run_s", "stop_s", "accel_m_per_s2"});
  const std::string speed_kind = r.text(speed, "speed", "kind");
  if (speed_kind == "constant") s.speed.kind = SpeedKind::kConstant;
  else if (speed_kind == "fluctuating") s.speed.kind = SpeedKind::kFluctuating;
  else if (speed_kind == "stop-and-go") s.speed.kind = SpeedKind::kStopAndGo;
  else r.fail(speed["kind"], "speed.kind", "'" + speed_kind + "' is not constant, fluctuating or stop-and-go");
  s.speed.min_speed = r.number(speed, "speed", "min_m_per_s", 0.0, 5.0);
  s.speed.max_speed = r.number_or(speed, "speed", "max_m_per_s", 0.0, 5.0, s.speed.min_speed);
  if (s.speed.max_speed < s.speed.min_speed) r.fail(speed["max_m_per_s"], "speed.max_m_per_s", "is below min_m_per_s");
  s.speed.stop_and_go_run_s = r.number_or(speed, "speed", "run_s", 0.01, 3600.0, s.speed.stop_and_go_run_s);
  s.speed.stop_and_go_stop_s = r.number_or(speed, "speed", "stop_s", 0.0, 3600.0, s.speed.stop_and_go_stop_s);
  s.speed.accel = r.number_or(speed, "speed", "accel_m_per_s2", 0.001, 100.0, s.speed.accel);
  s.speed.seed = s.seed;

  const YAML::Node line = r.need(root, "", "line");
  r.map(line, "line", {"X_CamR_Line", "curve_start_m", "curvature_per_m"});
  s.path.X_CamR_Line = r.pose(r.need(line, "line", "X_CamR_Line"), "line.X_CamR_Line");
  s.path.curve_start_m = r.number_or(line, "line", "curve_start_m", 0.0, 1e9, s.path.curve_start_m);
  s.path.curvature = r.number_or(line, "line", "curvature_per_m", -10.0, 10.0, 0.0);

  const YAML::Node defects = r.need(root, "", "defects");
  if (!defects.IsSequence() || defects.size() > kMaxDefects)
    r.fail(defects, "defects", "must be a list of at most " + std::to_string(kMaxDefects) + " defects");
  for (std::size_t i = 0; i < defects.size(); ++i) {
    const std::string key = "defects[" + std::to_string(i) + "]";
    r.map(defects[i], key, {"id", "x", "y", "radius"});
    DefectSpec d;
    d.id = static_cast<int>(r.count(r.need(defects[i], key, "id"), key + ".id", 1'000'000));
    d.x = r.number(defects[i], key, "x", -10.0, 10.0);
    d.y = r.number(defects[i], key, "y", -10.0, 10.0);
    d.radius = r.number(defects[i], key, "radius", 0.001, 0.1);
    for (const auto& e : s.defects)
      if (e.id == d.id) r.fail(defects[i]["id"], key + ".id", "id " + std::to_string(d.id) + " is used twice");
    s.defects.push_back(d);
  }
  if (const YAML::Node people = root["people"]; people.IsDefined()) {
    if (!people.IsSequence() || people.size() > kMaxPeople)
      r.fail(people, "people", "must be a list of at most " + std::to_string(kMaxPeople) + " walks");
    for (std::size_t i = 0; i < people.size(); ++i) {
      const std::string key = "people[" + std::to_string(i) + "]";
      r.map(people[i], key, {"enter_s", "leave_s", "from_CamR", "to_CamR"});
      PersonWalk w;
      w.enter = to_nanos(r.number(people[i], key, "enter_s", 0.0, 3600.0));
      w.leave = to_nanos(r.number(people[i], key, "leave_s", 0.0, 3600.0));
      if (w.leave <= w.enter) r.fail(people[i]["leave_s"], key + ".leave_s", "must be after enter_s");
      w.from_CamR = r.point(r.need(people[i], key, "from_CamR"), key + ".from_CamR", 100.0);
      w.to_CamR = r.point(r.need(people[i], key, "to_CamR"), key + ".to_CamR", 100.0);
      s.people.push_back(w);
    }
  }
  if (const YAML::Node drops = root["frame_drops"]; drops.IsDefined()) {
    r.map(drops, "frame_drops", {"ratio", "burst_start", "burst_length"});
    s.drop_ratio = r.number_or(drops, "frame_drops", "ratio", 0.0, 0.9, 0.0);
    if (drops["burst_start"].IsDefined()) s.drop_burst_start = r.count(drops["burst_start"], "frame_drops.burst_start", 1u << 30);
    if (drops["burst_length"].IsDefined())
      s.drop_burst_length = r.count(drops["burst_length"], "frame_drops.burst_length", 1u << 30);
  }
  s.exposure_drift = r.number_or(root, "", "exposure_drift", 0.0, 0.5, 0.0);
  const YAML::Node insp = r.need(root, "", "inspection");
  r.map(insp, "inspection", {"X_SL_Panel", "depth_sigma", "ding_depth", "points_per_defect"});
  s.X_SL_Panel = r.pose(r.need(insp, "inspection", "X_SL_Panel"), "inspection.X_SL_Panel");
  s.inspection.depth_sigma = r.number_or(insp, "inspection", "depth_sigma", 0.0, 0.01, s.inspection.depth_sigma);
  s.inspection.ding_depth = r.number_or(insp, "inspection", "ding_depth", 0.0, 0.01, s.inspection.ding_depth);
  if (insp["points_per_defect"].IsDefined())
    s.inspection.points_per_defect = static_cast<int>(r.count(insp["points_per_defect"], "inspection.points_per_defect", 10000));
  if (const YAML::Node plc = root["plc_script"]; plc.IsDefined()) {
    const std::string rel = r.text(root, "", "plc_script");
    const std::filesystem::path folder = std::filesystem::path(path).parent_path();
    if (const std::string why = confined_problem(folder.empty() ? "." : folder, rel, "the scenario file's folder",
                                                 "a PLC script is named relative to the scenario file");
        !why.empty())
      r.fail(plc, "plc_script", "'" + rel + "' " + why);
    s.plc_script = (folder / rel).string();
  }
  return s;
}

}  // namespace

void draw_board_offset(Scenario& s) {
  // The camera where the configured X_Base_CamR is not quite: a translation within the
  // offset in each axis and a turn of half to all of the angle about a random axis.
  // Each draw in a statement of its own (argument evaluation order is unspecified) from
  // the project's generator (docs/determinism.md).
  SplitMix rng{s.seed * 7919 + 17};
  Eigen::Vector3d axis, offset;
  for (int i = 0; i < 3; ++i) axis[i] = rng.uniform(-1.0, 1.0);
  const double share = 0.5 + 0.5 * std::abs(rng.uniform(-1.0, 1.0));
  for (int i = 0; i < 3; ++i) offset[i] = rng.uniform(-s.board_offset_m, s.board_offset_m);
  s.X_CamRnominal_CamR.linear() = Eigen::AngleAxisd(s.board_angle_rad * share, axis.normalized()).toRotationMatrix();
  s.X_CamRnominal_CamR.translation() = offset;
}

Scenario load_scenario(const std::string& path) {
  return parse_scenario(path, read_bounded_file(path, kMaxScenarioBytes, "a scenario file"));
}

Scenario with_seed(Scenario s, std::uint64_t seed) {
  s.seed = seed;
  s.speed.seed = seed;
  if (s.board_only) draw_board_offset(s);
  return s;
}

std::vector<std::string> scenario_names(const std::string& folder) {
  std::vector<std::string> names;
  std::error_code ec;
  for (const auto& e : std::filesystem::directory_iterator(folder, ec))
    if (e.is_regular_file() && e.path().extension() == ".yaml") names.push_back(e.path().stem().string());
  std::sort(names.begin(), names.end());
  return names;
}

std::string scenario_file(const std::string& name_or_file, const std::string& folder) {
  const std::filesystem::path p(name_or_file);
  if (p.extension() == ".yaml" || p.extension() == ".yml" || name_or_file.find('/') != std::string::npos) return name_or_file;
  const std::filesystem::path file = std::filesystem::path(folder) / (name_or_file + ".yaml");
  std::error_code ec;
  if (std::filesystem::is_regular_file(file, ec)) return file.string();
  std::string known;
  for (const auto& n : scenario_names(folder)) known += (known.empty() ? "" : ", ") + n;
  throw std::invalid_argument("unknown scenario '" + name_or_file + "': no " + file.string() + " (known: " +
                              (known.empty() ? "none, the folder has no .yaml file" : known) + ")");
}

std::string scenario_folder(const std::string& config_file) {
  return (std::filesystem::path(config_file).parent_path() / "scenarios").string();
}

Scenario find_scenario(const std::string& name_or_file, const std::string& folder, std::uint64_t seed) {
  return with_seed(load_scenario(scenario_file(name_or_file, folder)), seed);
}

vision::PanelTypeModel reference_panel_type(const Scenario& s, const rig::Panel& panel, const vision::StereoCalibration& marking,
                                            const rig::RenderSettings& render, cv::Mat* reference_left) {
  Eigen::Isometry3d X_CamR_Panel = s.path.X_CamR_Line;
  X_CamR_Panel.translation().x() = marking.X_CamR_CamL.translation().x();  // in front of the left camera
  const rig::StereoRenderer renderer(marking, render);
  cv::Mat left, right;
  renderer.render(panel, X_CamR_Panel, 1.0, s.seed * 7919ULL + 17, {}, left, right);
  std::vector<vision::MfPick> px;  // (each a corner or a hole, as the image shows it)
  for (const auto& mf : panel.macro_features) px.push_back({renderer.project(0, X_CamR_Panel * mf), vision::MfKindRequest::kAuto});
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
    for (const auto& d : s.defects) truth.push_back({d.id, panel.surface_point(d.x, d.y), d.radius});
    writer.set_defects(truth);
  }
  vision::save_stereo_calibration((std::filesystem::path(folder) / "stereo.yaml").string(), marking);
  std::filesystem::copy_file(panel.mesh_file, std::filesystem::path(folder) / m.panel_mesh,
                             std::filesystem::copy_options::overwrite_existing);

  // The inspection station's record for this panel: the station on the scanner's views.
  const InspectionRun inspection = run_inspection_station(folder, s.name + "-" + std::to_string(s.seed), panel, s.defects, scanner,
                                                          s.X_SL_Panel, s.inspection, render, s.seed);
  if (!inspection.outcome.ok())
    throw std::runtime_error("scenario '" + s.name + "': the inspection station made no record: " + inspection.outcome.problem +
                             " (its views and files: " + (std::filesystem::path(folder) / "inspection").string() + ")");
  return written;
}

}  // namespace markcell::rig
