// libFuzzer target: the arm's serial protocol decoder and payload decoders on arbitrary
// bytes, delivered in arbitrary chunks. Crashes, sanitizer reports and broken invariants
// (a frame longer than the maximum, a decoded pose that is not finite) are findings.
#include <cmath>
#include <cstdint>
#include <cstdlib>

#include "markcell/drivers/serial_protocol.hpp"

using namespace markcell::drivers;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  serial::Decoder decoder;
  std::size_t at = 0;
  while (at < size) {
    // The first byte of each chunk says how long the chunk is: arbitrary fragmentation.
    const std::size_t chunk = std::min<std::size_t>(size - at, 1 + data[at] % 40);
    std::span<const std::uint8_t> in(data + at, chunk);
    at += chunk;
    decoder.consume(
        in,
        [](const serial::Frame& f) {
          if (f.length > serial::kMaxPayload) std::abort();
          ArmCommand c;
          if (serial::decode_command(f, c) == serial::PayloadError::kOk)
            for (double v : c.target.position) if (!std::isfinite(v)) std::abort();
          ArmState s;
          markcell::Nanos t = 0;
          if (serial::decode_state(f, s, t) == serial::PayloadError::kOk)
            for (double v : s.tool.rotation) if (!std::isfinite(v)) std::abort();
          std::uint8_t seq = 0;
          serial::AckResult result{};
          (void)serial::decode_ack(f, seq, result);
        },
        [] {});
  }
  return 0;
}
