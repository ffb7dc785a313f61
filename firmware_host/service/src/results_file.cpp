#include "markcell/host/results_file.hpp"

#include <nlohmann/json.hpp>

#include "markcell/common/bounded_file.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <algorithm>
#include <filesystem>
#include <optional>
#include <stdexcept>

namespace markcell::host {

namespace {
using Json = nlohmann::ordered_json;  // keys in the order written: a line reads as the docs show it

// Seconds with 0.1 ms resolution: the same value always prints the same bytes.
double seconds4(Nanos t) { return std::round(to_seconds(t) * 1e4) / 1e4; }
double round4(double v) { return std::isfinite(v) ? std::round(v * 1e4) / 1e4 : v; }

// One line: compact, and bytes that are not UTF-8 (a record's file name can hold any)
// replaced rather than refused: a result is never lost to its text.
std::string line_of(const Json& j) { return j.dump(-1, ' ', false, Json::error_handler_t::replace); }
}  // namespace

ResultsFile::ResultsFile(const std::string& path) : path_(path) { open_file(); }

void ResultsFile::open_file() {
  fd_ = ::open(path_.c_str(), O_RDWR | O_APPEND | O_CREAT | O_CLOEXEC | O_NOFOLLOW, 0640);
  if (fd_ < 0) throw std::runtime_error(path_ + ": cannot open the results file: " + std::strerror(errno));
  struct stat st {};
  if (::fstat(fd_, &st) != 0 || !S_ISREG(st.st_mode)) {
    ::close(fd_);
    fd_ = -1;
    throw std::runtime_error(path_ + ": the results file is not a regular file");
  }
  // A line cut short by a crash (no newline at the end) is ended here, so the next result
  // starts a line of its own and readers skip only the torn one.
  try {
    end_torn_line();
  } catch (const std::exception&) {
    ::close(fd_);
    fd_ = -1;
    throw;
  }
  const std::string dir = std::filesystem::path(path_).parent_path().string();
  const int dfd = ::open(dir.empty() ? "." : dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);  // the file's directory entry, for a file just created
    ::close(dfd);
  }
}

ResultsFile::~ResultsFile() {
  if (fd_ >= 0) ::close(fd_);
}

void ResultsFile::reopen() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

void ResultsFile::end_torn_line() {
  const off_t size = ::lseek(fd_, 0, SEEK_END);
  char last = '\n';
  if (size > 0 && ::pread(fd_, &last, 1, size - 1) == 1 && last != '\n') {
    if (::write(fd_, "\n", 1) != 1 || ::fdatasync(fd_) != 0)
      throw std::runtime_error(path_ + ": cannot end the torn last line of the results file: " + std::strerror(errno));
  }
}

void ResultsFile::check_still_there() {
  struct stat open_st {}, path_st {};
  if (::fstat(fd_, &open_st) != 0) throw std::runtime_error(path_ + ": the results file cannot be checked: " + std::strerror(errno));
  if (::lstat(path_.c_str(), &path_st) != 0)
    throw std::runtime_error(path_ + ": the results file was removed while the cell ran (results are not written until it is back)");
  if (path_st.st_dev == open_st.st_dev && path_st.st_ino == open_st.st_ino && open_st.st_nlink > 0) return;
  if (!S_ISREG(path_st.st_mode))
    throw std::runtime_error(path_ + ": the results file was replaced by " + std::string(file_kind(path_st.st_mode)));
  // Rotated (logrotate's create): the new file at the path takes the results from here on.
  ::close(fd_);
  fd_ = -1;
  open_file();
}

void ResultsFile::append(const std::string& line) {
  if (fd_ < 0) open_file();
  check_still_there();
  end_torn_line();  // a line an earlier failure could not take back
  const off_t before = ::lseek(fd_, 0, SEEK_END);
  const std::string text = line + "\n";
  std::size_t done = 0;
  const auto take_back = [&](const char* what) {
    const std::string why = std::strerror(errno);
    // All or nothing: the partial line goes, the file ends at the last complete one.
    if (before >= 0 && ::ftruncate(fd_, before) == 0) (void)::fdatasync(fd_);
    throw std::runtime_error(path_ + ": " + what + ": " + why + " (the result was not written)");
  };
  while (done < text.size()) {
    const ssize_t n = ::write(fd_, text.data() + done, text.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      if (n == 0) errno = ENOSPC;
      take_back("writing a result failed");
    }
    done += static_cast<std::size_t>(n);
  }
  if (::fdatasync(fd_) != 0) take_back("syncing a result failed");
  if (mirror_) mirror_(line);
}

