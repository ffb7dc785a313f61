#include "markcell/vision/recording.hpp"

#include <yaml-cpp/yaml.h>

#include "markcell/common/bounded_file.hpp"
#include "markcell/common/confined_path.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <sstream>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace markcell::vision {

namespace fs = std::filesystem;

namespace {

// What a recording's files may hold at most: checked before they are read.
constexpr std::size_t kMaxManifestBytes = 64 << 10;
constexpr std::size_t kMaxIndexBytes = 64 << 20;      // about a million frames
constexpr std::size_t kMaxTableBytes = 64 << 20;      // truth.csv, defects.csv
constexpr std::size_t kMaxImageBytes = 64 << 20;      // one PNG
constexpr int kMaxImageSide = 8192;
// Times far enough from the int64 limits that differences of two never overflow.
constexpr std::int64_t kMaxAbsTime = std::int64_t{1} << 62;

// A table the manifest names (truth.csv, defects.csv): there, a regular file, bounded.
std::string read_table(const fs::path& path, std::string_view what) {
  if (!fs::exists(path)) throw RecordingError(path.string() + ": missing (the manifest names it)");
  try {
    return read_bounded_file(path.string(), kMaxTableBytes, what);
  } catch (const FileRefused& e) {
    throw RecordingError(e.what());
  }
}

// A path from the index or the manifest, confined to the recording folder.
std::string confined_problem(const fs::path& folder, const std::string& rel) {
  return markcell::confined_problem(folder, rel, "the recording folder", "image paths are relative to the recording folder");
}

// The PNG header (signature and IHDR), read before anything is decoded: a file
// declaring 60000x60000 or 16-bit samples is refused without allocating its pixels.
std::string png_problem(const std::string& bytes, int width, int height) {
  static const unsigned char kSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  if (bytes.size() < 33 || std::memcmp(bytes.data(), kSignature, 8) != 0 || bytes.compare(12, 4, "IHDR") != 0)
    return "is not a PNG file";
  const auto be32 = [&](std::size_t at) {
    return (static_cast<std::uint32_t>(static_cast<unsigned char>(bytes[at])) << 24) |
           (static_cast<std::uint32_t>(static_cast<unsigned char>(bytes[at + 1])) << 16) |
           (static_cast<std::uint32_t>(static_cast<unsigned char>(bytes[at + 2])) << 8) |
           static_cast<std::uint32_t>(static_cast<unsigned char>(bytes[at + 3]));
  };
  const std::uint32_t w = be32(16), h = be32(20);
  const int depth = static_cast<unsigned char>(bytes[24]), colour = static_cast<unsigned char>(bytes[25]);
  if (w != static_cast<std::uint32_t>(width) || h != static_cast<std::uint32_t>(height))
    return "is " + std::to_string(w) + "x" + std::to_string(h) + ", the recording says " + std::to_string(width) + "x" +
           std::to_string(height);
  if (colour == 3) return depth <= 8 ? "" : "has a palette of " + std::to_string(depth) + "-bit indices";
  if (depth != 8) return "is not 8-bit (" + std::to_string(depth) + " bits a sample)";
  if (colour == 4) return "has 2 channels (grey and alpha): expected grey, RGB or RGBA";
  if (colour != 0 && colour != 2 && colour != 6) return "has PNG colour type " + std::to_string(colour);
  return "";
}

std::vector<std::string> split_csv(const std::string& line) {
  std::vector<std::string> out;
  std::string field;
  std::istringstream in(line);
  while (std::getline(in, field, ',')) out.push_back(field);
  if (!line.empty() && line.back() == ',') out.emplace_back();
  return out;
}

bool parse_u64(const std::string& s, std::uint64_t& out) {
  if (s.empty() || s.find_first_not_of("0123456789") != std::string::npos) return false;
  try {
    out = std::stoull(s);
  } catch (...) {
    return false;
  }
  return true;
}

bool parse_i64(const std::string& s, std::int64_t& out) {
  if (s.empty() || s.find_first_not_of("-0123456789") != std::string::npos) return false;
  try {
    out = std::stoll(s);
  } catch (...) {
    return false;
  }
  return true;
}

bool parse_double(const std::string& s, double& out) {
  try {
    std::size_t used = 0;
    out = std::stod(s, &used);
    return used == s.size() && std::isfinite(out);
  } catch (...) {
    return false;
  }
}

std::string strip_cr(std::string s) {
  if (!s.empty() && s.back() == '\r') s.pop_back();
  return s;
}

}  // namespace

