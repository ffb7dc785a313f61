#pragma once
// The line's PLC over Modbus TCP (docs/line.md) as the service runs it: every poll, one
// exchange (the cell's block written: heartbeat, the I/O lines' mirror, the safe stop
// and its fault code, the arrival heard, panels done, the last result; the PLC's block
// read: which panel comes next). Each answer is handed to the control lane through the
// cell's triple buffer of arrivals (the real-time path never waits on the network) and
// kept here for the service's thread, which pairs records by the announced id. A PLC
// that does not answer is retried every poll; the marking task stops the cell once it has
// been silent for line.silent_ms.
//
// On the real clock a thread of its own polls; on the simulated clock the service's loop
// calls poll() once per step (the same exchange, on simulated time).
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <string>
#include <thread>

#include "markcell/common/triple_buffer.hpp"
#include "markcell/drivers/gpio_mirror.hpp"
#include "markcell/drivers/modbus_plc.hpp"
#include "markcell/control/faults.hpp"
#include "markcell/host/config.hpp"

namespace markcell::host {

// What the cell's block says besides the lines' mirror: written by the service's thread.
struct CellReport {
  std::atomic<std::uint32_t> panels_done{0};
  std::atomic<std::uint32_t> last_result{0};  // 0 none, 1 done, 2 fault
  std::atomic<std::uint32_t> records_rejected{0};
};

// The newest word from the line, as the service's thread sees it.
struct LineWord {
  msg::LineArrival arrival;   // counter 0: nothing announced (or not heard yet)
  bool valid = true;          // false: the PLC's block was not valid (error says why)
  std::uint64_t answers = 0;  // exchanges that succeeded
  std::string error;          // the last failure (empty: the last exchange succeeded)
};

class PlcLink {
 public:
  using Now = Nanos (*)(void*);
  // `lines`: the cell's mirrored GPIO; `arrivals`: the marking task's buffer (this is its
  // one writer); `now`: the cell's clock.
  PlcLink(const ModbusLinkConfig& config, const drivers::MirroredGpioLines& lines, const control::SafeStop& safe_stop,
          TripleBuffer<msg::LineArrival>& arrivals, Now now, void* now_user);
  ~PlcLink();
  PlcLink(const PlcLink&) = delete;
  PlcLink& operator=(const PlcLink&) = delete;

  // One exchange now. True: the PLC answered (and its block was valid or not: word()).
  bool poll();
  // The real clock: a thread polls every poll_ms until stop() (or the destructor).
  void start_thread();
  void stop();
  LineWord word() const;
  CellReport& report() { return report_; }
  std::string peer() const { return plc_.peer(); }

 private:
  void fill_cell_block(drivers::CellBlock& block);
  const ModbusLinkConfig config_;
  drivers::ModbusPlc plc_;
  const drivers::MirroredGpioLines& lines_;
  const control::SafeStop& safe_stop_;
  TripleBuffer<msg::LineArrival>& arrivals_;
  Now now_;
  void* now_user_;
  CellReport report_;
  std::uint16_t heartbeat_ = 0;
  msg::LineArrival last_;  // the last valid word (what the control lane has)
  mutable std::mutex mutex_;
  LineWord word_;
  std::thread thread_;
  std::mutex stop_mutex_;
  std::condition_variable stop_cv_;
  bool stopping_ = false;
};

}  // namespace markcell::host
