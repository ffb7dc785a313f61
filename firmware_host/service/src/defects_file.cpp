#include "markcell/host/defects_file.hpp"

#include <charconv>
#include <cmath>
#include <cstdio>
#include <map>

#include "markcell/common/bounded_file.hpp"
#include "markcell/control/marking.hpp"

namespace markcell::host {

namespace {

// The file's lines, each with its number; \r\n taken as \n.
class Lines {
 public:
  explicit Lines(std::string_view text) : text_(text) {}
  bool next(std::string_view& line) {
    if (at_ >= text_.size()) return false;
    const std::size_t end = text_.find('\n', at_);
    line = text_.substr(at_, (end == std::string_view::npos ? text_.size() : end) - at_);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    at_ = end == std::string_view::npos ? text_.size() : end + 1;
    ++number_;
    return true;
  }
  int number() const { return number_; }

 private:
  std::string_view text_;
  std::size_t at_ = 0;
  int number_ = 0;
};

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

// What is shown of a field in a message, quoted: at most 24 printable characters.
// (Built by appending: GCC 12's -O3 for aarch64 warns falsely on "'" + std::string.)
std::string quoted(std::string_view s) {
  std::string out(1, '\'');
  for (const char c : s.substr(0, 24)) out += (c >= 0x20 && c < 0x7f) ? c : '?';
  if (s.size() > 24) out.append("...");
  out += '\'';
  return out;
}

std::vector<std::string_view> split(std::string_view line, char sep) {
  std::vector<std::string_view> out;
  std::size_t at = 0;
  for (int guard = 0; guard < 64; ++guard) {
    const std::size_t end = line.find(sep, at);
    out.push_back(trim(line.substr(at, end == std::string_view::npos ? std::string_view::npos : end - at)));
    if (end == std::string_view::npos) break;
    at = end + 1;
  }
  return out;
}

std::vector<std::string_view> words(std::string_view line) {
  std::vector<std::string_view> out;
  std::size_t at = 0;
  while (at < line.size() && out.size() < 64) {
    while (at < line.size() && (line[at] == ' ' || line[at] == '\t')) ++at;
    std::size_t end = at;
    while (end < line.size() && line[end] != ' ' && line[end] != '\t') ++end;
    if (end > at) out.push_back(line.substr(at, end - at));
    at = end;
  }
  return out;
}

struct Reader {
  const std::string& path;
  const ScannerVolume& volume;
  std::map<int, std::vector<Eigen::Vector3d>> clusters;

