#include "markcell/host/journal.hpp"

#include <sys/stat.h>
#include <sys/uio.h>
#include <systemd/sd-journal.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <vector>

namespace markcell::host {

bool is_journal_stream(const char* journal_stream, int fd) {
  if (journal_stream == nullptr) return false;
  unsigned long long device = 0, inode = 0;
  char extra = 0;
  if (std::sscanf(journal_stream, "%llu:%llu%c", &device, &inode, &extra) != 2) return false;
  struct stat st {};
  if (::fstat(fd, &st) != 0) return false;
  return static_cast<unsigned long long>(st.st_dev) == device && static_cast<unsigned long long>(st.st_ino) == inode;
}

Journal::Journal() : native_(is_journal_stream(std::getenv("JOURNAL_STREAM"), STDERR_FILENO)) {}

void Journal::log(int priority, std::string_view text, std::initializer_list<JournalField> fields) const {
  if (native_) {
    std::vector<std::string> items;
    items.reserve(3 + fields.size());
    items.push_back("MESSAGE=" + std::string(text));
    items.push_back("PRIORITY=" + std::to_string(priority));
    items.emplace_back("SYSLOG_IDENTIFIER=markcell");
    for (const JournalField& f : fields) items.push_back(std::string(f.name) + "=" + std::string(f.value));
    std::vector<iovec> iov(items.size());
    for (std::size_t i = 0; i < items.size(); ++i) iov[i] = iovec{items[i].data(), items[i].size()};
    if (sd_journal_sendv(iov.data(), static_cast<int>(iov.size())) >= 0) return;
  }
  std::fprintf(stderr, "<%d>%.*s\n", priority, static_cast<int>(text.size()), text.data());
}

}  // namespace markcell::host
