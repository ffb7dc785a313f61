#include "markcell/host/results_file.hpp"
#include "markcell/host/json.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <stdexcept>

namespace markcell::host {

namespace {
std::string quote(std::string_view s) { return json_quote(s); }
std::string num(double v) { return json_number(v, 4); }
}  // namespace

ResultsFile::ResultsFile(const std::string& path) : path_(path) {
  fd_ = ::open(path.c_str(), O_WRONLY | O_APPEND | O_CREAT | O_CLOEXEC, 0640);
  if (fd_ < 0) throw std::runtime_error(path + ": cannot open the results file: " + std::strerror(errno));
  const std::string dir = std::filesystem::path(path).parent_path().string();
  const int dfd = ::open(dir.empty() ? "." : dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);  // the file's directory entry, for a file just created
    ::close(dfd);
  }
}

ResultsFile::~ResultsFile() {
  if (fd_ >= 0) ::close(fd_);
}

void ResultsFile::append(const std::string& line) {
  const std::string text = line + "\n";
  std::size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::write(fd_, text.data() + done, text.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) throw std::runtime_error(path_ + ": writing a result failed: " + std::strerror(errno));
    done += static_cast<std::size_t>(n);
  }
  if (::fdatasync(fd_) != 0) throw std::runtime_error(path_ + ": syncing a result failed: " + std::strerror(errno));
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
  for (int i = 0; i < r.defect_count; ++i) {
    const auto& d = r.defects[static_cast<std::size_t>(i)];
    o += std::string(i ? ", " : "") + "{\"id\": " + std::to_string(d.id) + ", \"sprayed\": " + (d.sprayed ? "true" : "false");
    if (d.sprayed) o += ", \"spray_s\": " + num(to_seconds(d.spray_requested));
    if (d.skipped != control::SkipReason::kNone) o += ", \"skipped\": " + quote(control::to_string(d.skipped));
    o += "}";
  }
  return o + "]}";
}

}  // namespace markcell::host
