#include "markcell/drivers/modbus_plc.hpp"

#include <modbus/modbus.h>

#include <cerrno>
#include <cstdio>
#include <stdexcept>

namespace markcell::drivers {

namespace {
// The text in registers [from, from + count): printable ASCII then NUL padding.
bool decode_text(const PlcBlock& block, int from, int count, const char* name, std::string& out, std::string& error) {
  out.clear();
  bool ended = false;
  for (int r = from; r < from + count; ++r) {
    for (int half = 0; half < 2; ++half) {
      const unsigned c = half == 0 ? block[static_cast<std::size_t>(r)] >> 8 : block[static_cast<std::size_t>(r)] & 0xffu;
      if (c == 0) {
        ended = true;
        continue;
      }
      if (ended || c < 0x20 || c > 0x7e) {
        char text[160];
        std::snprintf(text, sizeof text, "register %d (%s): byte 0x%02x %s", r, name, c,
                      ended ? "after the NUL padding" : "is not printable ASCII");
        error = text;
        return false;
      }
      out.push_back(static_cast<char>(c));
    }
  }
  return true;
}
}  // namespace

bool decode_plc_block(const PlcBlock& block, msg::LineArrival& out, std::string& error) {
  if (block[0] != kPlcRegisterMapVersion) {
    error = "register 0 (map version): " + std::to_string(block[0]) + ", markcell speaks version " +
            std::to_string(kPlcRegisterMapVersion);
    return false;
  }
  std::string id, type;
  if (!decode_text(block, 2, 32, "panel id", id, error) || !decode_text(block, 34, 16, "panel type", type, error)) return false;
  // As long as an inspection record's panel_id and panel_type may be (a longer one could
  // only be cut, and a cut id may name another panel).
  if (id.size() > decltype(out.panel_id)::capacity() || type.size() > decltype(out.panel_type)::capacity()) {
    const bool id_long = id.size() > decltype(out.panel_id)::capacity();
    error = std::string(id_long ? "registers 2-33 (panel id): " : "registers 34-49 (panel type): ") +
            std::to_string((id_long ? id : type).size()) + " bytes, at most " +
            std::to_string(id_long ? decltype(out.panel_id)::capacity() : decltype(out.panel_type)::capacity());
    return false;
  }
  if (block[1] != 0 && id.empty()) {
    error = "register 1 (arrival counter): " + std::to_string(block[1]) + " announces a panel, but its id (registers 2-33) is empty";
    return false;
  }
  out.counter = block[1];
  out.panel_id.assign(id);
  out.panel_type.assign(type);
  return true;
}

void encode_text(std::string_view text, std::span<std::uint16_t> registers) {
  for (std::size_t r = 0; r < registers.size(); ++r) {
    const auto byte = [&](std::size_t i) -> std::uint16_t { return i < text.size() ? static_cast<unsigned char>(text[i]) : 0; };
    registers[r] = static_cast<std::uint16_t>(byte(2 * r) << 8 | byte(2 * r + 1));
  }
}

ModbusPlc::ModbusPlc(ModbusPlcConfig config) : config_(std::move(config)) {
  ctx_ = modbus_new_tcp(config_.address.c_str(), config_.port);
  if (ctx_ == nullptr) throw std::runtime_error("Modbus TCP " + peer() + ": " + modbus_strerror(errno));
  const auto us = static_cast<std::uint32_t>(config_.response_timeout / micros(1));
  modbus_set_response_timeout(ctx_, us / 1'000'000, us % 1'000'000);
  modbus_set_byte_timeout(ctx_, us / 1'000'000, us % 1'000'000);
  modbus_set_slave(ctx_, config_.unit_id);
}

ModbusPlc::~ModbusPlc() {
  if (connected_) modbus_close(ctx_);
  modbus_free(ctx_);
}

bool ModbusPlc::fail(const char* what) {
  error_ = std::string(what) + " (Modbus TCP " + peer() + ", unit " + std::to_string(config_.unit_id) + "): " +
           modbus_strerror(errno);
  modbus_close(ctx_);
  connected_ = false;
  return false;
}

bool ModbusPlc::exchange(const CellBlock& cell, PlcBlock& plc) {
  if (!connected_) {
    if (modbus_connect(ctx_) != 0) return fail("connect");
    connected_ = true;
  }
  if (modbus_write_registers(ctx_, config_.cell_block, kCellBlockRegisters, cell.data()) != kCellBlockRegisters)
    return fail("writing the cell's block");
  if (modbus_read_registers(ctx_, config_.plc_block, kPlcBlockRegisters, plc.data()) != kPlcBlockRegisters)
    return fail("reading the PLC's block");
  error_.clear();
  return true;
}

}  // namespace markcell::drivers
