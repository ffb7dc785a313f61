#pragma once
// The drop folder through which inspection records reach the cell (for now; the format
// is vision/RECORDING.md's inspection.yaml). The inspection station writes each panel's
// record as NAME.yaml, written elsewhere on the same filesystem (or as NAME.yaml.part)
// and renamed into place. Records are taken in name order, one at a time: a valid one
// is offered to the marking sequence and moved to accepted/ once taken; a bad one (any
// field, a panel id seen before, a symbolic link, a FIFO, a directory, a file over the
// size limit) is moved to rejected/ with NAME.yaml.reason beside it, and never
// half-used.
//
// A record is complete by construction: its last line is YAML's end-of-document marker
// `...`, and it is read only once its size and modification time have not changed
// between two polls. One without the marker waits (written in place, still being
// written) for `incomplete_wait`, then is rejected. A record that waits for the
// marking sequence is kept parsed, not read again on every poll. Bad records ahead of a
// valid one are rejected in the same poll (up to kRejectsPerPoll), so junk never holds
// a record back past its panel.
//
// Off the real-time path: the service's main thread polls it.
#include <sys/types.h>

#include <deque>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "markcell/control/marking.hpp"
#include "markcell/host/config.hpp"
#include "markcell/msg/line_arrival.hpp"

namespace markcell::host {

struct RecordEvent {
  enum class Kind { kAccepted, kRejected } kind = Kind::kAccepted;
  std::string file;      // where it now is (accepted/ or rejected/)
  std::string panel_id;  // when it could be read
  std::string reason;    // kRejected: what is wrong, naming file, line and field
};

class RecordFolder {
 public:
  static constexpr std::size_t kMaxRecordBytes = 1 << 20;  // an inspection record, at most (kMaxInspectionRecordBytes)
  static constexpr int kRejectsPerPoll = 64;
  static constexpr std::size_t kMaxEntriesPerPoll = 100'000;  // directory entries looked at in one poll
  // Creates accepted/ and rejected/ inside `folder` (which must exist).
  RecordFolder(std::string folder, std::vector<PanelTypeConfig> panel_types, Nanos incomplete_wait = seconds(10));
  // One look at the folder at `now` (any monotonic clock): records ahead of the first
  // valid one that are bad are rejected; the first valid one is passed to `offer`, which
  // returns false while a record still waits (it stays, parsed, for the next poll).
  std::vector<RecordEvent> poll(const std::function<bool(const control::PanelJob&)>& offer, Nanos now);
  const std::string& folder() const { return folder_; }
  // Pairing by panel id (docs/line.md): every valid record is read into a pool (at most
  // kMaxPool, in name order; none holds another back) and the one whose id the line
  // announced last (`wanted`) is passed to `offer`, once per announcement (its counter).
  // A record whose panel type differs from the announced one is rejected; a record in the
  // pool longer than `expiry` is rejected as expired (its panel was never announced).
  std::vector<RecordEvent> poll_by_id(const std::function<bool(const control::PanelJob&)>& offer,
                                      const msg::LineArrival& wanted, Nanos expiry, Nanos now);
  static constexpr std::size_t kMaxPool = 64;
  std::size_t pooled() const { return pool_.size(); }
  // A panel id received before this start (from the results file): a record with it again
  // is a duplicate.
  void remember(const std::string& panel_id);
  // Inside `offer`: where the record being offered goes once taken (accepted/NAME.yaml,
  // or NAME.N.yaml when a record of that name was accepted before).
  const std::string& offering() const { return offering_; }

 private:
  struct Seen {  // a record's identity and size as the last poll saw it
    std::string name;
    dev_t dev = 0;
    ino_t ino = 0;
    off_t size = -1;
    long long mtime_ns = 0;
    Nanos first_stable = -1;  // when it was first seen unchanged (waiting for its marker)
    bool operator==(const Seen& o) const {
      return name == o.name && dev == o.dev && ino == o.ino && size == o.size && mtime_ns == o.mtime_ns;
    }
  };
  RecordEvent reject(const std::string& name, const std::string& reason, const std::string& panel_id = "");
  std::vector<std::string> candidates() const;  // NAME.yaml entries, in name order
  // A first look at a candidate: kGone (vanished), kRejected (no regular file, too large:
  // moved to rejected/ while `may_reject`), kSkipped (such a file when it may not
  // reject), kNew (not seen unchanged by the last poll) or kStable; `cur` as seen now.
  enum class Look { kGone, kRejected, kSkipped, kNew, kStable };
  Look look(const std::string& name, Seen& cur, bool may_reject, std::vector<RecordEvent>& events);
  // Reads and validates a stable candidate: kWait (no end marker yet, within the wait),
  // kRejected (moved to rejected/ with the reason) or kOk (`job` filled). `also_taken`:
  // ids held elsewhere (the pool) that make it a duplicate.
  enum class Read { kWait, kRejected, kOk };
  Read read(const std::string& name, Seen& cur, Nanos now, control::PanelJob& job, std::vector<RecordEvent>& events,
            const std::vector<std::string>& also_taken = {});
  RecordEvent accept(const std::string& name, const control::PanelJob& job);
  std::string unique_in(const char* sub, const std::string& name) const;
  static constexpr std::size_t kRecentIds = 4096;  // duplicate panel ids are caught among these
  std::string folder_;
  std::vector<PanelTypeConfig> panel_types_;
  Nanos incomplete_wait_;
  std::deque<std::string> recent_ids_;
  std::string offering_;
  std::vector<Seen> previous_;               // the candidates the last poll saw, in name order
  std::optional<Seen> parsed_of_;            // the record parsed_ holds
  std::optional<control::PanelJob> parsed_;  // valid, waiting for the sequence
  struct Pooled {  // pairing by id: a valid record waiting for its panel's announcement
    Seen seen;
    std::unique_ptr<control::PanelJob> job;
    Nanos read_at = 0;
  };
  std::vector<Pooled> pool_;
  std::uint32_t offered_counter_ = 0;  // the announcement a record was last offered for
};

}  // namespace markcell::host
