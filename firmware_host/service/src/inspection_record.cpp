#include "markcell/host/inspection_record.hpp"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>

#include <yaml-cpp/yaml.h>

#include "markcell/common/bounded_file.hpp"

namespace markcell::host {

namespace {
[[noreturn]] void fail(const std::string& path, const YAML::Node& at, const std::string& field, const std::string& what) {
  std::ostringstream os;
  os << path;
  if (at.IsDefined() && at.Mark().line >= 0) os << ":" << at.Mark().line + 1 << ":" << at.Mark().column + 1;
  os << ": " << field << ": " << what;
  throw RecordInvalid(os.str());
}

Eigen::Vector3d point(const std::string& path, const YAML::Node& n, const std::string& field) {
  if (!n.IsSequence() || n.size() != 3) fail(path, n, field, "expected [x, y, z] in metres");
  Eigen::Vector3d p;
  for (std::size_t i = 0; i < 3; ++i) {
    try {
      p(static_cast<Eigen::Index>(i)) = n[i].as<double>();
    } catch (const YAML::Exception&) {
      fail(path, n[i], field, "'" + (n[i].IsScalar() ? n[i].Scalar() : std::string("?")) + "' is not a number");
    }
    if (!std::isfinite(p(static_cast<Eigen::Index>(i)))) fail(path, n[i], field, "not a finite number");
  }
  // The scanner sees the panel within a few metres: anything else is a unit mistake (mm).
  if (p.norm() > 20.0) fail(path, n, field, "point " + std::to_string(p.norm()) + " m from the scanner: units must be metres");
  return p;
}

// Keys outside the format are errors: a record is what the format says, no more (a
// 10 MB list under an unknown key was accepted, and parsed whole).
void only_keys(const std::string& path, const YAML::Node& map, const std::string& where, std::initializer_list<const char*> keys) {
  for (const auto& kv : map) {
    const std::string k = kv.first.IsScalar() ? kv.first.Scalar() : std::string("?");
    bool known = false;
    for (const char* allowed : keys) known = known || k == allowed;
    if (!known) {
      std::string list;
      for (const char* allowed : keys) list += std::string(list.empty() ? "" : ", ") + allowed;
      fail(path, kv.first, where.empty() ? k : where + "." + k, "unknown key (known: " + list + ")");
    }
  }
}

std::string scalar(const std::string& path, const YAML::Node& root, const std::string& key) {
  const YAML::Node n = root[key];
  if (!n.IsDefined()) fail(path, root, key, "missing");
  if (!n.IsScalar() || n.Scalar().empty()) fail(path, n, key, "expected a non-empty text");
  return n.Scalar();
}
}  // namespace

control::PanelJob parse_inspection_record(const std::string& text, const std::string& path,
                                          const std::vector<PanelTypeConfig>& panel_types) {
  YAML::Node root;
  if (text.size() > kMaxInspectionRecordBytes)
    throw RecordInvalid(path + ": " + std::to_string(text.size()) + " bytes, more than the " +
                        std::to_string(kMaxInspectionRecordBytes) + " allowed for an inspection record");
  if (const int line = nesting_beyond(text, 8); line > 0)
    throw RecordInvalid(path + ":" + std::to_string(line) + ": nested deeper than an inspection record is (8 levels)");
  try {
    if (const int line = second_document_line(text); line > 0)
      throw RecordInvalid(path + ":" + std::to_string(line) + ": a second YAML document: a record is one document");
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw RecordInvalid(path + ":" + std::to_string(e.mark.line + 1) + ": YAML: " + e.msg);
  }
  if (!root.IsMap()) fail(path, root, "(document)", "expected a map");
  only_keys(path, root, "", {"panel_id", "panel_type", "frame", "units", "macro_features", "macro_feature_quality", "defects"});
  control::PanelJob job;
  const std::string id = scalar(path, root, "panel_id");
  if (const std::string why = panel_id_problem(id); !why.empty()) fail(path, root["panel_id"], "panel_id", why);
  job.panel_id.assign(id);
  const std::string type = scalar(path, root, "panel_type");
  const PanelTypeConfig* panel = nullptr;
  for (std::size_t i = 0; i < panel_types.size(); ++i)
    if (panel_types[i].name == type) {
      panel = &panel_types[i];
      job.panel_type_index = static_cast<int>(i);
    }
  if (panel == nullptr) fail(path, root["panel_type"], "panel_type", "'" + type + "' is not configured in panel_types");
  job.panel_type.assign(type);
  if (scalar(path, root, "frame") != "CamL_SL") fail(path, root["frame"], "frame", "must be CamL_SL (the scanner's left camera)");
  if (scalar(path, root, "units") != "m") fail(path, root["units"], "units", "must be m");
  const YAML::Node mfs = root["macro_features"];
  if (!mfs.IsSequence()) fail(path, mfs.IsDefined() ? mfs : root, "macro_features", "expected a list of [x, y, z]");
  if (static_cast<int>(mfs.size()) != panel->macro_features)
    fail(path, mfs, "macro_features",
         std::to_string(mfs.size()) + " given, panel type '" + type + "' has " + std::to_string(panel->macro_features));
  // An MF the inspection station did not find is `~`: it is held as not finite, which the
  // inter-calibration leaves out. Three are the fewest a rigid fit rests on.
  int measured = 0;
  for (std::size_t i = 0; i < mfs.size(); ++i) {
    const bool missing = mfs[i].IsNull();
    const Eigen::Vector3d p = missing ? Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN())
                                      : point(path, mfs[i], "macro_features[" + std::to_string(i) + "]");
    measured += missing ? 0 : 1;
    if (!job.mfs_SL.push_back(p))
      fail(path, mfs, "macro_features", std::to_string(mfs.size()) + " given, at most " + std::to_string(msg::kMaxMacroFeatures));
  }
  if (measured < 3)
    fail(path, mfs, "macro_features", std::to_string(measured) + " measured (the rest ~), at least 3 are needed to place the panel");
  // How the station saw each MF: checked for form (the marking station does not use it).
  if (const YAML::Node q = root["macro_feature_quality"]; q.IsDefined()) {
    if (!q.IsSequence() || q.size() != mfs.size())
      fail(path, q, "macro_feature_quality", std::string("expected a list with one entry per macro-feature (") + std::to_string(mfs.size()) + ")");
    for (std::size_t i = 0; i < q.size(); ++i) {
      const std::string F = std::string("macro_feature_quality[") + std::to_string(i) + "]";
      if (q[i].IsNull() != mfs[i].IsNull())
        fail(path, q[i], F, mfs[i].IsNull() ? "must be ~: the macro-feature was not measured" : "missing for a measured macro-feature");
      if (q[i].IsNull()) continue;
      if (!q[i].IsMap()) fail(path, q[i], F, "expected a map");
      only_keys(path, q[i], F, {"left_px", "right_px", "epipolar_px", "corner_response", "hole_rms_px"});
      for (const auto& kv : q[i]) {
        const YAML::Node v = kv.second;
        const std::size_t n = v.IsSequence() ? v.size() : 1;
        if (n > 2 || (v.IsSequence() && n != 2)) fail(path, v, F + "." + kv.first.Scalar(), "expected a number or [u, v]");
        for (std::size_t j = 0; j < n; ++j) {
          const YAML::Node e = v.IsSequence() ? v[j] : v;
          double x = 0;
          if (!e.IsScalar() || !YAML::convert<double>::decode(e, x) || !std::isfinite(x))
            fail(path, e, F + "." + kv.first.Scalar(), "not a finite number");
        }
      }
    }
  }
  const YAML::Node defects = root["defects"];
  if (!defects.IsSequence()) fail(path, defects.IsDefined() ? defects : root, "defects", "expected a list (may be empty)");
  if (defects.size() > static_cast<std::size_t>(control::kMaxDefects))
    fail(path, defects, "defects", std::to_string(defects.size()) + " defects, at most " + std::to_string(control::kMaxDefects));
  std::set<int> ids;
  for (std::size_t i = 0; i < defects.size(); ++i) {
    const std::string F = "defects[" + std::to_string(i) + "]";
    const YAML::Node d = defects[i];
    if (!d.IsMap()) fail(path, d, F, "expected a map with id and points");
    only_keys(path, d, F, {"id", "points"});
    int did = 0;
    try {
      did = d["id"].as<int>();
    } catch (const YAML::Exception&) {
      fail(path, d["id"].IsDefined() ? d["id"] : d, F + ".id", "missing or not an integer");
    }
    if (did <= 0) fail(path, d["id"], F + ".id", "must be a positive integer");
    if (!ids.insert(did).second) fail(path, d["id"], F + ".id", "duplicate defect id " + std::to_string(did));
    const YAML::Node pts = d["points"];
    // d is read-only: a missing key gives an invalid node, whose type cannot be asked.
    if (!pts.IsDefined() || !pts.IsSequence() || pts.size() == 0) fail(path, pts.IsDefined() ? pts : d, F + ".points", "expected a non-empty list of [x, y, z]");
    if (pts.size() > static_cast<std::size_t>(control::kMaxDefectPoints))
      fail(path, pts, F + ".points", std::to_string(pts.size()) + " points, at most " + std::to_string(control::kMaxDefectPoints));
    auto& out = *job.defects.emplace_back();  // bounded above: kMaxDefects
    out.id = did;
    for (std::size_t j = 0; j < pts.size(); ++j) out.points_SL.push_back(point(path, pts[j], F + ".points[" + std::to_string(j) + "]"));
  }
  return job;
}