std::string ResultsFile::accepted_json(const std::string& cell, const std::string& utc, const std::string& record,
                                       const std::string& panel_id) {
  return line_of(Json{{"cell", cell}, {"utc", utc}, {"record", record}, {"panel_id", panel_id}, {"accepted", true}});
}

std::string ResultsFile::rejected_json(const std::string& cell, const std::string& utc, const std::string& record,
                                       const std::string& panel_id, const std::string& reason) {
  return line_of(Json{{"cell", cell}, {"utc", utc}, {"record", record}, {"panel_id", panel_id}, {"rejected", reason}});
}

std::string ResultsFile::late_json(const std::string& cell, const std::string& utc, std::uint64_t serial,
                                   const std::string& panel_id) {
  return line_of(Json{{"cell", cell},
                      {"utc", utc},
                      {"panel", serial},
                      {"panel_id", panel_id},
                      {"late", true},
                      {"fault", true},
                      {"reason", "results file not written in time: the result above reached the disk after the PLC was "
                                 "told fault"}});
}

std::string ResultsFile::interrupted_json(const std::string& cell, const std::string& utc, const std::string& panel_id) {
  return line_of(Json{{"cell", cell},
                      {"utc", utc},
                      {"panel_id", panel_id},
                      {"interrupted", true},
                      {"fault", true},
                      {"reason", "markcell stopped after accepting the panel's record and before its result"}});
}

ResultsFile::History ResultsFile::history() const {
  History h;
  const off_t size = ::lseek(fd_, 0, SEEK_END);
  if (size <= 0) return h;
  const off_t from = size > kHistoryBytes ? size - kHistoryBytes : 0;
  std::string text(static_cast<std::size_t>(size - from), '\0');
  std::size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::pread(fd_, text.data() + done, text.size() - done, from + static_cast<off_t>(done));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) throw std::runtime_error(path_ + ": reading the results file failed: " + std::strerror(errno));
    done += static_cast<std::size_t>(n);
  }
  std::size_t start = 0;
  if (from > 0) {  // the first line read from the middle is partial
    start = text.find('\n');
    if (start == std::string::npos) return h;
    ++start;
  }
  while (start < text.size()) {
    std::size_t end = text.find('\n', start);
    if (end == std::string::npos) break;  // a torn last line counts for nothing
    const std::string_view line(text.data() + start, end - start);
    start = end + 1;
    // Only a whole line counts: one torn by a crash and ended later does not parse.
    const Json j = Json::parse(line, nullptr, false);
    if (j.is_discarded() || !j.is_object()) continue;
    const auto id = j.find("panel_id");
    if (id == j.end() || !id->is_string() || j.contains("rejected")) continue;
    const std::string panel_id = id->get<std::string>();
    auto pending = std::find(h.unfinished.begin(), h.unfinished.end(), panel_id);
    const auto accepted = j.find("accepted");
    if (accepted != j.end() && *accepted == true) {
      if (pending == h.unfinished.end()) h.unfinished.push_back(panel_id);
      h.panel_ids.push_back(panel_id);
    } else if (pending != h.unfinished.end()) {
      h.unfinished.erase(pending);  // its result (or its interrupted line)
    }
  }
  return h;
}

std::string ResultsFile::to_json(const control::PanelResult& r, const std::string& cell, const UtcClock& utc) {
  const auto& ic = r.intercalibration;
  const std::int64_t utc_offset = utc.offset();
  const auto triple = [](const Eigen::Vector3d& v) { return Json::array({round4(v.x()), round4(v.y()), round4(v.z())}); };
  Json defects = Json::array();
  for (const control::DefectResult& d : r.defects) {
    Json o{{"id", d.id}, {"sprayed", d.sprayed}};
    if (d.sprayed) {
      o["spray_s"] = seconds4(d.spray_requested);
      o["spray_utc"] = UtcClock::at(d.spray_requested, utc_offset);
    }
    if (d.skipped != control::SkipReason::kNone) o["skipped"] = control::to_string(d.skipped);
    defects.push_back(std::move(o));
  }
  return line_of(Json{{"cell", cell},
                      {"panel", r.serial},
                      {"panel_id", r.panel_id.view()},
                      {"started_s", seconds4(r.started)},
                      {"finished_s", seconds4(r.finished)},
                      {"started_utc", UtcClock::at(r.started, utc_offset)},
                      {"finished_utc", UtcClock::at(r.finished, utc_offset)},
                      {"fault", r.fault},
                      {"reason", r.reason.view()},
                      {"intercalibration",
                       {{"status", control::to_string(ic.status)},
                        {"macro_features", ic.inliers},
                        {"max_abs_m", triple(ic.max_abs)},
                        {"rms_m", triple(ic.rms)}}},
                      {"defects", std::move(defects)}});
}

}  // namespace markcell::host
