#pragma once
// The drop folder through which inspection records reach the cell (for now; the format
// is vision/RECORDING.md's inspection.yaml). The inspection station writes each panel's
// record as NAME.yaml, written elsewhere on the same filesystem (or as NAME.yaml.part)
// and renamed into place, so the cell never reads half a file. Records are taken in name
// order, one at a time: a valid one is offered to the marking sequence and moved to
// accepted/ once taken; a bad one (any field, or a panel id seen before) is moved to
// rejected/ with NAME.yaml.reason beside it, and never half-used.
//
// Off the real-time path: the service's main thread polls it.
#include <deque>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "markcell/control/marking.hpp"
#include "markcell/host/config.hpp"

namespace markcell::host {

struct RecordEvent {
  enum class Kind { kAccepted, kRejected } kind = Kind::kAccepted;
  std::string file;      // where it now is (accepted/ or rejected/)
  std::string panel_id;  // when it could be read
  std::string reason;    // kRejected: what is wrong, naming file, line and field
};

class RecordFolder {
 public:
  // Creates accepted/ and rejected/ inside `folder` (which must exist).
  RecordFolder(std::string folder, std::vector<PanelTypeConfig> panel_types);
  // One look at the folder: the first record by name is read and validated; a valid one
  // is passed to `offer`, which returns false while a record still waits (it stays for
  // the next poll). Nothing happened: nullopt.
  std::optional<RecordEvent> poll(const std::function<bool(const control::PanelJob&)>& offer);
  const std::string& folder() const { return folder_; }
  // A panel id received before this start (from the results file): a record with it again
  // is a duplicate.
  void remember(const std::string& panel_id);
  // Inside `offer`: where the record being offered goes once taken (accepted/NAME.yaml).
  const std::string& offering() const { return offering_; }

 private:
  static constexpr std::size_t kRecentIds = 4096;  // duplicate panel ids are caught among these
  std::string folder_;
  std::vector<PanelTypeConfig> panel_types_;
  std::deque<std::string> recent_ids_;
  std::string offering_;
};

}  // namespace markcell::host
