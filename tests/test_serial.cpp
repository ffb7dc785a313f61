// The serial arm protocol (pure codec on byte vectors) and the link against the
// simulated arm over socat pseudo-terminals: normal exchange, line noise, refusals,
// lost acknowledgements and a peer that vanishes.
#include <catch2/catch.hpp>
#include <chrono>
#include <cmath>
#include <limits>
#include <thread>
#include <vector>

#include "markcell/drivers/serial_arm_link.hpp"
#include "markcell/drivers/serial_protocol.hpp"
#include "markcell/drivers/sim_arm.hpp"
#include "alloc_guard.hpp"
#include "socat_pair.hpp"

using namespace markcell;
using namespace markcell::drivers;
namespace sp = markcell::drivers::serial;

namespace {


std::vector<std::uint8_t> command_frame(const ArmCommand& c, std::uint8_t seq) {
  std::array<std::uint8_t, sp::kMaxFrame> out{};
  const auto n = sp::encode_command(c, seq, out);
  return {out.begin(), out.begin() + static_cast<std::ptrdiff_t>(n)};
}

sp::Decoder::Result decode_one(const std::vector<std::uint8_t>& in, sp::Frame& f) {
  sp::Decoder d;
  d.push(in);
  return d.next(f);
}

ArmCommand sample_command() {
  ArmCommand c;
  c.mode = ArmMode::kMove;
  c.time = 1'234'567'890'123LL;
  c.target.position = {0.5, -0.25, 0.125};  // exact in binary32
  c.target.rotation = {0.0, 1.5, -0.75};
  return c;
}

}  // namespace

TEST_CASE("CRC-16/CCITT-FALSE matches its catalogue check value") {
  const std::string check = "123456789";
  CHECK(sp::crc16(std::span<const std::uint8_t>(reinterpret_cast<const std::uint8_t*>(check.data()), check.size())) == 0x29B1);
}

TEST_CASE("frames round-trip: command, ack, state") {
  const ArmCommand c = sample_command();
  const auto frame = command_frame(c, 42);
  REQUIRE(frame.size() == sp::kHeader + sp::kCommandSize + 2);
  CHECK(frame[0] == 0xA5);
  CHECK(frame[1] == 0x5A);
  CHECK(frame[2] == sp::kCommandSize);
  CHECK(frame[3] == 42);
  sp::Frame f;
  REQUIRE(decode_one(frame, f) == sp::Decoder::Result::kFrame);
  ArmCommand back;
  REQUIRE(sp::decode_command(f, back) == sp::PayloadError::kOk);
  CHECK(f.seq == 42);
  CHECK(back.mode == c.mode);
  CHECK(back.time == c.time);
  CHECK(back.target.position == c.target.position);
  CHECK(back.target.rotation == c.target.rotation);

  std::array<std::uint8_t, sp::kMaxFrame> out{};
  auto n = sp::encode_ack(7, sp::AckResult::kUnreachable, out);
  REQUIRE(decode_one({out.begin(), out.begin() + static_cast<std::ptrdiff_t>(n)}, f) == sp::Decoder::Result::kFrame);
  std::uint8_t acked = 0;
  sp::AckResult result{};
  REQUIRE(sp::decode_ack(f, acked, result) == sp::PayloadError::kOk);
  CHECK(acked == 7);
  CHECK(result == sp::AckResult::kUnreachable);

  ArmState s;
  s.tool = c.target;
  s.mode = ArmMode::kHome;
  s.flags = kInPosition | kHomed;
  s.fault_code = 3;
  s.applied_seq = 9;
  n = sp::encode_state(s, 555, 1, out);
  REQUIRE(decode_one({out.begin(), out.begin() + static_cast<std::ptrdiff_t>(n)}, f) == sp::Decoder::Result::kFrame);
  ArmState sb;
  Nanos t = 0;
  REQUIRE(sp::decode_state(f, sb, t) == sp::PayloadError::kOk);
  CHECK(t == 555);
  CHECK(sb.tool.position == s.tool.position);
  CHECK(sb.mode == ArmMode::kHome);
  CHECK(sb.flags == (kInPosition | kHomed));
  CHECK(sb.fault_code == 3);
  CHECK(sb.applied_seq == 9);
}

