#pragma once
// A stop asked for by SIGTERM or SIGINT, for the batch commands (`replay`, `sim`): they
// run long loops of their own on the main thread, so a thread of this watcher takes the
// signals (blocked in every thread since main()'s first line) with a bounded wait and
// leaves the signal's number where those loops look between their steps. `run` takes the
// signals on its main thread itself (sigtimedwait in its supervision loop).
#include <signal.h>

#include <atomic>
#include <chrono>
#include <string>
#include <thread>

namespace markcell::host {

class StopSignalWatcher {
 public:
  // Starts the thread; `signals` must be blocked in the calling thread already. A command
  // that has not finished `grace` after the signal (its loops stuck, or a second signal:
  // the user insists) is ended there with 128 + the signal, as the default action would.
  explicit StopSignalWatcher(const sigset_t& signals, std::chrono::milliseconds grace = std::chrono::seconds(10));
  ~StopSignalWatcher();  // stops and joins the thread within its 100 ms wait
  StopSignalWatcher(const StopSignalWatcher&) = delete;
  StopSignalWatcher& operator=(const StopSignalWatcher&) = delete;

  // 0 until a signal came; then its number (the first one; later ones are taken too).
  const std::atomic<int>& signal() const { return signal_; }

 private:
  sigset_t signals_;
  std::chrono::milliseconds grace_;
  std::atomic<int> signal_{0};
  std::atomic<bool> quit_{false};
  std::thread thread_;
};

// "SIGTERM", "SIGINT", or "signal N".
std::string signal_name(int signal);

}  // namespace markcell::host
