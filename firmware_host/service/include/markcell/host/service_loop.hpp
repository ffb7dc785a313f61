#pragma once
// The service's loop: `markcell run`, the cell as systemd runs it. Around a Cell whose
// lanes do the real-time work, this thread (never a lane) writes each panel's result and
// acknowledges it, logs every fault, takes inspection records from the drop folder,
// keeps systemd's status line, applies a scripted PLC (simulated lines), and decides
// when the process ends: the duration elapsed, SIGTERM or SIGINT, or a fault of the cell
// itself (exit 1, for Restart=on-failure). Every wait is bounded (50 ms at most), so a
// result is on disk within 50 ms of its panel's end and a signal is seen at once (within
// 100 ms of simulated time on the simulated clock).
//
// The rig's replay runs its cell through the same loop (supervise()): the same steps, the
// same scripted PLC, the same looks at the cell; its stop, faults and progress its own.
//
// Its lines go to the journal with fields, or to stderr with sd-daemon's priority
// prefixes (journal.hpp); every value escaped in the text. docs/operation.md lists them.
#include <csignal>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "markcell/common/time.hpp"
#include "markcell/host/broker_link.hpp"
#include "markcell/host/cell.hpp"
#include "markcell/host/config.hpp"
#include "markcell/host/exit_codes.hpp"
#include "markcell/host/journal.hpp"
#include "markcell/host/operator_page.hpp"
#include "markcell/host/plc_link.hpp"
#include "markcell/host/pose_log.hpp"
#include "markcell/host/record_folder.hpp"
#include "markcell/host/results_file.hpp"
#include "markcell/host/utc_clock.hpp"
#include "markcell/sim/plc_script.hpp"

namespace markcell::host {

struct ServiceOptions {
  ClockKind clock = ClockKind::kReal;
  Nanos duration = 0;                     // 0: until a signal (the real clock only)
  std::vector<sim::PlcEvent> plc_events;  // a scripted PLC on simulated lines; times from the start

  // For the rig's replay (rig/replay.cpp), which runs its cell through this same loop:
  // the PLC's inputs driven here (its peer behind real devices) instead of the cell's
  // simulated lines; empty: the cell's.
  std::function<void(LineRole, bool)> drive;
  Nanos step = 0;            // between two looks at the cell; 0: 100 ms simulated, 50 ms real
  std::uint64_t panels = 0;  // the loop ends once this many panels are done (0: it does not)
  bool journal = true;       // false: no journal lines (the replay keeps stderr for its progress)
  // Every fault as it is recorded; empty: each one a journal line.
  std::function<void(const control::Fault&)> on_fault;
  std::function<void(Nanos elapsed)> on_step;  // after each step, with the time since the start
  // The pose log (host/pose_log.hpp): its folder (empty: none), whether it is appended to
  // (the service) or made anew (a rig run), and its rotation size (0: never rotated).
  std::string pose_log_folder;
  PoseLog::Mode pose_log_mode = PoseLog::Mode::kAppend;
  std::uint64_t pose_log_rotate_bytes = 0;
  // Serve the operator page on the configuration's cell.operator_page (`run`; never the
  // rig's replay, whose configuration may name one for the cell it came from).
  bool operator_page = false;
};

// Why the loop ended.
enum class LoopEnd { kDuration, kPanels, kSignal, kCellFault, kWedged };

// Waits up to `timeout` of real time for a stop to be asked (0: only looks); returns the
// signal's number, or 0 when none came. `run` waits in sigtimedwait, the rig on its
// StopSignalWatcher.
using StopWait = std::function<int(Nanos timeout)>;

// Every panel whose record was accepted but whose result never came (the process was
// killed, the power cut, or it stopped before the panel arrived) gets a fault result
// now, so no accepted panel is without one; the ids seen are duplicates from now on.
// `utc`: when (docs/operation.md "Time").
void close_interrupted(ResultsFile& results, const std::string& cell, const std::string& utc, RecordFolder* records,
                       const Journal& journal, BrokerLink* broker = nullptr);

// What pairing records by order risks, when the configuration has a marking task, a
// record folder and no panel-id source (check-config and run warn); empty otherwise.
std::string pairing_warning(const CellConfig& config);

class ServiceLoop {
 public:
  // Opens the results file and the record folder before anything moves (a cell that could
  // not record its results must not start): throws what failed.
  ServiceLoop(const CellConfig& config, Cell& cell, ServiceOptions options);
  ServiceLoop(const ServiceLoop&) = delete;
  ServiceLoop& operator=(const ServiceLoop&) = delete;
  ~ServiceLoop();