TEST_CASE("every malformed input class is rejected with its reason") {
  const auto good = command_frame(sample_command(), 1);
  sp::Frame f;
  SECTION("length over the maximum") {
    auto b = good;
    b[2] = sp::kMaxPayload + 1;
    CHECK(decode_one(b, f) == sp::Decoder::Result::kBadLength);
  }
  SECTION("unknown type") {
    auto b = good;
    b[4] = 9;
    CHECK(decode_one(b, f) == sp::Decoder::Result::kBadType);
  }
  SECTION("corrupted payload byte") {
    auto b = good;
    b[10] ^= 0x40;
    CHECK(decode_one(b, f) == sp::Decoder::Result::kBadCrc);
  }
  SECTION("corrupted CRC") {
    auto b = good;
    b.back() ^= 0x01;
    CHECK(decode_one(b, f) == sp::Decoder::Result::kBadCrc);
  }
  SECTION("truncated frame waits for more") {
    auto b = good;
    b.resize(b.size() - 3);
    CHECK(decode_one(b, f) == sp::Decoder::Result::kNeedMore);
  }
  SECTION("payload of the wrong size for its type") {
    std::array<std::uint8_t, sp::kMaxFrame> out{};
    const std::array<std::uint8_t, 5> short_payload{};
    const auto n = sp::encode(sp::FrameType::kCommand, 3, short_payload, out);
    REQUIRE(decode_one({out.begin(), out.begin() + static_cast<std::ptrdiff_t>(n)}, f) == sp::Decoder::Result::kFrame);
    ArmCommand c;
    CHECK(sp::decode_command(f, c) == sp::PayloadError::kWrongSize);
    CHECK(sp::to_string(sp::decode_command(f, c)) == "payload has the wrong size for its type");
  }
  SECTION("unknown mode") {
    ArmCommand c = sample_command();
    c.mode = static_cast<ArmMode>(7);
    REQUIRE(decode_one(command_frame(c, 1), f) == sp::Decoder::Result::kFrame);
    CHECK(sp::decode_command(f, c) == sp::PayloadError::kBadMode);
  }
  SECTION("non-finite pose") {
    ArmCommand c = sample_command();
    c.target.position[1] = std::numeric_limits<double>::quiet_NaN();
    REQUIRE(decode_one(command_frame(c, 1), f) == sp::Decoder::Result::kFrame);
    CHECK(sp::decode_command(f, c) == sp::PayloadError::kNotFinite);
  }
  SECTION("unknown ack result") {
    std::array<std::uint8_t, sp::kMaxFrame> out{};
    const std::array<std::uint8_t, 2> payload{1, 9};
    const auto n = sp::encode(sp::FrameType::kAck, 1, payload, out);
    REQUIRE(decode_one({out.begin(), out.begin() + static_cast<std::ptrdiff_t>(n)}, f) == sp::Decoder::Result::kFrame);
    std::uint8_t s = 0;
    sp::AckResult r{};
    CHECK(sp::decode_ack(f, s, r) == sp::PayloadError::kBadResult);
  }
}

TEST_CASE("the decoder resynchronises after noise, false starts and corrupt frames") {
  const auto a = command_frame(sample_command(), 1);
  const auto b = command_frame(sample_command(), 2);
  auto corrupt = command_frame(sample_command(), 3);
  corrupt[12] ^= 0xFF;
  std::vector<std::uint8_t> stream = {0x00, 0xFF, 0xA5, 0x13, 0xA5};  // noise with a false start
  stream.insert(stream.end(), a.begin(), a.end());
  stream.insert(stream.end(), {0xA5, 0x5A, 0xF0});  // a header claiming 240 bytes
  stream.insert(stream.end(), corrupt.begin(), corrupt.end());
  stream.insert(stream.end(), b.begin(), b.end());
  sp::Decoder d;
  std::vector<std::uint8_t> seqs;
  int errors = 0;
  for (std::uint8_t byte : stream) {  // one byte at a time, as a slow line delivers them
    REQUIRE(d.push(std::span<const std::uint8_t>(&byte, 1)) == 1);
    sp::Frame f;
    for (;;) {
      const auto r = d.next(f);
      if (r == sp::Decoder::Result::kNeedMore) break;
      if (r == sp::Decoder::Result::kFrame) seqs.push_back(f.seq);
      else ++errors;
    }
  }
  CHECK(seqs == std::vector<std::uint8_t>{1, 2});
  CHECK(errors >= 2);  // the over-long header and the corrupt frame
}