RecordingWriter::RecordingWriter(std::string folder, RecordingManifest manifest)
    : folder_(std::move(folder)), manifest_(std::move(manifest)), uncaught_at_start_(std::uncaught_exceptions()) {
  if (fs::exists(fs::path(folder_) / "recording.yaml"))
    throw RecordingError(folder_ + ": already holds a recording (recording.yaml exists)");
  fs::create_directories(fs::path(folder_) / "left");
  fs::create_directories(fs::path(folder_) / "right");
}

RecordingWriter::~RecordingWriter() {
  if (std::uncaught_exceptions() > uncaught_at_start_) return;  // abandoned: see the header
  try {
    close();
  } catch (...) {
  }
}

void RecordingWriter::add(std::uint64_t seq, Nanos time, const cv::Mat& left, const cv::Mat& right) {
  if (closed_) throw RecordingError(folder_ + ": add() after close()");
  if (left.type() != CV_8UC1 || right.type() != CV_8UC1 || left.cols != manifest_.image_width ||
      left.rows != manifest_.image_height || right.size() != left.size())
    throw RecordingError(folder_ + ": frame " + std::to_string(seq) + ": images must be 8-bit grey " +
                         std::to_string(manifest_.image_width) + "x" + std::to_string(manifest_.image_height));
  std::ostringstream name;
  name << std::setw(6) << std::setfill('0') << seq << ".png";
  IndexEntry e{seq, time, "left/" + name.str(), "right/" + name.str(), 0};
  if (!cv::imwrite((fs::path(folder_) / e.left).string(), left) || !cv::imwrite((fs::path(folder_) / e.right).string(), right))
    throw RecordingError(folder_ + ": frame " + std::to_string(seq) + ": cannot write its images");
  index_.push_back(e);
}

void RecordingWriter::add_truth(std::uint64_t seq, Nanos time, const Eigen::Isometry3d& X) {
  truth_.push_back(TruthPose{seq, time, X});
}

void RecordingWriter::set_defects(const std::vector<TruthDefect>& defects) { defects_ = defects; }

void RecordingWriter::close() {
  if (closed_) return;
  closed_ = true;
  const fs::path dir(folder_);
  {
    std::ofstream out(dir / "frames.csv");
    out << "seq,time_ns,left,right\n";
    for (const auto& e : index_) out << e.seq << ',' << e.time << ',' << e.left << ',' << e.right << '\n';
  }
  if (!truth_.empty()) {
    std::ofstream out(dir / "truth.csv");
    out << "seq,time_ns,x,y,z,qw,qx,qy,qz\n" << std::setprecision(17);
    for (const auto& t : truth_) {
      const Eigen::Quaterniond q(t.X_CamR_Panel.linear());
      const Eigen::Vector3d p = t.X_CamR_Panel.translation();
      out << t.seq << ',' << t.time << ',' << p.x() << ',' << p.y() << ',' << p.z() << ',' << q.w() << ',' << q.x() << ','
          << q.y() << ',' << q.z() << '\n';
    }
  }
  if (!defects_.empty()) {
    std::ofstream out(dir / "defects.csv");
    out << "id,x,y,z,radius_m\n" << std::setprecision(17);
    for (const auto& d : defects_)
      out << d.id << ',' << d.p_Panel.x() << ',' << d.p_Panel.y() << ',' << d.p_Panel.z() << ',' << d.radius << '\n';
  }
  YAML::Emitter y;
  y << YAML::BeginMap;
  y << YAML::Key << "format" << YAML::Value << "markcell-recording";
  y << YAML::Key << "version" << YAML::Value << 1;
  y << YAML::Key << "station" << YAML::Value << manifest_.station;
  y << YAML::Key << "panel_type" << YAML::Value << manifest_.panel_type;
  y << YAML::Key << "frame_rate_hz" << YAML::Value << manifest_.frame_rate_hz;
  y << YAML::Key << "image_width" << YAML::Value << manifest_.image_width;
  y << YAML::Key << "image_height" << YAML::Value << manifest_.image_height;
  y << YAML::Key << "calibration" << YAML::Value << manifest_.calibration;
  if (!truth_.empty()) y << YAML::Key << "truth" << YAML::Value << "truth.csv";
  if (!defects_.empty()) y << YAML::Key << "defects" << YAML::Value << "defects.csv";
  if (manifest_.seed) y << YAML::Key << "seed" << YAML::Value << *manifest_.seed;
  if (!manifest_.scenario.empty()) y << YAML::Key << "scenario" << YAML::Value << manifest_.scenario;
  if (!manifest_.generator.empty()) y << YAML::Key << "generator" << YAML::Value << manifest_.generator;
  if (!manifest_.panel_mesh.empty()) {
    y << YAML::Key << "panel_mesh" << YAML::Value << manifest_.panel_mesh;
    y << YAML::Key << "panel_mesh_metres_per_unit" << YAML::Value << manifest_.panel_mesh_metres_per_unit;
  }
  if (!manifest_.macro_features_Panel.empty()) {
    y << YAML::Key << "macro_features_panel" << YAML::Value << YAML::BeginSeq;
    for (const auto& p : manifest_.macro_features_Panel)
      y << YAML::Flow << YAML::BeginSeq << p.x() << p.y() << p.z() << YAML::EndSeq;
    y << YAML::EndSeq;
  }
  y << YAML::EndMap;
  std::ofstream(dir / "recording.yaml") << y.c_str() << '\n';
}

