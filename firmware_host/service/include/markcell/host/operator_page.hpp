#pragma once
// The operator page and the plant's metrics (docs/operator_page.md): an HTTP server on
// the configured address (cell.operator_page, off when empty) that serves
//   /             the page: state and fault, the panel under way, the last results, the
//                 timing statistics, the live stereo view; it polls the two below
//   /api/state    the same as JSON
//   /view.jpg     the newest tracked stereo pair with the MFs and the defects drawn
//   /metrics      Prometheus's text format (0.0.4)
// Read-only: GET and HEAD only (anything else: 405); no control from the page.
//
// Its threads (cpp-httplib's, two workers) never touch a lane: they read the executive's
// and the vision task's counters (relaxed atomics the lanes write), the live view's
// triple buffer (live_view.hpp), and the service loop's OperatorState, which the loop
// rebuilds after each of its steps under a lock the lanes never take.
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "markcell/common/time.hpp"
#include "markcell/control/marking.hpp"

namespace markcell::host {

class Cell;

// What only the service loop knows, as the page shows it.
struct OperatorState {
  static constexpr std::size_t kKeptResults = 20;
  static constexpr std::size_t kKeptFaults = 50;
  struct FaultEntry {
    double time_s = 0;  // the cell's clock
    std::string utc;     // the same in UTC (host/utc_clock.hpp)
    std::string code, source, detail;
  };
  std::string status;  // systemd's status line (the same words)
  bool safe_stop = false;
  std::string stop_code, stop_source, stop_detail;
  bool has_marking = false;
  control::MarkingProgress progress;
  std::deque<std::string> results;  // the results file's lines (JSON), newest last
  std::deque<FaultEntry> faults;    // newest last
  std::uint64_t panels_done = 0, panels_fault = 0;
  std::uint64_t defects_sprayed = 0, defects_skipped = 0;
  std::uint64_t faults_total = 0;
  std::uint64_t records_accepted = 0, records_rejected = 0;
};

// "ADDRESS:PORT" (an IPv4 address, e.g. 127.0.0.1:8089; 0.0.0.0 for every interface):
// false, with what is wrong in `error`, for anything else.
bool parse_listen_address(const std::string& text, std::string& address, int& port, std::string& error);

class OperatorPage {
 public:
  // Binds the address now (throws "operator page: cannot listen on ADDRESS:PORT: ..."),
  // serves from start() on. The cell and `cell_name` outlive the page.
  OperatorPage(const std::string& listen, const std::string& cell_name, Cell& cell);
  ~OperatorPage();  // stops serving and joins its threads
  OperatorPage(const OperatorPage&) = delete;
  OperatorPage& operator=(const OperatorPage&) = delete;

  void start();
  int port() const { return port_; }
  const std::string& address() const { return address_; }

  // The service loop's thread: `f(state)` under the page's lock.
  template <class F>
  void update(F&& f) {
    std::lock_guard<std::mutex> lock(state_mutex_);
    f(state_);
  }

  // What the routes answer (public for the tests).
  std::string state_json();
  std::string metrics_text();
  // The newest live view as a JPEG; empty when no tracked pair came since the first
  // request (the request itself asks the vision task for the next one).
  std::vector<unsigned char> view_jpeg();

 private:
  OperatorState copy_state();
  struct Server;
  Cell& cell_;
  const std::string cell_name_;
  std::string address_;
  int port_ = 0;
  const Nanos started_;
  std::mutex state_mutex_;
  OperatorState state_;
  std::mutex view_mutex_;  // one reader of the live view at a time
  std::unique_ptr<Server> server_;
  std::thread thread_;
};

// The page itself (operator_page_html.cpp).
extern const char* const kOperatorPageHtml;

}  // namespace markcell::host