namespace {

struct Bench {
  explicit Bench(SerialArmLinkConfig cfg = {}) : socat(dir), arm(SimArmLimits{}) {
    cfg.device = socat.a();
    link = std::make_unique<SerialArmLink>(cfg);
    arm.open(socat.b(), cfg.baud);
    link->activate(monotonic_now());
  }
  // Runs both ends for `ms` of real time, 1 ms apart.
  void run(int ms) {
    for (int i = 0; i < ms; ++i) {
      const Nanos now = monotonic_now();
      arm.poll(now);
      link->poll(now);
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
  }
  test::TempDir dir;
  test::SocatPair socat;
  SimSerialArm arm;
  std::unique_ptr<SerialArmLink> link;
};

}  // namespace

TEST_CASE("serial link over socat: the arm moves to the set-point and reports it") {
  Bench b;
  b.run(100);
  CHECK(b.link->status() == ArmLinkStatus::kOk);
  ArmCommand c;
  c.mode = ArmMode::kMove;
  c.time = monotonic_now();
  c.target.position = {0.5, 0.2, 0.4};
  const auto seq = b.link->send(c, monotonic_now());
  b.run(1500);  // 0.35 m at 1 m/s and 4 m/s^2: well under a second
  CHECK(b.link->status() == ArmLinkStatus::kOk);
  const ArmState& s = b.link->state();
  CHECK(s.applied_seq == seq);
  CHECK(s.in_position());
  for (int i = 0; i < 3; ++i) CHECK(s.tool.position[static_cast<std::size_t>(i)] == Approx(c.target.position[static_cast<std::size_t>(i)]).margin(0.001));
  CHECK(b.link->counters().states_received > 100);
  CHECK(b.link->counters().decode_errors == 0);
}

TEST_CASE("serial link over socat: sending and polling allocate nothing once active") {
  Bench b;
  b.run(50);
  ArmCommand c;
  c.mode = ArmMode::kMove;
  c.target.position = {0.4, 0.1, 0.5};
  std::size_t allocations = 0;
  {
    test::AllocationGuard guard;
    for (int i = 0; i < 300; ++i) {
      const Nanos now = monotonic_now();
      if (i % 10 == 0) b.link->send(c, now);
      b.link->poll(now);
      b.arm.poll(now);
    }
    allocations = guard.allocations();
  }
  CHECK(allocations == 0);
  CHECK(b.link->status() == ArmLinkStatus::kOk);
}

TEST_CASE("serial link over socat: line noise is survived and counted") {
  Bench b;
  const std::array<std::uint8_t, 12> noise{0xA5, 0x5A, 0x20, 0x01, 0x03, 0xDE, 0xAD, 0xBE, 0xEF, 0xA5, 0x00, 0x5A};
  for (int i = 0; i < 20; ++i) {
    b.arm.send_raw(noise);
    b.run(10);
  }
  b.run(50);
  CHECK(b.link->status() == ArmLinkStatus::kOk);
  CHECK(b.link->counters().states_received > 10);
  CHECK(b.link->decoder().discarded_bytes() > 0);
}

TEST_CASE("serial link over socat: refusal, missing acknowledgements, silence, hang-up") {
  SECTION("an unreachable target is refused") {
    Bench b;
    b.run(50);
    ArmCommand c;
    c.mode = ArmMode::kMove;
    c.target.position = {3.0, 0.0, 0.0};  // beyond the 1.6 m reach
    b.link->send(c, monotonic_now());
    b.run(50);
    CHECK(b.link->status() == ArmLinkStatus::kRefused);
    CHECK(b.link->counters().refusals == 1);
  }
  SECTION("no acknowledgement after every retry") {
    SerialArmLinkConfig cfg;
    cfg.retries = 2;
    cfg.ack_timeout = millis(20);
    Bench b(cfg);
    b.arm.set_drop_acks(true);
    b.run(30);
    b.link->send(ArmCommand{}, monotonic_now());
    b.run(200);
    CHECK(b.link->status() == ArmLinkStatus::kNoAck);
    CHECK(b.link->counters().retries == 2);
    CHECK(b.arm.commands_received() == 3);
    CHECK(is_fault(b.link->status()));
  }
  SECTION("the arm falls silent: heartbeat lost") {
    Bench b;
    b.run(50);
    REQUIRE(b.link->status() == ArmLinkStatus::kOk);
    b.arm.set_silent(true);
    // Timeout 150 ms of listening: on a busy machine a poll more than 5 ms late does not
    // count its gap (SilenceTimer), so the test polls until it is lost, at most 3 s.
    for (int i = 0; i < 30 && b.link->status() != ArmLinkStatus::kHeartbeatLost; ++i) b.run(100);
    CHECK(b.link->status() == ArmLinkStatus::kHeartbeatLost);
  }
  SECTION("the peer vanishes: the line hangs up") {
    Bench b;
    b.run(50);
    b.arm.close();
    b.socat.kill();
    b.run(200);
    CHECK(is_fault(b.link->status()));
  }
}