Recording Recording::open(const std::string& folder) {
  Recording r;
  r.folder_ = folder;
  const fs::path dir(folder);
  const std::string manifest_path = (dir / "recording.yaml").string();
  YAML::Node m;
  if (!fs::exists(manifest_path)) throw RecordingError(manifest_path + ": missing (is " + folder + " a recording?)");
  try {
    const std::string text = read_bounded_file(manifest_path, kMaxManifestBytes, "a recording's manifest");
    if (const int line = nesting_beyond(text, 8); line > 0)
      throw RecordingError(manifest_path + ":" + std::to_string(line) + ": nested deeper than a manifest is (8 levels)");
    m = YAML::Load(text);
  } catch (const FileRefused& e) {
    throw RecordingError(e.what());
  } catch (const YAML::Exception& e) {
    throw RecordingError(manifest_path + ": line " + std::to_string(e.mark.line + 1) + ": " + e.msg);
  }
  auto need = [&](const char* key) {
    if (!m.IsMap() || !m[key].IsDefined() || !m[key].IsScalar())
      throw RecordingError(manifest_path + ": key '" + key + "': missing or not a value");
    return m[key];
  };
  if (need("format").as<std::string>() != "markcell-recording")
    throw RecordingError(manifest_path + ": key 'format': expected markcell-recording");
  try {
    if (need("version").as<int>() != 1) throw RecordingError(manifest_path + ": key 'version': only version 1 is known");
    r.manifest_.station = need("station").as<std::string>();
    r.manifest_.panel_type = need("panel_type").as<std::string>();
    r.manifest_.frame_rate_hz = need("frame_rate_hz").as<double>();
    r.manifest_.image_width = need("image_width").as<int>();
    r.manifest_.image_height = need("image_height").as<int>();
    r.manifest_.calibration = need("calibration").as<std::string>();
    if (m["truth"].IsDefined()) r.manifest_.has_truth = true;
    if (m["defects"].IsDefined()) r.manifest_.has_defects = true;
    if (m["seed"].IsDefined()) r.manifest_.seed = m["seed"].as<std::uint64_t>();
    if (m["scenario"].IsDefined()) r.manifest_.scenario = m["scenario"].as<std::string>();
    if (m["generator"].IsDefined()) r.manifest_.generator = m["generator"].as<std::string>();
    if (m["panel_mesh"].IsDefined()) r.manifest_.panel_mesh = need("panel_mesh").as<std::string>();
    if (m["panel_mesh_metres_per_unit"].IsDefined())
      r.manifest_.panel_mesh_metres_per_unit = need("panel_mesh_metres_per_unit").as<double>();
    if (const YAML::Node mfs = m["macro_features_panel"]; mfs.IsDefined()) {
      if (!mfs.IsSequence() || mfs.size() > 64)
        throw RecordingError(manifest_path + ": key 'macro_features_panel': expected a list of at most 64 [x, y, z] in metres");
      for (std::size_t i = 0; i < mfs.size(); ++i) {
        const YAML::Node p = mfs[i];
        if (!p.IsSequence() || p.size() != 3)
          throw RecordingError(manifest_path + ": key 'macro_features_panel': entry " + std::to_string(i + 1) + " is not [x, y, z]");
        const Eigen::Vector3d v(p[0].as<double>(), p[1].as<double>(), p[2].as<double>());
        if (!v.allFinite() || v.norm() > 20)
          throw RecordingError(manifest_path + ": key 'macro_features_panel': entry " + std::to_string(i + 1) +
                               " is not a finite point within 20 m (units are metres)");
        r.manifest_.macro_features_Panel.push_back(v);
      }
    }
  } catch (const YAML::BadConversion& e) {
    throw RecordingError(manifest_path + ": line " + std::to_string(e.mark.line + 1) + ": wrong type of value");
  }
  if (r.manifest_.station != "marking" && r.manifest_.station != "inspection")
    throw RecordingError(manifest_path + ": key 'station': expected marking or inspection, got " + r.manifest_.station);
  if (!std::isfinite(r.manifest_.frame_rate_hz) || !(r.manifest_.frame_rate_hz > 0) || r.manifest_.frame_rate_hz > 10'000)
    throw RecordingError(manifest_path + ": key 'frame_rate_hz': must be a number in (0, 10000], got " +
                         need("frame_rate_hz").Scalar());
  if (r.manifest_.image_width <= 0 || r.manifest_.image_height <= 0 || r.manifest_.image_width > kMaxImageSide ||
      r.manifest_.image_height > kMaxImageSide)
    throw RecordingError(manifest_path + ": keys 'image_width', 'image_height': must be in [1, " + std::to_string(kMaxImageSide) +
                         "], got " + std::to_string(r.manifest_.image_width) + "x" + std::to_string(r.manifest_.image_height));
  if (const std::string why = confined_problem(dir, r.manifest_.calibration); !why.empty())
    throw RecordingError(manifest_path + ": key 'calibration': '" + r.manifest_.calibration + "' " + why);
  if (!r.manifest_.panel_mesh.empty())
    if (const std::string why = confined_problem(dir, r.manifest_.panel_mesh); !why.empty())
      throw RecordingError(manifest_path + ": key 'panel_mesh': '" + r.manifest_.panel_mesh + "' " + why);
  if (!std::isfinite(r.manifest_.panel_mesh_metres_per_unit) || !(r.manifest_.panel_mesh_metres_per_unit > 0) ||
      r.manifest_.panel_mesh_metres_per_unit > 1000)
    throw RecordingError(manifest_path + ": key 'panel_mesh_metres_per_unit': must be a number in (0, 1000], got " +
                         need("panel_mesh_metres_per_unit").Scalar());

  const std::string index_path = (dir / "frames.csv").string();
  if (!fs::exists(index_path)) throw RecordingError(index_path + ": missing");
  std::istringstream in;
  try {
    in.str(read_bounded_file(index_path, kMaxIndexBytes, "a recording's frame index"));
  } catch (const FileRefused& e) {
    throw RecordingError(e.what());
  }
  std::string line;
  if (!std::getline(in, line) || strip_cr(line) != "seq,time_ns,left,right")
    throw RecordingError(index_path + ":1: expected the header seq,time_ns,left,right");
  int number = 1;
  while (std::getline(in, line)) {
    ++number;
    line = strip_cr(line);
    if (line.empty()) continue;
    const auto f = split_csv(line);
    const std::string where = "frames.csv:" + std::to_string(number) + ": ";
    IndexEntry e;
    e.line = number;
    std::int64_t t = 0;
    if (f.size() != 4) {
      r.index_problems_.push_back(where + "expected 4 fields (seq,time_ns,left,right), got " + std::to_string(f.size()));
      continue;
    }
    if (!parse_u64(f[0], e.seq) || !parse_i64(f[1], t) || f[2].empty() || f[3].empty()) {
      r.index_problems_.push_back(where + "seq and time_ns must be integers and both image paths present");
      continue;
    }
    if (t > kMaxAbsTime || t < -kMaxAbsTime) {
      r.index_problems_.push_back(where + "time_ns " + f[1] + " is out of range (at most 2^62 ns from 0)");
      continue;
    }
    e.time = t;
    e.left = f[2];
    e.right = f[3];
    std::string why;
    for (const std::string* rel : {&e.left, &e.right})
      if (why.empty()) {
        why = confined_problem(dir, *rel);
        if (!why.empty()) why = "image path '" + *rel + "' " + why;
      }
    if (!why.empty()) {
      r.index_problems_.push_back(where + why);
      continue;
    }
    r.index_.push_back(e);
  }

  if (r.manifest_.has_truth) {
    std::istringstream tin(read_table(dir / "truth.csv", "a recording's truth"));
    std::getline(tin, line);
    number = 1;
    while (std::getline(tin, line)) {
      ++number;
      const auto f = split_csv(strip_cr(line));
      double v[7];
      std::uint64_t seq = 0;
      std::int64_t t = 0;
      bool ok = f.size() == 9 && parse_u64(f[0], seq) && parse_i64(f[1], t);
      for (int i = 0; ok && i < 7; ++i) ok = parse_double(f[static_cast<std::size_t>(i) + 2], v[i]);
      if (!ok) throw RecordingError((dir / "truth.csv").string() + ":" + std::to_string(number) + ": expected seq,time_ns,x,y,z,qw,qx,qy,qz");
      TruthPose p{seq, t, Eigen::Isometry3d::Identity()};
      p.X_CamR_Panel.linear() = Eigen::Quaterniond(v[3], v[4], v[5], v[6]).normalized().toRotationMatrix();
      p.X_CamR_Panel.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
      r.truth_.push_back(p);
    }
  }
  if (r.manifest_.has_defects) {
    std::istringstream din(read_table(dir / "defects.csv", "a recording's defects"));
    std::getline(din, line);
    number = 1;
    while (std::getline(din, line)) {
      ++number;
      const auto f = split_csv(strip_cr(line));
      TruthDefect d;
      std::int64_t id = 0;
      double x = 0, y = 0, z = 0;
      if (f.size() != 5 || !parse_i64(f[0], id) || !parse_double(f[1], x) || !parse_double(f[2], y) || !parse_double(f[3], z) ||
          !parse_double(f[4], d.radius))
        throw RecordingError((dir / "defects.csv").string() + ":" + std::to_string(number) + ": expected id,x,y,z,radius_m");
      d.id = static_cast<int>(id);
      d.p_Panel = Eigen::Vector3d(x, y, z);
      r.defects_.push_back(d);
    }
  }
  return r;
}

std::string Recording::calibration_path() const { return (fs::path(folder_) / manifest_.calibration).string(); }

ReplayFrame Recording::read(std::size_t i) const {
  ReplayFrame f;
  f.index = i;
  if (i >= index_.size()) {
    f.dropped = true;
    f.problem = "frame index " + std::to_string(i) + " is past the end (" + std::to_string(index_.size()) + " frames)";
    return f;
  }
  const IndexEntry& e = index_[i];
  f.seq = e.seq;
  f.time = e.time;
  const std::string name = "frame " + std::to_string(i) + " (seq " + std::to_string(e.seq) + ", frames.csv:" +
                           std::to_string(e.line) + "): ";
  if (i > 0) {
    const IndexEntry& prev = index_[i - 1];
    if (e.time <= prev.time) {
      f.dropped = true;
      f.problem = name + "time " + std::to_string(e.time) + " ns is not after the previous frame's " +
                  std::to_string(prev.time) + " ns";
      return f;
    }
    if (e.seq <= prev.seq) {
      f.dropped = true;
      f.problem = name + "seq does not increase (previous " + std::to_string(prev.seq) + ")";
      return f;
    }
  }
  const auto load = [&](const std::string& rel, const char* side, cv::Mat& out) {
    const std::string path = (fs::path(folder_) / rel).string();
    std::string bytes;
    try {
      bytes = read_bounded_file(path, kMaxImageBytes, "a recorded image");
    } catch (const FileRefused& refused) {
      std::string why = refused.what();  // "PATH: what": the path is the folder's and rel
      if (why.rfind(path + ": ", 0) == 0) why.erase(0, path.size() + 2);
      f.problem = name + side + " image " + rel + " is missing or unreadable (" + why + ")";
      return false;
    }
    if (const std::string why = png_problem(bytes, manifest_.image_width, manifest_.image_height); !why.empty()) {
      f.problem = name + side + " image " + rel + " " + why;
      return false;
    }
    cv::Mat img;
    try {
      img = cv::imdecode(cv::Mat(1, static_cast<int>(bytes.size()), CV_8U, bytes.data()), cv::IMREAD_UNCHANGED);
    } catch (const cv::Exception& decode) {
      f.problem = name + side + " image " + rel + " could not be decoded: " + decode.err;
      return false;
    }
    if (img.empty()) {
      f.problem = name + side + " image " + rel + " is unreadable (a damaged PNG)";
      return false;
    }
    if (img.depth() != CV_8U || (img.channels() != 1 && img.channels() != 3 && img.channels() != 4)) {
      f.problem = name + side + " image " + rel + " is not 8-bit grey, RGB or RGBA";
      return false;
    }
    if (img.channels() == 3) cv::cvtColor(img, img, cv::COLOR_BGR2GRAY);
    else if (img.channels() == 4) cv::cvtColor(img, img, cv::COLOR_BGRA2GRAY);
    if (img.cols != manifest_.image_width || img.rows != manifest_.image_height) {
      f.problem = name + side + " image " + rel + " is " + std::to_string(img.cols) + "x" + std::to_string(img.rows) +
                  ", the recording says " + std::to_string(manifest_.image_width) + "x" +
                  std::to_string(manifest_.image_height);
      return false;
    }
    out = img;
    return true;
  };
  if (!load(e.left, "left", f.left) || !load(e.right, "right", f.right)) {
    f.dropped = true;
    f.left.release();
    f.right.release();
  }
  return f;
}

}  // namespace markcell::vision
