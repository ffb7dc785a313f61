#pragma once
// The line's PLC over Modbus TCP (libmodbus): the client side of the register map
// docs/line.md documents. The PLC is the server; the cell reads the PLC's block of
// holding registers (which panel comes next: an arrival counter, its id and type) and
// writes its own block (a heartbeat and status words mirroring the I/O lines). Off the
// real-time path: a thread of the service polls it and hands the words to the control
// lane through a triple buffer. Every call is bounded by the response timeout (connect
// included).
#include <array>
#include <cstdint>
#include <span>
#include <string>

#include "markcell/common/time.hpp"
#include "markcell/msg/line_arrival.hpp"

struct _modbus;  // libmodbus's context

namespace markcell::drivers {

inline constexpr std::uint16_t kPlcRegisterMapVersion = 1;
// The PLC's block: [0] map version, [1] arrival counter, [2..33] panel id (64 bytes),
// [34..49] panel type (32 bytes); text two bytes a register, high byte first,
// NUL-padded.
inline constexpr int kPlcBlockRegisters = 50;
// The cell's block: [0] map version, [1] heartbeat, [2] lines (bit = role), [3] safe
// stop (1) and [4] its fault code, [5] the arrival counter heard, [6] panels done,
// [7] the last panel's result (0 none, 1 done, 2 fault), [8] records rejected.
inline constexpr int kCellBlockRegisters = 9;

using PlcBlock = std::array<std::uint16_t, kPlcBlockRegisters>;
using CellBlock = std::array<std::uint16_t, kCellBlockRegisters>;

// The PLC's block decoded: false, with what is wrong in `error` (the register and the
// value), when the version is not this map's, a text is not printable ASCII (NUL-padded),
// or a panel is announced without an id. `out.heard` is left as it was.
bool decode_plc_block(const PlcBlock& block, msg::LineArrival& out, std::string& error);
// `text` into `count` registers from `at` (two bytes each, high first, NUL-padded); the
// PLC's side of the same encoding (tests, the simulated PLC).
void encode_text(std::string_view text, std::span<std::uint16_t> registers);

struct ModbusPlcConfig {
  std::string address;  // IPv4
  int port = 502;
  int unit_id = 1;
  int plc_block = 0;    // first holding register of the PLC's block
  int cell_block = 100; // first holding register of the cell's block
  Nanos response_timeout = millis(200);
};

class ModbusPlc {
 public:
  explicit ModbusPlc(ModbusPlcConfig config);
  ~ModbusPlc();
  ModbusPlc(const ModbusPlc&) = delete;
  ModbusPlc& operator=(const ModbusPlc&) = delete;

  // One exchange: connects if not connected, writes the cell's block, reads the PLC's.
  // False: what failed in error() (the connection is closed, the next call connects).
  bool exchange(const CellBlock& cell, PlcBlock& plc);
  const std::string& error() const { return error_; }
  std::string peer() const { return config_.address + ":" + std::to_string(config_.port); }

 private:
  bool fail(const char* what);
  ModbusPlcConfig config_;
  _modbus* ctx_ = nullptr;
  bool connected_ = false;
  std::string error_;
};

}  // namespace markcell::drivers