  // Starts the cell's lanes: throws what failed (nothing has moved then).
  void start();
  // Runs until the end, shuts the cell down and prints its timing report and faults;
  // returns the exit code. `signals`: blocked in every thread (main()'s first line; run
  // adds SIGHUP before the cell's threads exist), taken here with sigtimedwait: SIGTERM
  // and SIGINT stop, SIGHUP reloads.
  int run(const sigset_t& signals);
  // The loop alone, for the rig: time driven (the simulated clock run, or the real one
  // waited on) in steps of at most `options.step`, cut at each scripted PLC event so that
  // it lands on its own time; after each step the cell is looked at (results, faults,
  // records, safety). Ends at the duration, the panel count, a stop `wait` reports, a
  // fault of the cell itself or a wedged simulation; the cell is left to the caller.
  LoopEnd supervise(const StopWait& wait);
 private:
  LoopEnd supervise_steps(const StopWait& wait);
 public:
  int signal() const { return signal_; }  // the stop's signal after LoopEnd::kSignal
  // The vision task's estimates so far into the pose log (each step does it; the last
  // ones after the cell stops, and the destructor).
  void write_poses();
  const PoseLog* pose_log() const { return pose_log_.get(); }
  OperatorPage* operator_page() { return page_.get(); }
  PlcLink* plc_link() { return line_.get(); }
  BrokerLink* broker_link() { return broker_.get(); }
  Nanos elapsed() const;                  // since the loop's start

 private:
  void collect();
  void log_faults();
  void take_records(Nanos now);
  // A record refused, by the folder or the broker: logged (`where` after the reason),
  // counted for the PLC, appended to the results file as `record` rejected.
  void record_rejected(const std::string& record, const std::string& panel_id, const std::string& reason,
                       const std::string& where, std::initializer_list<JournalField> fields, Nanos at);
  void apply_plc_events(Nanos elapsed);
  // The line's PLC: its newest word looked at (the simulated clock: one exchange first);
  // each announcement, a PLC that stops or starts answering and a block that is not
  // valid logged once.
  void watch_line();
  // The broker: one pass of its network (the simulated clock), the messages it rejected
  // logged and appended as rejected records, the connection's changes logged, the
  // station's state published when it changes.
  void watch_broker();
  // SIGHUP (systemctl reload): the panel types' recipes from the configuration file as it
  // is now, for the panels whose record is taken from now on, and the results file
  // reopened. A file that is not valid now, or whose panel types changed, changes
  // nothing: each error logged, the running configuration kept.
  void reload();
  void log(int priority, std::string_view text, std::initializer_list<JournalField> fields = {}) const;
  // True: a fault of the cell itself; the process must end.
  bool watch_safety();
  // The operator page's view of what this thread knows (after each step).
  void refresh_page();
  Nanos now() const;  // the cell's clock: simulated or monotonic

  const CellConfig& config_;
  Cell& cell_;
  const ServiceOptions options_;
  const Journal journal_;
  std::unique_ptr<ResultsFile> results_;
  std::unique_ptr<RecordFolder> records_;
  std::unique_ptr<PoseLog> pose_log_;
  std::unique_ptr<OperatorPage> page_;
  std::unique_ptr<PlcLink> line_;  // the panel-id source (line.panel_id_source: modbus)
  std::unique_ptr<BrokerLink> broker_;  // the stations' broker (line.broker)
  bool broker_down_ = false;
  std::string broker_state_;  // the state last published
  LineWord line_word_;             // as the last step saw it
  bool line_failing_ = false;
  std::uint64_t poses_dropped_seen_ = 0, poses_failed_seen_ = 0;
  sim::PlcScript script_;
  std::uint64_t written_ = 0;
  std::string status_shown_;
  Nanos start_ = 0;
  UtcClock utc_;  // the results file's and the fault lines' UTC
  int signal_ = 0;
};

}  // namespace markcell::host
