// libFuzzer target: the arm's CAN protocol decoder, and the link state machine fed with
// arbitrary frames (ids, lengths, flags, error frames) on the in-memory wire.
#include <cstdint>
#include <cstdlib>
#include <cstring>

#include "markcell/drivers/can_arm_link.hpp"

using namespace markcell;
using namespace markcell::drivers;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  SimCanWire wire;
  Nanos now = 0;
  wire.set_time_source([](void* t) { return *static_cast<Nanos*>(t); }, &now);
  wire.b().open();
  CanArmLink link(wire.a(), CanArmLinkConfig{});
  link.activate(now);
  std::size_t at = 0;
  // Each frame: 2 bytes id+flags, 1 byte length, then up to 8 (classic) or 64 (FD) data bytes.
  while (at + 3 <= size) {
    CanFrame f;
    const std::uint16_t word = static_cast<std::uint16_t>(data[at] | (data[at + 1] << 8));
    f.id = word & 0x7FF;
    f.error = (word & 0x8000) != 0;
    f.extended = (word & 0x4000) != 0;
    f.fd = (word & 0x2000) != 0;
    f.len = static_cast<std::uint8_t>(data[at + 2] % (f.fd ? 65 : 9));
    at += 3;
    const std::size_t n = std::min<std::size_t>(f.len, size - at);
    std::memcpy(f.data.data(), data + at, n);
    at += n;
    canopen::Message m;
    (void)canopen::decode(f, m);
    wire.a().inject(f);
    now += millis(1);
    const ArmLinkStatus s = link.poll(now);
    if (static_cast<int>(s) > static_cast<int>(ArmLinkStatus::kIoError)) std::abort();
  }
  return 0;
}
