#pragma once
// Every panel's result, one JSON line each, appended to a file that survives a power
// cut: each line is written and fdatasync'ed before the marking sequence may tell the
// PLC done (or fault). Append-only: a crash can at worst cut the last line short, never
// touch an earlier one. Opening ends a torn last line with a newline, so readers skip
// exactly the lines that do not parse and every later result stands on a line of its own.
//
// Each append is all or nothing as a reader sees it (docs/operation.md): a write the disk
// refuses halfway (full, quota) is truncated back to the last complete line, and a line
// left torn all the same is ended before the next is appended. Before each append the
// path is checked to still be this file (device, inode, not unlinked): a results file
// removed or replaced by something else is a fault, not a silent write into a deleted
// inode; one rotated away (a new regular file at the path) is reopened.
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "markcell/control/marking.hpp"
#include "markcell/host/utc_clock.hpp"

namespace markcell::host {

class ResultsFile {
 public:
  // Opens (creates) for appending and syncs the folder so the file itself survives.
  // Throws naming the path and the system error.
  explicit ResultsFile(const std::string& path);
  ~ResultsFile();
  ResultsFile(const ResultsFile&) = delete;
  ResultsFile& operator=(const ResultsFile&) = delete;
  // Appends and syncs one line; throws naming the path when the disk refuses (the file is
  // then as it was before) or the file is gone.
  void append(const std::string& line);
  // Closes the file; the next append opens the path anew (SIGHUP, after a rotation that
  // the inode check in append would find anyway).
  void reopen();
  const std::string& path() const { return path_; }
  // Called with each line once it is on disk (the broker's result topic: the same lines).
  void mirror_to(std::function<void(const std::string&)> mirror) { mirror_ = std::move(mirror); }

  // The panel's times in the cell's seconds (started_s, finished_s, spray_s) and, by
  // `utc`, in UTC (started_utc, finished_utc, spray_utc).
  static std::string to_json(const control::PanelResult& result, const std::string& cell, const UtcClock& utc);
  // The other lines carry `utc`: when they were written (UtcClock::at of the cell's now).
  // A record taken from the drop folder, written before its panel can start: if the
  // process dies before the panel's result, the next start finds this line unanswered.
  static std::string accepted_json(const std::string& cell, const std::string& utc, const std::string& record,
                                   const std::string& panel_id);
  // A record the drop folder rejected (moved to `record`), with the reason.
  static std::string rejected_json(const std::string& cell, const std::string& utc, const std::string& record,
                                   const std::string& panel_id, const std::string& reason);
  // Appended after a panel's result line that reached the disk only after the marking
  // sequence had stopped waiting for it and told the PLC fault: the panel's last line is
  // then what the PLC heard (a fault), never a done the PLC did not hear.
  static std::string late_json(const std::string& cell, const std::string& utc, std::uint64_t serial,
                               const std::string& panel_id);
  // The result written at start-up for such a panel: a fault, with the reason.
  static std::string interrupted_json(const std::string& cell, const std::string& utc, const std::string& panel_id);

  // What the file's last kHistoryBytes hold (the recent past; start-up reads no more):
  // the panel ids seen, and those accepted without a result after (in file order).
  static constexpr long kHistoryBytes = 8L << 20;
  struct History {
    std::vector<std::string> panel_ids;
    std::vector<std::string> unfinished;
  };
  History history() const;

 private:
  std::function<void(const std::string&)> mirror_;
  void open_file();
  void check_still_there();
  void end_torn_line();
  std::string path_;
  int fd_ = -1;
};

}  // namespace markcell::host
