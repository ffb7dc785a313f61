#include "markcell/host/calibration_state.hpp"

#include <cstdio>
#include <ctime>
#include <filesystem>
#include <ostream>
#include <sys/stat.h>

#include "markcell/common/file_history.hpp"
#include "markcell/common/log_escape.hpp"
#include "markcell/host/build_version.hpp"

namespace markcell::host {

namespace fs = std::filesystem;

vision::CalibrationProvenance make_provenance(const std::string& tool, const std::string& left_camera,
                                              const std::string& right_camera, double rms, const std::string& rms_unit,
                                              std::vector<vision::CalibrationProvenance::View> views) {
  vision::CalibrationProvenance p;
  p.calibrated_utc = utc_iso8601(std::time(nullptr));
  p.tool = std::string("markcell ") + build_version() + " (commit " + build_commit() + ", " + tool + ")";
  p.left_camera = left_camera;
  p.right_camera = right_camera;
  p.rms = rms;
  p.rms_unit = rms_unit;
  p.views = std::move(views);
  return p;
}

void write_calibration(const std::string& out, const std::function<void(const std::string&)>& save, std::ostream& log) {
  const FileReplacement r = replace_file_keeping_history(out, save);
  if (!r.kept.empty()) log << "kept the previous " << fs::path(out).filename().string() << " as " << r.kept.string() << "\n";
  for (const auto& p : r.pruned) log << "removed the oldest kept version " << p.string() << " (" << kHistoryKept << " are kept)\n";
  log << "wrote " << out << "\n";
}

namespace {

std::string number(double v, const char* format) {
  char text[32];
  std::snprintf(text, sizeof text, format, v);
  return text;
}

std::string modified_utc(const std::string& path) {
  struct stat st {};
  return ::stat(path.c_str(), &st) == 0 ? utc_iso8601(st.st_mtime) : "unknown";
}

}  // namespace

std::string calibration_summary(const std::string& path) {
  std::optional<vision::CalibrationProvenance> p;
  try {
    p = vision::load_provenance(path);
  } catch (const std::exception& e) {
    return std::string("cannot be read: ") + escape_log(e.what());
  }
  if (!p) return "no provenance (not written by markcell's calibrate tools), modified " + modified_utc(path);
  std::string s = "calibrated " + escape_log(p->calibrated_utc) + " by " + escape_log(p->tool) + ", RMS " +
                  number(p->rms, "%.3f") + " " + p->rms_unit;
  if (!p->views.empty()) s += " over " + std::to_string(p->views.size()) + (p->rms_unit == "mm" ? " arm poses" : " views");
  const auto camera = [](const std::string& id) { return id.empty() ? std::string("not given") : escape_log(id); };
  s += ", cameras " + camera(p->left_camera) + " and " + camera(p->right_camera);
  return s;
}

std::string calibration_listing(const std::string& role, const std::string& path) {
  std::string out = role + ": " + path + " (in use)\n  " + calibration_summary(path) + "\n";
  try {
    if (const auto p = vision::load_provenance(path)) {
      for (const auto& v : p->views) out += "    " + escape_log(v.name) + "  RMS " + number(v.rms, "%.3f") + " " + p->rms_unit + "\n";
    }
  } catch (const std::exception&) {
    // Said in the summary above.
  }
  const auto history = file_history(path);
  if (history.empty()) {
    out += "  no earlier versions in " + history_folder(path).string() + "\n";
  } else {
    out += "  " + std::to_string(history.size()) + " earlier version(s) in " + history_folder(path).string() + ", newest first:\n";
    for (const auto& h : history) out += "    " + h.filename().string() + ": " + calibration_summary(h.string()) + "\n";
  }
  return out;
}

}  // namespace markcell::host
