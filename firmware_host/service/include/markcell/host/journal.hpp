#pragma once
// The service's log lines. Under systemd, stderr is a stream into journald
// (JOURNAL_STREAM names it); each line then goes as one journal entry through the native
// protocol (sd_journal_sendv) with fields a plant's tools can filter on (PANEL_ID=,
// PANEL_RESULT=, FAULT_CODE=, ...) beside its MESSAGE= and PRIORITY=. Anywhere else (a
// terminal, a test, a pipe) it is the same text as one stderr line with sd-daemon's
// priority prefix ("<3>markcell: ..."), which journald also understands. The fields carry
// the values as they are (the journal is binary-safe); the MESSAGE is escaped
// (common/log_escape.hpp), as it is on stderr. Off the real-time path: it allocates.
#include <initializer_list>
#include <string>
#include <string_view>

namespace markcell::host {

struct JournalField {
  std::string_view name;  // upper case, digits and '_' (journald's rule for field names)
  std::string_view value;
};

class Journal {
 public:
  // Decides once: the native protocol when stderr is the stream JOURNAL_STREAM names.
  Journal();
  bool native() const { return native_; }
  // One line: `text` (already escaped) as the MESSAGE, with its priority (syslog's: 3
  // error, 4 warning, 6 info) and fields. When journald refuses the entry, the stderr line.
  void log(int priority, std::string_view text, std::initializer_list<JournalField> fields = {}) const;

 private:
  bool native_ = false;
};

// Whether `journal_stream` ("DEVICE:INODE", systemd's JOURNAL_STREAM) names the file
// open on `fd`.
bool is_journal_stream(const char* journal_stream, int fd);

}  // namespace markcell::host