  [[noreturn]] void fail(int line, const std::string& what) const {
    throw DefectsInvalid(path + ":" + std::to_string(line) + ": " + what);
  }
  double number(int line, std::string_view field, const char* name) const {
    double v = 0;
    const auto [end, ec] = std::from_chars(field.data(), field.data() + field.size(), v);
    if (ec != std::errc() || end != field.data() + field.size() || field.empty())
      fail(line, std::string(name) + ": " + quoted(field) + " is not a number");
    if (!std::isfinite(v)) fail(line, std::string(name) + ": " + quoted(field) + " is not finite");
    return v;
  }
  int id(int line, std::string_view field) const {
    long long v = 0;
    const auto [end, ec] = std::from_chars(field.data(), field.data() + field.size(), v);
    if (ec != std::errc() || end != field.data() + field.size() || field.empty() || v < 1 || v > 1'000'000)
      fail(line, "defect_id: " + quoted(field) + " is not an integer from 1 to 1000000");
    return static_cast<int>(v);
  }
  void point(int line, int defect, const Eigen::Vector3d& p) {
    const ScannerVolume& v = volume;
    if (p.z() < v.z_min_m || p.z() > v.z_max_m)
      fail(line, "the point (" + std::to_string(p.x()) + ", " + std::to_string(p.y()) + ", " + std::to_string(p.z()) +
                     ") m is not between " + std::to_string(v.z_min_m) + " and " + std::to_string(v.z_max_m) +
                     " m in front of the scanner (z)");
    const double u = v.fx * p.x() / p.z() + v.cx, w = v.fy * p.y() / p.z() + v.cy;
    if (u < 0 || u >= v.width || w < 0 || w >= v.height)
      fail(line, "the point (" + std::to_string(p.x()) + ", " + std::to_string(p.y()) + ", " + std::to_string(p.z()) +
                     ") m is outside the scanner's left image (it projects to " + std::to_string(u) + ", " +
                     std::to_string(w) + " px of " + std::to_string(v.width) + "x" + std::to_string(v.height) + ")");
    auto& c = clusters[defect];
    if (c.empty() && clusters.size() > static_cast<std::size_t>(control::kMaxDefects))
      fail(line, "defect " + std::to_string(defect) + ": more than " + std::to_string(control::kMaxDefects) +
                     " defects in one file");
    if (c.size() >= static_cast<std::size_t>(control::kMaxDefectPoints))
      fail(line, "defect " + std::to_string(defect) + ": more than " + std::to_string(control::kMaxDefectPoints) +
                     " points");
    c.push_back(p);
  }
};

void parse_csv(std::string_view text, Reader& r) {
  Lines lines(text);
  std::string_view line;
  bool header = false;
  while (lines.next(line)) {
    const std::string_view t = trim(line);
    if (t.empty() || t.front() == '#') continue;
    const std::vector<std::string_view> f = split(t, ',');
    if (!header) {
      if (f.size() != 4 || f[0] != "defect_id" || f[1] != "x_m" || f[2] != "y_m" || f[3] != "z_m")
        r.fail(lines.number(), "expected the header 'defect_id,x_m,y_m,z_m', found " + quoted(t));
      header = true;
      continue;
    }
    if (f.size() != 4)
      r.fail(lines.number(), std::to_string(f.size()) + " fields, expected 4 (defect_id,x_m,y_m,z_m)");
    const int defect = r.id(lines.number(), f[0]);
    r.point(lines.number(), defect,
            {r.number(lines.number(), f[1], "x_m"), r.number(lines.number(), f[2], "y_m"),
             r.number(lines.number(), f[3], "z_m")});
  }
  if (!header) r.fail(lines.number(), "no header 'defect_id,x_m,y_m,z_m': the file is empty");
}

void parse_ply(std::string_view text, Reader& r) {
  Lines lines(text);
  std::string_view line;
  lines.next(line);  // "ply"
  long long vertices = -1;
  int props = 0, px = -1, py = -1, pz = -1, pid = -1;
  bool in_vertex = false, ended = false;
  while (lines.next(line)) {
    const std::vector<std::string_view> w = words(line);
    if (w.empty()) continue;
    if (w[0] == "format") {
      if (w.size() != 3 || w[1] != "ascii" || w[2] != "1.0")
        r.fail(lines.number(), "format " + quoted(trim(line.substr(6))) + ": only 'ascii 1.0' is read");
    } else if (w[0] == "comment" || w[0] == "obj_info") {
    } else if (w[0] == "element") {
      if (w.size() != 3) r.fail(lines.number(), "element: expected 'element NAME COUNT'");
      in_vertex = w[1] == "vertex";
      if (in_vertex) {
        const auto [end, ec] = std::from_chars(w[2].data(), w[2].data() + w[2].size(), vertices);
        if (ec != std::errc() || end != w[2].data() + w[2].size() || vertices < 0 || vertices > 1'000'000)
          r.fail(lines.number(), "element vertex: " + quoted(w[2]) + " is not a count from 0 to 1000000");
      } else if (vertices < 0) {
        r.fail(lines.number(), "element " + quoted(w[1]) + " before element vertex: the vertices come first");
      }
    } else if (w[0] == "property") {
      if (!in_vertex) continue;  // (other elements' properties: their lines come after the vertices)
      if (w.size() != 3) r.fail(lines.number(), "property: expected 'property TYPE NAME' (no lists on vertices)");
      if (w[2] == "x") px = props;
      if (w[2] == "y") py = props;
      if (w[2] == "z") pz = props;
      if (w[2] == "defect_id") pid = props;
      ++props;
    } else if (w[0] == "end_header") {
      ended = true;
      break;
    } else {
      r.fail(lines.number(), quoted(w[0]).append(" is not a PLY header keyword"));
    }
  }
  if (!ended) r.fail(lines.number(), "no end_header");
  if (vertices < 0) r.fail(lines.number(), "no element vertex");
  if (px < 0 || py < 0 || pz < 0 || pid < 0)
    r.fail(lines.number(), "the vertices need the properties x, y, z and defect_id");
  for (long long i = 0; i < vertices; ++i) {
    if (!lines.next(line)) r.fail(lines.number(), "vertex " + std::to_string(i) + " of " + std::to_string(vertices) + " missing");
    const std::vector<std::string_view> w = words(line);
    if (static_cast<int>(w.size()) != props)
      r.fail(lines.number(), std::to_string(w.size()) + " values, expected " + std::to_string(props));
    const auto at = [&](int k) { return w[static_cast<std::size_t>(k)]; };
    r.point(lines.number(), r.id(lines.number(), at(pid)),
            {r.number(lines.number(), at(px), "x"), r.number(lines.number(), at(py), "y"),
             r.number(lines.number(), at(pz), "z")});
  }
}

}  // namespace

std::vector<DefectCluster> parse_defects(std::string_view text, const std::string& path, const ScannerVolume& volume,
                                         int min_points) {
  Reader r{path, volume, {}};
  const bool ply = text.substr(0, 3) == "ply" && (text.size() == 3 || text[3] == '\n' || text[3] == '\r');
  if (ply) parse_ply(text, r);
  else parse_csv(text, r);
  std::vector<DefectCluster> out;
  for (auto& [id, points] : r.clusters) {
    if (static_cast<int>(points.size()) < min_points)
      throw DefectsInvalid(path + ": defect " + std::to_string(id) + ": " + std::to_string(points.size()) +
                           " point(s), at least " + std::to_string(min_points) + " needed");
    out.push_back(DefectCluster{id, std::move(points)});
  }
  return out;
}

std::vector<DefectCluster> read_defects_file(const std::string& path, const ScannerVolume& volume, int min_points) {
  std::string text;
  try {
    text = read_bounded_file(path, kMaxDefectsFileBytes, "a defects file");
  } catch (const std::exception& e) {
    throw DefectsInvalid(e.what());
  }
  return parse_defects(text, path, volume, min_points);
}

std::string format_defects_csv(const std::vector<DefectCluster>& clusters) {
  std::string out = "defect_id,x_m,y_m,z_m\n";
  for (const DefectCluster& c : clusters)
    for (const Eigen::Vector3d& p : c.points_SL) {
      char line[128];
      std::snprintf(line, sizeof line, "%d,%.9g,%.9g,%.9g\n", c.id, p.x(), p.y(), p.z());
      out += line;
    }
  return out;
}

}  // namespace markcell::host
