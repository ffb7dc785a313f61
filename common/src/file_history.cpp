#include "markcell/common/file_history.hpp"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <stdexcept>
#include <system_error>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

namespace markcell {

namespace fs = std::filesystem;

namespace {

std::string utc_format(std::time_t t, const char* format) {
  std::tm tm{};
  if (::gmtime_r(&t, &tm) == nullptr) throw std::runtime_error("time " + std::to_string(t) + " is not a UTC date");
  char text[32];
  const std::size_t n = std::strftime(text, sizeof text, format, &tm);
  return std::string(text, n);
}

[[noreturn]] void fail(const fs::path& path, const std::string& step, int error) {
  throw std::runtime_error(path.string() + ": " + step + ": " + std::strerror(error));
}

void fsync_path(const fs::path& path, int flags, const std::string& what) {
  const int fd = ::open(path.c_str(), flags | O_CLOEXEC);
  if (fd < 0) fail(path, "cannot open " + what + " to sync it", errno);
  const int r = ::fsync(fd);
  const int error = errno;
  ::close(fd);
  if (r != 0) fail(path, "cannot sync " + what, error);
}

fs::path folder_of(const fs::path& path) { return path.has_parent_path() ? path.parent_path() : fs::path("."); }

// NAME.STAMP.EXT or NAME.STAMP-NN.EXT, STAMP as utc_compact writes it.
bool is_history_entry(const fs::path& entry, const fs::path& path) {
  const std::string name = entry.filename().string(), stem = path.stem().string(), ext = path.extension().string();
  if (name.size() < stem.size() + 1 + 16 + ext.size() || name.compare(0, stem.size() + 1, stem + ".") != 0 ||
      name.compare(name.size() - ext.size(), ext.size(), ext) != 0)
    return false;
  const std::string stamp = name.substr(stem.size() + 1, name.size() - stem.size() - 1 - ext.size());
  if (stamp.size() != 16 && stamp.size() != 19) return false;
  for (std::size_t i = 0; i < 16; ++i) {
    const char c = stamp[i];
    const bool ok = i == 8 ? c == 'T' : i == 15 ? c == 'Z' : (c >= '0' && c <= '9');
    if (!ok) return false;
  }
  return stamp.size() == 16 || (stamp[16] == '-' && std::isdigit(static_cast<unsigned char>(stamp[17])) &&
                                std::isdigit(static_cast<unsigned char>(stamp[18])));
}

}  // namespace

std::string utc_iso8601(std::time_t t) { return utc_format(t, "%Y-%m-%dT%H:%M:%SZ"); }
std::string utc_compact(std::time_t t) { return utc_format(t, "%Y%m%dT%H%M%SZ"); }

std::string utc_iso8601_ms(std::int64_t ns) {
  constexpr std::int64_t kPerSecond = 1'000'000'000, kPerMilli = 1'000'000;
  std::int64_t s = ns / kPerSecond, rest = ns % kPerSecond;
  if (rest < 0) {  // before the epoch: the second below, and the milliseconds from it
    --s;
    rest += kPerSecond;
  }
  char ms[8];
  std::snprintf(ms, sizeof ms, ".%03d", static_cast<int>(rest / kPerMilli));
  return utc_format(static_cast<std::time_t>(s), "%Y-%m-%dT%H:%M:%S") + ms + "Z";
}

fs::path history_folder(const fs::path& path) { return folder_of(path) / "history"; }

std::vector<fs::path> file_history(const fs::path& path) {
  std::vector<fs::path> entries;
  std::error_code ec;
  fs::directory_iterator it(history_folder(path), ec);
  if (ec) return entries;  // no history yet
  int seen = 0;
  for (const fs::directory_entry& e : it) {
    if (++seen > kHistoryScanLimit) break;
    if (e.is_regular_file(ec) && is_history_entry(e.path(), path)) entries.push_back(e.path());
  }
  // The stamps sort by time, and a stamp's -02 after the plain one of the same second
  // (compared as stamps: in the whole names '-' would sort before the extension's '.').
  const std::size_t skip = path.stem().string().size() + 1, ext = path.extension().string().size();
  const auto stamp = [&](const fs::path& p) {
    const std::string name = p.filename().string();
    return name.substr(skip, name.size() - skip - ext);
  };
  std::sort(entries.begin(), entries.end(), [&](const fs::path& a, const fs::path& b) { return stamp(a) > stamp(b); });
  return entries;
}

FileReplacement replace_file_keeping_history(const fs::path& path, const std::function<void(const std::string&)>& write,
                                             int keep) {
  const fs::path folder = folder_of(path);
  std::error_code ec;
  if (!fs::is_directory(folder, ec)) throw std::runtime_error(path.string() + ": its folder " + folder.string() + " does not exist");
  if (fs::exists(path, ec) && !fs::is_regular_file(path, ec))
    throw std::runtime_error(path.string() + ": not a regular file; nothing written");
  // Built by appending: GCC 12 at -O3 (the arm64 build) takes `"." + std::string&&` for an
  // overlapping memcpy (-Wrestrict, a false positive).
  std::string hidden(".");
  hidden += path.stem().string();
  hidden += ".partial";
  hidden += path.extension().string();
  const fs::path temporary = folder / hidden;
  try {
    write(temporary.string());
  } catch (...) {
    fs::remove(temporary, ec);
    throw;
  }
  if (!fs::is_regular_file(temporary, ec)) throw std::runtime_error(temporary.string() + ": the writer made no file");
  fsync_path(temporary, O_RDONLY, "the new file");

  FileReplacement done;
  struct stat old {};
  if (::stat(path.c_str(), &old) == 0) {
    const fs::path history = history_folder(path);
    fs::create_directories(history, ec);
    if (ec) fail(history, "cannot make the history folder", ec.value());
    const std::string base = path.stem().string() + "." + utc_compact(old.st_mtime);
    for (int n = 1; n <= 99 && done.kept.empty(); ++n) {
      char suffix[8] = "";
      if (n > 1) std::snprintf(suffix, sizeof suffix, "-%02d", n);
      const fs::path candidate = history / (base + suffix + path.extension().string());
      if (::link(path.c_str(), candidate.c_str()) == 0) done.kept = candidate;
      else if (errno != EEXIST) fail(candidate, "cannot keep the previous version", errno);
    }
    if (done.kept.empty()) throw std::runtime_error(path.string() + ": 99 versions in one second in " + history.string());
    fsync_path(history, O_RDONLY | O_DIRECTORY, "the history folder");
  }
  if (::rename(temporary.c_str(), path.c_str()) != 0) fail(path, "cannot rename " + temporary.string() + " over it", errno);
  fsync_path(folder, O_RDONLY | O_DIRECTORY, "its folder");

  const std::vector<fs::path> versions = file_history(path);
  for (std::size_t i = static_cast<std::size_t>(std::max(keep, 0)); i < versions.size(); ++i) {
    if (fs::remove(versions[i], ec)) done.pruned.push_back(versions[i]);
  }
  return done;
}

}  // namespace markcell