bool ends_with_end_marker(std::string_view text) {
  std::size_t end = text.size();
  while (end > 0 && (text[end - 1] == '\n' || text[end - 1] == '\r' || text[end - 1] == ' ')) --end;
  const std::size_t begin = text.rfind('\n', end == 0 ? 0 : end - 1);
  const std::size_t from = begin == std::string_view::npos ? 0 : begin + 1;
  return end >= from + 3 && text.compare(from, end - from, "...") == 0;
}

std::string panel_id_problem(std::string_view id) {
  if (id.empty()) return "empty";
  if (id.size() > 63) return "longer than 63 characters";
  for (std::size_t i = 0; i < id.size(); ++i) {
    const auto c = static_cast<unsigned char>(id[i]);
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '.' || c == '_' ||
                    c == '-' || c == ':' || c == '/' || c == '#' || c == '+';
    if (!ok) {
      char what[160];
      std::snprintf(what, sizeof what, "character %zu (0x%02x%s) is not allowed: a panel id is letters, digits and . _ - : / # +",
                    i + 1, c, c < 0x20 || c == 0x7f ? ", a control character" : c == ' ' ? ", a space" : "");
      return what;
    }
  }
  return "";
}

control::PanelJob read_inspection_record(const std::string& path, const std::vector<PanelTypeConfig>& panel_types) {
  std::string text;
  try {
    text = read_bounded_file(path, kMaxInspectionRecordBytes, "an inspection record");
  } catch (const FileRefused& e) {
    throw RecordInvalid(e.what());
  }
  return parse_inspection_record(text, path, panel_types);
}

}  // namespace markcell::host
