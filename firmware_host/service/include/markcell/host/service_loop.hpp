#pragma once
// The service's loop: `markcell run`, the cell as systemd runs it. Around a Cell whose
// lanes do the real-time work, this thread (never a lane) writes each panel's result and
// acknowledges it, logs every fault, takes inspection records from the drop folder,
// keeps systemd's status line, applies a scripted PLC (simulated lines), and decides
// when the process ends: the duration elapsed, SIGTERM or SIGINT, or a fault of the cell
// itself (exit 1, for Restart=on-failure). Every wait is bounded (50 ms at most), so a
// result is on disk within 50 ms of its panel's end and a signal is seen at once.
//
// Its lines go to the journal with fields, or to stderr with sd-daemon's priority
// prefixes (journal.hpp); every value escaped in the text. docs/operation.md lists them.
#include <csignal>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "markcell/common/time.hpp"
#include "markcell/host/cell.hpp"
#include "markcell/host/config.hpp"
#include "markcell/host/journal.hpp"
#include "markcell/host/record_folder.hpp"
#include "markcell/host/results_file.hpp"
#include "markcell/sim/plc_script.hpp"

namespace markcell::host {

inline constexpr int kExitOk = 0;
inline constexpr int kExitRuntime = 1;  // a device, a fault at start-up, a fault of the cell itself
inline constexpr int kExitConfig = 2;   // an invalid configuration or arguments

struct ServiceOptions {
  ClockKind clock = ClockKind::kReal;
  double seconds = 0;                   // 0: until a signal (the real clock only)
  std::vector<sim::PlcEvent> plc_events;  // a scripted PLC on simulated lines; times from the start
};

// Every panel whose record was accepted but whose result never came (the process was
// killed, the power cut, or it stopped before the panel arrived) gets a fault result
// now, so no accepted panel is without one; the ids seen are duplicates from now on.
void close_interrupted(ResultsFile& results, const std::string& cell, RecordFolder* records, const Journal& journal);

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
  // returns the exit code. `signals`: blocked in every thread (main()'s first line),
  // taken here with sigtimedwait.
  int run(const sigset_t& signals);

 private:
  void collect();
  void log_faults();
  void take_records(Nanos now);
  void apply_plc_events(Nanos elapsed);
  Nanos next_event_after(Nanos elapsed);
  // True: a fault of the cell itself; the process must end.
  bool watch_safety();
  void run_simulated();
  void run_real(const sigset_t& signals);

  const CellConfig& config_;
  Cell& cell_;
  const ServiceOptions options_;
  const Journal journal_;
  std::unique_ptr<ResultsFile> results_;
  std::unique_ptr<RecordFolder> records_;
  sim::PlcScript script_;
  std::uint64_t written_ = 0;
  std::string status_shown_;
  std::string stop_reason_ = "duration elapsed";
  int exit_code_ = kExitOk;
};

}  // namespace markcell::host
