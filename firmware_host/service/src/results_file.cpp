#include "markcell/host/results_file.hpp"
#include "markcell/host/json.hpp"

#include "markcell/common/bounded_file.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <algorithm>
#include <filesystem>
#include <optional>
#include <stdexcept>

namespace markcell::host {

namespace {
std::string quote(std::string_view s) { return json_quote(s); }
std::string num(double v) { return json_number(v, 4); }

// The value of `"key": "..."` in one of this file's own lines (json_quote's escapes).
std::optional<std::string> string_field(std::string_view line, std::string_view key) {
  const std::string pattern = "\"" + std::string(key) + "\": \"";
  const std::size_t at = line.find(pattern);
  if (at == std::string_view::npos) return std::nullopt;
  std::string value;
  for (std::size_t i = at + pattern.size(); i < line.size(); ++i) {
    if (line[i] == '"') return value;
    if (line[i] == '\\' && i + 1 < line.size()) ++i;
    value += line[i];
  }
  return std::nullopt;  // torn: no closing quote
}
// A line that is one whole JSON object: braces and brackets balanced outside strings,
// closing exactly at its end (a line cut after an inner '}' is not).
bool whole_json_object(std::string_view line) {
  if (line.size() < 2 || line.front() != '{') return false;
  int depth = 0;
  bool in_string = false;
  for (std::size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (in_string) {
      if (c == '\\') ++i;
      else if (c == '"') in_string = false;
      continue;
    }
    if (c == '"') in_string = true;
    else if (c == '{' || c == '[') ++depth;
    else if ((c == '}' || c == ']') && --depth == 0) return i + 1 == line.size();
  }
  return false;
}
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
}

std::string ResultsFile::accepted_json(const std::string& cell, const std::string& record, const std::string& panel_id) {
  return "{\"cell\": " + quote(cell) + ", \"record\": " + quote(record) + ", \"panel_id\": " + quote(panel_id) +
         ", \"accepted\": true}";
}

std::string ResultsFile::rejected_json(const std::string& cell, const std::string& record, const std::string& panel_id,
                                       const std::string& reason) {
  return "{\"cell\": " + quote(cell) + ", \"record\": " + quote(record) + ", \"panel_id\": " + quote(panel_id) +
         ", \"rejected\": " + quote(reason) + "}";
}

std::string ResultsFile::late_json(const std::string& cell, std::uint64_t serial, const std::string& panel_id) {
  return "{\"cell\": " + quote(cell) + ", \"panel\": " + std::to_string(serial) + ", \"panel_id\": " + quote(panel_id) +
         ", \"late\": true, \"fault\": true, \"reason\": \"results file not written in time: the result above reached "
         "the disk after the PLC was told fault\"}";
}

std::string ResultsFile::interrupted_json(const std::string& cell, const std::string& panel_id) {
  return "{\"cell\": " + quote(cell) + ", \"panel_id\": " + quote(panel_id) +
         ", \"interrupted\": true, \"fault\": true, \"reason\": "
         "\"markcell stopped after accepting the panel's record and before its result\"}";
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
    // Only a whole line counts: one torn by a crash and ended later is no result.
    if (!whole_json_object(line)) continue;
    const auto id = string_field(line, "panel_id");
    if (!id || line.find("\"rejected\": ") != std::string_view::npos) continue;
    auto pending = std::find(h.unfinished.begin(), h.unfinished.end(), *id);
    if (line.find("\"accepted\": true") != std::string_view::npos) {
      if (pending == h.unfinished.end()) h.unfinished.push_back(*id);
      h.panel_ids.push_back(*id);
    } else if (pending != h.unfinished.end()) {
      h.unfinished.erase(pending);  // its result (or its interrupted line)
    }
  }
  return h;
}

std::string ResultsFile::to_json(const control::PanelResult& r, const std::string& cell) {
  std::string o = "{\"cell\": " + quote(cell) + ", \"panel\": " + std::to_string(r.serial) +
                  ", \"panel_id\": " + quote(r.panel_id.view()) + ", \"started_s\": " + num(to_seconds(r.started)) +
                  ", \"finished_s\": " + num(to_seconds(r.finished)) + ", \"fault\": " + (r.fault ? "true" : "false") +
                  ", \"reason\": " + quote(r.reason.view());
  const auto& ic = r.intercalibration;
  o += ", \"intercalibration\": {\"status\": " + quote(control::to_string(ic.status)) + ", \"macro_features\": " +
       std::to_string(ic.inliers) + ", \"max_abs_m\": [" + num(ic.max_abs.x()) + ", " + num(ic.max_abs.y()) + ", " +
       num(ic.max_abs.z()) + "], \"rms_m\": [" + num(ic.rms.x()) + ", " + num(ic.rms.y()) + ", " + num(ic.rms.z()) + "]}";
  o += ", \"defects\": [";
  for (int i = 0; i < r.defects.ssize(); ++i) {
    const auto& d = r.defects[static_cast<std::size_t>(i)];
    o += std::string(i ? ", " : "") + "{\"id\": " + std::to_string(d.id) + ", \"sprayed\": " + (d.sprayed ? "true" : "false");
    if (d.sprayed) o += ", \"spray_s\": " + num(to_seconds(d.spray_requested));
    if (d.skipped != control::SkipReason::kNone) o += ", \"skipped\": " + quote(control::to_string(d.skipped));
    o += "}";
  }
  return o + "]}";
}

}  // namespace markcell::host
