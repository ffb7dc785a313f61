// The Modbus register map's PLC block (docs/line.md) decoded from registers written by
// hand, two ASCII bytes a register, high byte first.
#include <catch2/catch.hpp>

#include "markcell/drivers/modbus_plc.hpp"

using namespace markcell;

namespace {
drivers::PlcBlock block(std::uint16_t version, std::uint16_t counter) {
  drivers::PlcBlock b{};
  b[0] = version;
  b[1] = counter;
  return b;
}
}  // namespace

TEST_CASE("the PLC's block: counter, id and type decoded from two bytes a register, high byte first") {
  drivers::PlcBlock b = block(1, 42);
  b[2] = 0x4431;  // 'D' '1'
  b[3] = 0x2d37;  // '-' '7'
  b[4] = 0x3900;  // '9' NUL
  b[34] = 0x646f;  // "do"
  b[35] = 0x6f72;  // "or"
  msg::LineArrival a;
  a.heard = 123;
  std::string error;
  REQUIRE(drivers::decode_plc_block(b, a, error));
  CHECK(a.counter == 42);
  CHECK(a.panel_id.view() == "D1-79");
  CHECK(a.panel_type.view() == "door");
  CHECK(a.heard == 123);  // left as it was
}

TEST_CASE("the PLC's block: encode_text is decode's inverse, 63 bytes of id and 31 of type at most") {
  drivers::PlcBlock b = block(1, 65535);
  const std::string id(63, 'x');
  drivers::encode_text(id, std::span<std::uint16_t>(b.data() + 2, 32));
  drivers::encode_text("fender", std::span<std::uint16_t>(b.data() + 34, 16));
  CHECK(b[2] == 0x7878);
  CHECK(b[34] == 0x6665);  // "fe"
  CHECK(b[37] == 0x0000);  // padding
  msg::LineArrival a;
  std::string error;
  REQUIRE(drivers::decode_plc_block(b, a, error));
  CHECK(a.panel_id.view() == id);
  CHECK(a.panel_type.view() == "fender");
  CHECK(a.counter == 65535);
  // One byte more than a record's panel_id may have: refused, never cut.
  drivers::encode_text(std::string(64, 'y'), std::span<std::uint16_t>(b.data() + 2, 32));
  CHECK_FALSE(drivers::decode_plc_block(b, a, error));
  CHECK(error == "registers 2-33 (panel id): 64 bytes, at most 63");
  CHECK(a.panel_id.view() == id);
  drivers::encode_text("p", std::span<std::uint16_t>(b.data() + 2, 32));
  drivers::encode_text(std::string(32, 't'), std::span<std::uint16_t>(b.data() + 34, 16));
  CHECK_FALSE(drivers::decode_plc_block(b, a, error));
  CHECK(error == "registers 34-49 (panel type): 32 bytes, at most 31");
}

TEST_CASE("the PLC's block refused: version, non-ASCII, text after the padding, a count without an id") {
  msg::LineArrival a;
  a.counter = 5;
  a.panel_id.assign("before");
  std::string error;
  CHECK_FALSE(drivers::decode_plc_block(block(2, 1), a, error));
  CHECK(error == "register 0 (map version): 2, markcell speaks version 1");
  drivers::PlcBlock b = block(1, 1);
  b[2] = 0x41ff;
  CHECK_FALSE(drivers::decode_plc_block(b, a, error));
  CHECK(error == "register 2 (panel id): byte 0xff is not printable ASCII");
  b[2] = 0x4100;
  b[3] = 0x4200;  // 'B' after the NUL that ended the id
  CHECK_FALSE(drivers::decode_plc_block(b, a, error));
  CHECK(error == "register 3 (panel id): byte 0x42 after the NUL padding");
  b = block(1, 1);
  b[34] = 0x0a00;  // a newline in the type
  b[2] = 0x4100;
  CHECK_FALSE(drivers::decode_plc_block(b, a, error));
  CHECK(error == "register 34 (panel type): byte 0x0a is not printable ASCII");
  CHECK_FALSE(drivers::decode_plc_block(block(1, 9), a, error));
  CHECK(error == "register 1 (arrival counter): 9 announces a panel, but its id (registers 2-33) is empty");
  // Nothing refused changed the word.
  CHECK(a.counter == 5);
  CHECK(a.panel_id.view() == "before");
  // Counter 0 with no id: nothing announced yet, valid.
  REQUIRE(drivers::decode_plc_block(block(1, 0), a, error));
  CHECK(a.counter == 0);
  CHECK(a.panel_id.empty());
}
