#include "markcell/host/pose_log.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <stdexcept>

#include <Eigen/Geometry>

namespace markcell::host {

namespace {
// "..." with every quote doubled (RFC 4180); reasons are the tracker's static texts, but
// a reader should never have to know that.
std::size_t quoted(char* out, std::size_t room, std::string_view text) {
  std::size_t n = 0;
  const auto add = [&](char c) {
    if (n + 1 < room) out[n++] = c;
  };
  add('"');
  for (const char c : text) {
    if (c == '"') add('"');
    add(static_cast<unsigned char>(c) < 0x20 ? ' ' : c);
  }
  add('"');
  out[n] = '\0';
  return n;
}

long long ll(Nanos t) { return static_cast<long long>(t); }
unsigned long long ull(std::uint64_t v) { return static_cast<unsigned long long>(v); }
}  // namespace

PoseLog::PoseLog(const std::string& folder, Mode mode, std::uint64_t rotate_bytes) : rotate_bytes_(rotate_bytes) {
  poses_.path = (std::filesystem::path(folder) / "poses.csv").string();
  poses_.header = kPosesHeader;
  tracks_.path = (std::filesystem::path(folder) / "mf_tracks.csv").string();
  tracks_.header = kTracksHeader;
  open(poses_, mode);
  try {
    open(tracks_, mode);
  } catch (...) {
    ::close(poses_.fd);
    poses_.fd = -1;
    throw;
  }
}

PoseLog::~PoseLog() {
  for (File* file : {&poses_, &tracks_})
    if (file->fd >= 0) ::close(file->fd);
}

void PoseLog::open(File& file, Mode mode) {
  // A regular file or none: never through a link, never a device.
  const int fd = ::open(file.path.c_str(), O_WRONLY | O_CREAT | O_CLOEXEC | O_NOFOLLOW | (mode == Mode::kAppend ? O_APPEND : O_TRUNC),
                        0640);
  if (fd < 0) throw std::runtime_error(file.path + ": cannot open the pose log: " + std::strerror(errno));
  struct stat st {};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    ::close(fd);
    throw std::runtime_error(file.path + ": the pose log is not a regular file");
  }
  file.fd = fd;
  file.bytes = static_cast<std::uint64_t>(st.st_size);
  if (file.bytes == 0 && !put(file, file.header, std::strlen(file.header)))
    throw std::runtime_error(file.path + ": cannot write the pose log's header: " + std::strerror(errno));
}

// All of `text` or nothing: a write the disk cut short is taken back, so a reader never
// finds half a row glued to the next.
bool PoseLog::put(File& file, const char* text, std::size_t n) {
  if (file.fd < 0) return false;  // lost at a rotation that could not reopen it
  std::size_t done = 0;
  for (int attempt = 0; attempt < 8 && done < n; ++attempt) {
    const ssize_t w = ::write(file.fd, text + done, n - done);
    if (w < 0 && errno == EINTR) continue;
    if (w <= 0) break;
    done += static_cast<std::size_t>(w);
  }
  if (done == n) {
    file.bytes += n;
    return true;
  }
  if (done > 0 && ::ftruncate(file.fd, static_cast<off_t>(file.bytes)) != 0) file.bytes += done;
  return false;
}

void PoseLog::rotate(File& file) {
  ::close(file.fd);
  file.fd = -1;
  std::error_code ec;
  std::filesystem::rename(file.path, file.path + ".1", ec);  // the previous .1 is replaced
  try {
    open(file, Mode::kTruncate);
  } catch (const std::exception&) {
    file.fd = -1;  // rows are counted as failed from now on; the cell goes on
    return;
  }
  ++rotations_;
}

bool PoseLog::write(const msg::PoseEstimate& e) {
  // The frame's rows in two buffers, each written whole: 16 MF lines of at most 80 bytes.
  char pose[512];
  char tracks[msg::kMaxMacroFeatures * 96];
  char reason[160];
  quoted(reason, sizeof reason, e.has_pose() ? std::string_view{} : e.reason);
  const std::string_view status = msg::to_string(e.status);
  int n = 0;
  if (e.has_pose() || e.status == msg::TrackStatus::kLost) {
    Eigen::Quaterniond q(e.X_CamR_P.linear());
    q.normalize();
    if (q.w() < 0) q.coeffs() = -q.coeffs();  // one of the two: w >= 0
    const Eigen::Vector3d& t = e.X_CamR_P.translation();
    n = std::snprintf(pose, sizeof pose, "%llu,%lld,%.*s,%lld,%.6f,%.6f,%.6f,%.9f,%.9f,%.9f,%.9f,%d,%d,%.7f,%s\n", ull(e.seq),
                      ll(e.time), static_cast<int>(status.size()), status.data(), ll(e.reference_time), t.x(), t.y(), t.z(),
                      q.w(), q.x(), q.y(), q.z(), e.tracked, e.inliers, e.rms, reason);
  } else {
    n = std::snprintf(pose, sizeof pose, "%llu,%lld,%.*s,,,,,,,,,%d,%d,,%s\n", ull(e.seq), ll(e.time),
                      static_cast<int>(status.size()), status.data(), e.tracked, e.inliers, reason);
  }
  std::size_t used = 0;
  for (std::size_t k = 0; k < e.mfs.size(); ++k) {
    const msg::MacroFeatureObservation& m = e.mfs[k];
    char* at = tracks + used;
    const std::size_t room = sizeof tracks - used;
    const int w = m.valid ? std::snprintf(at, room, "%llu,%lld,%zu,%s,%.3f,%.3f,%.3f,%.3f\n", ull(e.seq), ll(e.time), k,
                                          m.inlier ? "inlier" : "outlier", m.left.x(), m.left.y(), m.right.x(), m.right.y())
                          : std::snprintf(at, room, "%llu,%lld,%zu,unseen,,,,\n", ull(e.seq), ll(e.time), k);
    if (w < 0 || static_cast<std::size_t>(w) >= room) break;  // (a pixel of 10^70: not a camera's)
    used += static_cast<std::size_t>(w);
  }
  const bool ok = n > 0 && static_cast<std::size_t>(n) < sizeof pose && put(poses_, pose, static_cast<std::size_t>(n)) &&
                  put(tracks_, tracks, used);
  if (!ok) {
    ++failed_;
    return false;
  }
  ++rows_;
  if (rotate_bytes_ > 0)
    for (File* file : {&poses_, &tracks_})
      if (file->bytes >= rotate_bytes_) rotate(*file);
  return true;
}

}  // namespace markcell::host
