#pragma once
// Every panel's result, one JSON line each, appended to a file that survives a power
// cut: each line is written and fdatasync'ed before the marking sequence may tell the
// PLC done (or fault). Append-only: a crash can at worst cut the last line short, never
// touch an earlier one; readers skip a last line without its newline.
#include <string>

#include "markcell/control/marking.hpp"

namespace markcell::host {

class ResultsFile {
 public:
  // Opens (creates) for appending and syncs the folder so the file itself survives.
  // Throws naming the path and the system error.
  explicit ResultsFile(const std::string& path);
  ~ResultsFile();
  ResultsFile(const ResultsFile&) = delete;
  ResultsFile& operator=(const ResultsFile&) = delete;
  // Appends and syncs one line; throws naming the path when the disk refuses.
  void append(const std::string& line);
  const std::string& path() const { return path_; }

  static std::string to_json(const control::PanelResult& result, const std::string& cell);

 private:
  std::string path_;
  int fd_ = -1;
};

}  // namespace markcell::host
