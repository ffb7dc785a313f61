#pragma once
// Reading a file that came from outside (a configuration, a calibration, an inspection
// record, a recording's index, a PLC script): only a regular file, of a bounded size,
// checked before a byte is read. Opened with O_NONBLOCK, so a FIFO or a device in its
// place neither blocks nor streams for ever; fstat on the open descriptor, so what is
// checked is what is read. Start-up and the record reader's thread only: allocates.
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>
#include <string>
#include <string_view>

namespace markcell {

class FileRefused : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

inline std::string_view file_kind(mode_t mode) {
  if (S_ISDIR(mode)) return "a directory";
  if (S_ISFIFO(mode)) return "a FIFO";
  if (S_ISCHR(mode)) return "a character device";
  if (S_ISBLK(mode)) return "a block device";
  if (S_ISSOCK(mode)) return "a socket";
  if (S_ISLNK(mode)) return "a symbolic link";
  return "not a regular file";
}

// The whole file, or FileRefused naming the path and what is wrong with it. `what` names
// the file's role in the messages ("an inspection record"). With follow_symlinks false
// a symbolic link is refused too (O_NOFOLLOW: the drop folder's records).
inline std::string read_bounded_file(const std::string& path, std::size_t max_bytes, std::string_view what,
                                     bool follow_symlinks = true) {
  const int flags = O_RDONLY | O_NONBLOCK | O_CLOEXEC | (follow_symlinks ? 0 : O_NOFOLLOW);
  const int fd = ::open(path.c_str(), flags);
  if (fd < 0) {
    const int err = errno;
    if (err == ELOOP && !follow_symlinks) throw FileRefused(path + ": a symbolic link, not read (" + std::string(what) + " must be a regular file)");
    throw FileRefused(path + ": cannot open: " + std::strerror(err));
  }
  struct Closer {
    int fd;
    ~Closer() { ::close(fd); }
  } closer{fd};
  struct stat st {};
  if (::fstat(fd, &st) != 0) throw FileRefused(path + ": cannot stat: " + std::strerror(errno));
  if (!S_ISREG(st.st_mode))
    throw FileRefused(path + ": " + std::string(file_kind(st.st_mode)) + ", not read (" + std::string(what) + " must be a regular file)");
  if (static_cast<unsigned long long>(st.st_size) > max_bytes)
    throw FileRefused(path + ": " + std::to_string(st.st_size) + " bytes, more than the " + std::to_string(max_bytes) +
                      " allowed for " + std::string(what));
  std::string text(static_cast<std::size_t>(st.st_size), '\0');
  std::size_t got = 0;
  // Bounded: at most the size fstat gave (a file that grows meanwhile is cut there and
  // the parser sees a torn end), each read making progress or ending the loop.
  while (got < text.size()) {
    const ssize_t n = ::read(fd, text.data() + got, text.size() - got);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) throw FileRefused(path + ": read failed: " + std::strerror(errno));
    if (n == 0) break;
    got += static_cast<std::size_t>(n);
  }
  text.resize(got);
  return text;
}

// The deepest nesting of flow collections ([ and {, outside quoted text and comments) in
// a YAML or OpenCV FileStorage text, and where it passes `limit`: the parsers recurse
// once per level, and 50,000 levels overflow their stack. 0 when within the limit, else
// the 1-based line at which it first went past.
inline int nesting_beyond(std::string_view text, int limit) {
  int depth = 0, line = 1;
  char quote = 0;
  bool comment = false;
  for (std::size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (c == '\n') {
      ++line;
      comment = false;
      if (quote == '\'') quote = 0;  // (a plain scalar's quote does not span lines)
      continue;
    }
    if (comment) continue;
    if (quote != 0) {
      if (c == '\\' && quote == '"' && i + 1 < text.size()) ++i;
      else if (c == quote) quote = 0;
      continue;
    }
    if (c == '"' || c == '\'') {
      // A quote opens quoted text only where a scalar starts (not "it's" inside one).
      const char before = i == 0 ? ' ' : text[i - 1];
      if (before == ' ' || before == '\t' || before == '[' || before == '{' || before == ',' || before == ':' || before == '\n')
        quote = c;
      continue;
    }
    if (c == '#' && (i == 0 || text[i - 1] == ' ' || text[i - 1] == '\t')) comment = true;
    else if (c == '[' || c == '{') {
      if (++depth > limit) return line;
    } else if ((c == ']' || c == '}') && depth > 0) {
      --depth;
    }
  }
  return 0;
}

// The 1-based line where a YAML text starts a second document (a `---` after content,
// or content after a `...`), 0 when it holds one. yaml-cpp 0.7's LoadAll can loop for
// ever on malformed text (found by the fuzzer): texts are parsed with Load, which reads
// the first document only, and a second one is found here instead.
inline int second_document_line(std::string_view text) {
  bool content = false, ended = false;
  int line = 0;
  for (std::size_t start = 0; start < text.size();) {
    std::size_t end = text.find('\n', start);
    if (end == std::string_view::npos) end = text.size();
    std::string_view l = text.substr(start, end - start);
    start = end + 1;
    ++line;
    if (!l.empty() && l.back() == '\r') l.remove_suffix(1);
    const bool marker_start = l.substr(0, 3) == "---" && (l.size() == 3 || l[3] == ' ' || l[3] == '\t');
    const bool marker_end = l.substr(0, 3) == "..." && (l.size() == 3 || l[3] == ' ' || l[3] == '\t');
    const std::size_t first = l.find_first_not_of(" \t");
    const bool blank = first == std::string_view::npos || l[first] == '#';
    if (marker_start) {
      if (content || ended) return line;
      continue;
    }
    if (marker_end) {
      ended = true;
      continue;
    }
    if (blank || (!content && l[0] == '%')) continue;
    if (ended) return line;
    content = true;
  }
  return 0;
}

}  // namespace markcell
