#include "markcell/host/calibration_state.hpp"

#include <cstdio>
#include <ctime>
#include <filesystem>
#include <optional>
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

namespace {

// The file's provenance read once, and the summary line of what was read (`why`: the
// reason it could not be read, else empty).
struct Read {
  std::optional<vision::CalibrationProvenance> provenance;
  std::string why;
};
Read read_provenance(const std::string& path) {
  Read r;
  try {
    r.provenance = vision::load_provenance(path);
  } catch (const std::exception& e) {
    r.why = e.what();
  }
  return r;
}

std::string summary(const std::string& path, const Read& r) {
  if (!r.why.empty()) return "cannot be read: " + escape_log(r.why);
  if (!r.provenance) return "no provenance (not written by markcell's calibrate tools), modified " + modified_utc(path);
  const vision::CalibrationProvenance& p = *r.provenance;
  std::string s = "calibrated " + escape_log(p.calibrated_utc) + " by " + escape_log(p.tool) + ", RMS " +
                  number(p.rms, "%.3f") + " " + p.rms_unit;
  if (!p.views.empty()) s += " over " + std::to_string(p.views.size()) + (p.rms_unit == "mm" ? " arm poses" : " views");
  const auto camera = [](const std::string& id) { return id.empty() ? std::string("not given") : escape_log(id); };
  s += ", cameras " + camera(p.left_camera) + " and " + camera(p.right_camera);
  return s;
}

}  // namespace

std::string calibration_summary(const std::string& path) { return summary(path, read_provenance(path)); }

std::string calibration_listing(const std::string& role, const std::string& path) {
  // One read for the summary and the views: a file replaced in between cannot mix them.
  const Read in_use = read_provenance(path);
  std::string out = role + ": " + path + " (in use)\n  " + summary(path, in_use) + "\n";
  if (in_use.provenance)
    for (const auto& v : in_use.provenance->views)
      out += "    " + escape_log(v.name) + "  RMS " + number(v.rms, "%.3f") + " " + in_use.provenance->rms_unit + "\n";
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
