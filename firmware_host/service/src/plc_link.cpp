#include "markcell/host/plc_link.hpp"

#include "markcell/host/operator_page.hpp"

namespace markcell::host {

namespace {
drivers::ModbusPlcConfig driver_config(const ModbusLinkConfig& c) {
  drivers::ModbusPlcConfig d;
  std::string error;
  if (!parse_listen_address(c.server, d.address, d.port, error))
    throw std::invalid_argument("line.modbus.server: " + error);  // (the loader has said so already)
  d.unit_id = c.unit_id;
  d.plc_block = c.plc_block;
  d.cell_block = c.cell_block;
  d.response_timeout = c.response_timeout;
  return d;
}
}  // namespace

PlcLink::PlcLink(const ModbusLinkConfig& config, const drivers::MirroredGpioLines& lines, const control::SafeStop& safe_stop,
                 TripleBuffer<msg::LineArrival>& arrivals, Now now, void* now_user)
    : config_(config),
      plc_(driver_config(config)),
      lines_(lines),
      safe_stop_(safe_stop),
      arrivals_(arrivals),
      now_(now),
      now_user_(now_user) {}

PlcLink::~PlcLink() { stop(); }

void PlcLink::fill_cell_block(drivers::CellBlock& b) {
  const bool stopped = safe_stop_.done();
  b[0] = drivers::kPlcRegisterMapVersion;
  b[1] = ++heartbeat_;
  b[2] = static_cast<std::uint16_t>(lines_.levels() & 0xffffu);
  b[3] = stopped ? 1 : 0;
  b[4] = stopped ? static_cast<std::uint16_t>(safe_stop_.reason().code) : 0;
  b[5] = static_cast<std::uint16_t>(last_.counter);
  b[6] = static_cast<std::uint16_t>(report_.panels_done.load(std::memory_order_relaxed) & 0xffffu);
  b[7] = static_cast<std::uint16_t>(report_.last_result.load(std::memory_order_relaxed));
  b[8] = static_cast<std::uint16_t>(report_.records_rejected.load(std::memory_order_relaxed) & 0xffffu);
}

bool PlcLink::poll() {
  drivers::CellBlock cell{};
  fill_cell_block(cell);
  drivers::PlcBlock plc{};
  const bool answered = plc_.exchange(cell, plc);
  const Nanos now = now_(now_user_);
  std::string error = plc_.error();
  bool valid = true;
  if (answered) {
    msg::LineArrival decoded = last_;
    valid = drivers::decode_plc_block(plc, decoded, error);
    // A block that is not valid still shows the PLC alive, but announces nothing: the
    // control lane keeps the last valid word (a panel then finds no record for it).
    if (valid) last_ = decoded;
    last_.heard = now;
    arrivals_.write(last_);
  }
  std::lock_guard lock(mutex_);
  word_.arrival = last_;
  word_.valid = valid;
  word_.error = answered && valid ? std::string() : error;
  if (answered) ++word_.answers;
  return answered;
}

void PlcLink::start_thread() {
  thread_ = std::thread([this] {
    std::unique_lock lock(stop_mutex_);
    while (!stopping_) {
      lock.unlock();
      poll();
      lock.lock();
      stop_cv_.wait_for(lock, std::chrono::nanoseconds(config_.poll), [this] { return stopping_; });
    }
  });
}

void PlcLink::stop() {
  {
    std::lock_guard lock(stop_mutex_);
    stopping_ = true;
  }
  stop_cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

LineWord PlcLink::word() const {
  std::lock_guard lock(mutex_);
  return word_;
}

}  // namespace markcell::host
