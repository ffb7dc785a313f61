// The CAN arm protocol: codec on frames, the DBC catalogue against the codec, and the
// link against the simulated arm over the in-memory wire in simulated time.
#include <sys/socket.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <cmath>
#include <limits>
#include <linux/can.h>

#include "dbc.hpp"
#include "markcell/drivers/can_arm_link.hpp"
#include "markcell/drivers/can_protocol.hpp"
#include "test_files.hpp"

using namespace markcell;
using namespace markcell::drivers;
namespace co = markcell::drivers::canopen;

namespace {

ArmCommand sample() {
  ArmCommand c;
  c.mode = ArmMode::kMove;
  c.time = 5'000'123'456LL;
  c.target.position = {0.61234, -0.2, 1.5};
  c.target.rotation = {0.1, -3.1415, 0.00004};
  return c;
}

}  // namespace

TEST_CASE("CAN codec: a set-point round-trips at the wire's resolution") {
  std::array<CanFrame, 3> frames;
  REQUIRE(co::encode_command(sample(), 77, 2, frames) == co::EncodeError::kOk);
  CHECK(frames[0].id == 0x202);
  CHECK(frames[1].id == 0x302);
  CHECK(frames[2].id == 0x402);
  co::Message m;
  REQUIRE(co::decode(frames[0], m) == co::DecodeError::kOk);
  CHECK(m.kind == co::Kind::kTargetPosition);
  CHECK(m.node == 2);
  CHECK(m.seq == 77);
  CHECK(m.mode_or_status == static_cast<std::uint8_t>(ArmMode::kMove));
  for (std::size_t i = 0; i < 3; ++i) CHECK(std::abs(m.vector[i] - sample().target.position[i]) <= 0.5e-4 + 1e-12);
  REQUIRE(co::decode(frames[1], m) == co::DecodeError::kOk);
  for (std::size_t i = 0; i < 3; ++i) CHECK(std::abs(m.vector[i] - sample().target.rotation[i]) <= 0.5e-4 + 1e-12);
  REQUIRE(co::decode(frames[2], m) == co::DecodeError::kOk);
  CHECK(m.time_us == static_cast<std::uint32_t>(5'000'123ULL & 0xFFFFFFFFULL));
  CHECK(m.seq == 77);
}

TEST_CASE("CAN codec: values the wire cannot carry are refused at encoding") {
  std::array<CanFrame, 3> frames;
  ArmCommand c = sample();
  c.target.position[0] = 3.3;
  CHECK(co::encode_command(c, 1, 2, frames) == co::EncodeError::kOutOfRange);
  c = sample();
  c.target.rotation[2] = std::numeric_limits<double>::infinity();
  CHECK(co::encode_command(c, 1, 2, frames) == co::EncodeError::kNotFinite);
}

TEST_CASE("CAN codec: every malformed input class is rejected with its reason") {
  co::Message m;
  CanFrame f = co::heartbeat(2, co::NmtState::kOperational);
  SECTION("unknown id") {
    f.id = 0x502;
    CHECK(co::decode(f, m) == co::DecodeError::kUnknownId);
    CHECK(co::to_string(co::decode(f, m)) == "id is not in the arm's message catalogue");
  }
  SECTION("node 0 is not a node") {
    f.id = 0x700;
    CHECK(co::decode(f, m) == co::DecodeError::kUnknownId);
  }
  SECTION("wrong length") {
    f.len = 2;
    CHECK(co::decode(f, m) == co::DecodeError::kWrongLength);
  }
  SECTION("unknown NMT state") {
    f.data[0] = 0x33;
    CHECK(co::decode(f, m) == co::DecodeError::kBadNmtState);
  }
  SECTION("unknown NMT command") {
    f = co::nmt(co::NmtCommand::kStart, 2);
    f.data[0] = 0x07;
    CHECK(co::decode(f, m) == co::DecodeError::kBadNmtCommand);
  }
  SECTION("unknown mode") {
    std::array<CanFrame, 3> frames;
    REQUIRE(co::encode_command(sample(), 1, 2, frames) == co::EncodeError::kOk);
    frames[0].data[6] = 9;
    CHECK(co::decode(frames[0], m) == co::DecodeError::kBadMode);
  }
  SECTION("reserved bytes not zero") {
    std::array<CanFrame, 3> frames;
    REQUIRE(co::encode_command(sample(), 1, 2, frames) == co::EncodeError::kOk);
    frames[2].data[7] = 1;
    CHECK(co::decode(frames[2], m) == co::DecodeError::kReservedNotZero);
  }
  SECTION("error frames and extended ids") {
    f.error = true;
    CHECK(co::decode(f, m) == co::DecodeError::kRemoteOrError);
    f.error = false;
    f.extended = true;
    CHECK(co::decode(f, m) == co::DecodeError::kRemoteOrError);
  }
}

TEST_CASE("the DBC catalogue decodes the codec's frames to the same values") {
  const auto dbc = test::Dbc::load(test::source_path("config/markcell_arm.dbc"));
  REQUIRE(dbc.messages().size() == 11);
  std::array<CanFrame, 3> cmd;
  REQUIRE(co::encode_command(sample(), 200, 2, cmd) == co::EncodeError::kOk);
  ArmState s;
  s.tool = sample().target;
  s.flags = kInPosition | kHomed;
  s.fault_code = 17;
  std::array<CanFrame, 2> state;
  REQUIRE(co::encode_state(s, static_cast<std::uint8_t>(s.flags | co::kStatusRefused), 9, 2, state) == co::EncodeError::kOk);
  CanFrame cmd_fd, state_fd;
  REQUIRE(co::encode_command_fd(sample(), 200, 2, cmd_fd) == co::EncodeError::kOk);
  REQUIRE(co::encode_state_fd(s, static_cast<std::uint8_t>(s.flags | co::kStatusRefused), 9, 2, state_fd) == co::EncodeError::kOk);
  const std::vector<CanFrame> all = {co::nmt(co::NmtCommand::kStart, 2), co::sync(), cmd[0], cmd[1], cmd[2], state[0], state[1],
                                     co::heartbeat(2, co::NmtState::kOperational), co::heartbeat(1, co::NmtState::kOperational),
                                     cmd_fd, state_fd};
  for (const auto& f : all) {
    INFO("id 0x" << std::hex << f.id);
    REQUIRE(dbc.find(f.id) != nullptr);
    const auto v = dbc.decode(f.id, f.data.data(), f.len);
    co::Message m;
    REQUIRE(co::decode(f, m) == co::DecodeError::kOk);
    switch (m.kind) {
      case co::Kind::kNmt:
        CHECK(v.at("nmt_command") == 1);
        CHECK(v.at("nmt_node") == 2);
        break;
      case co::Kind::kSync: CHECK(v.empty()); break;
      case co::Kind::kTargetPosition:
        CHECK(v.at("target_x") == Approx(m.vector[0]).margin(1e-12));
        CHECK(v.at("target_y") == Approx(m.vector[1]).margin(1e-12));
        CHECK(v.at("target_z") == Approx(m.vector[2]).margin(1e-12));
        CHECK(v.at("mode") == 1);
        CHECK(v.at("seq") == 200);
        break;
      case co::Kind::kTargetRotation:
        CHECK(v.at("target_ry") == Approx(m.vector[1]).margin(1e-12));
        CHECK(v.at("seq") == 200);
        break;
      case co::Kind::kTargetTime:
        CHECK(v.at("time_us") == m.time_us);
        CHECK(v.at("seq") == 200);
        break;
      case co::Kind::kToolPosition:
        CHECK(v.at("tool_x") == Approx(m.vector[0]).margin(1e-12));
        CHECK(v.at("status") == (kInPosition | kHomed | co::kStatusRefused));
        CHECK(v.at("seq") == 9);
        break;
      case co::Kind::kToolRotation:
        CHECK(v.at("tool_rz") == Approx(m.vector[2]).margin(1e-12));
        CHECK(v.at("fault_code") == 17);
        break;
      case co::Kind::kHeartbeat: CHECK(v.at("nmt_state") == 5); break;
      case co::Kind::kTargetFd:
        CHECK(v.at("fd_target_x") == Approx(m.vector[0]).margin(1e-12));
        CHECK(v.at("fd_target_rz") == Approx(m.vector2[2]).margin(1e-12));
        CHECK(v.at("seq") == 200);
        CHECK(v.at("time_us") == m.time_us);
        break;
      case co::Kind::kToolFd:
        CHECK(v.at("fd_tool_y") == Approx(m.vector[1]).margin(1e-12));
        CHECK(v.at("status") == (kInPosition | kHomed | co::kStatusRefused));
        CHECK(v.at("fault_code") == 17);
        break;
    }
  }
}

namespace {

// The link and the simulated arm on an in-memory wire, in simulated time.
struct SimBench {
  SimBench() : arm(wire.b(), 2, SimArmLimits{}), link(wire.a(), CanArmLinkConfig{}) {
    wire.set_time_source([](void* t) { return *static_cast<Nanos*>(t); }, &now);
    wire.a().open();
    arm.start(now);
    link.activate(now);
  }
  void run(Nanos duration) {
    const Nanos end = now + duration;
    while (now < end) {
      now += millis(1);
      arm.poll(now);
      link.poll(now);
    }
  }
  Nanos now = seconds(1);
  SimCanWire wire;
  SimCanArm arm;
  CanArmLink link;
};

}  // namespace

TEST_CASE("CAN link: NMT start, heartbeats, a set-point reached and reported") {
  SimBench b;
  CHECK(b.link.status() == ArmLinkStatus::kConnecting);
  b.run(millis(100));
  CHECK(b.arm.nmt_state() == co::NmtState::kOperational);
  CHECK(b.link.status() == ArmLinkStatus::kOk);
  ArmCommand c;
  c.mode = ArmMode::kMove;
  c.time = b.now;
  c.target.position = {0.8, -0.3, 0.5};
  c.target.rotation = {0.0, 1.5707, 0.0};
  const auto seq = b.link.send(c, b.now);
  b.run(millis(2000));
  const ArmState& s = b.link.state();
  CHECK(b.link.status() == ArmLinkStatus::kOk);
  CHECK(s.applied_seq == seq);
  CHECK(s.in_position());
  for (std::size_t i = 0; i < 3; ++i) {
    CHECK(s.tool.position[i] == Approx(c.target.position[i]).margin(1e-3));
    CHECK(s.tool.rotation[i] == Approx(c.target.rotation[i]).margin(1e-3));
  }
  CHECK(b.arm.set_points_applied() == 1);
  CHECK(b.link.counters().decode_errors == 0);
}

TEST_CASE("CAN FD: one frame per set-point and per state, at micrometre resolution, through link and arm") {
  CanFrame f;
  ArmCommand c = sample();
  REQUIRE(co::encode_command_fd(c, 5, 2, f) == co::EncodeError::kOk);
  CHECK(f.fd);
  CHECK(f.id == 0x502);
  CHECK(f.len == 32);
  co::Message m;
  REQUIRE(co::decode(f, m) == co::DecodeError::kOk);
  CHECK(m.kind == co::Kind::kTargetFd);
  for (std::size_t i = 0; i < 3; ++i) {
    CHECK(std::abs(m.vector[i] - c.target.position[i]) <= 0.5e-6 + 1e-12);
    CHECK(std::abs(m.vector2[i] - c.target.rotation[i]) <= 0.5e-6 + 1e-12);
  }
  CHECK(m.seq == 5);
  CHECK(m.mode_or_status == static_cast<std::uint8_t>(ArmMode::kMove));
  f.len = 24;
  CHECK(co::decode(f, m) == co::DecodeError::kWrongLength);

  // The link and the simulated arm both configured for FD, on the in-memory wire.
  Nanos now = seconds(1);
  SimCanWire wire;
  wire.set_time_source([](void* t) { return *static_cast<Nanos*>(t); }, &now);
  SimCanArm arm(wire.b(), 2, SimArmLimits{}, millis(10), millis(50), millis(200), true);
  CanArmLinkConfig cfg;
  cfg.fd = true;
  CanArmLink link(wire.a(), cfg);
  wire.a().open();
  arm.start(now);
  link.activate(now);
  auto run = [&](Nanos d) {
    for (const Nanos end = now + d; now < end;) {
      now += millis(1);
      arm.poll(now);
      link.poll(now);
    }
  };
  run(millis(100));
  REQUIRE(link.status() == ArmLinkStatus::kOk);
  c.time = now;
  c.target.position = {0.7, 0.1, 0.3};
  const auto seq = link.send(c, now);
  run(millis(2000));
  CHECK(link.state().applied_seq == seq);
  CHECK(link.state().in_position());
  CHECK(link.state().tool.position[0] == Approx(0.7).margin(1e-3));
  CHECK(arm.set_points_applied() == 1);
}

TEST_CASE("CAN link: heartbeat loss, refusal, arm reboot, bus-off and restart") {
  SimBench b;
  b.run(millis(100));
  REQUIRE(b.link.status() == ArmLinkStatus::kOk);
  SECTION("the arm falls silent: heartbeat lost after the timeout, not before") {
    b.arm.set_silent(true);
    b.run(millis(140));
    CHECK(b.link.status() == ArmLinkStatus::kOk);
    b.run(millis(100));
    CHECK(b.link.status() == ArmLinkStatus::kHeartbeatLost);
    CHECK(is_fault(b.link.status()));
  }
  SECTION("the controller deaf for 400 ms (its lane stalled, the simulated arm with it): not lost; then silent: lost") {
    b.now += millis(400);  // neither end ran: no poll, no heartbeat sent
    b.run(millis(1));
    CHECK(b.link.status() == ArmLinkStatus::kOk);
    b.run(millis(100));
    CHECK(b.link.status() == ArmLinkStatus::kOk);
    // The arm silent while the link listens: lost after the timeout as ever, with one
    // more deaf spell in between that does not count either.
    b.arm.set_silent(true);
    b.run(millis(100));
    b.now += millis(300);
    b.run(millis(1));
    CHECK(b.link.status() == ArmLinkStatus::kOk);
    b.run(millis(60));
    CHECK(b.link.status() == ArmLinkStatus::kHeartbeatLost);
  }
  SECTION("a target beyond the arm's reach is refused") {
    ArmCommand c;
    c.mode = ArmMode::kMove;
    c.target.position = {2.0, 0.0, 0.5};
    b.link.send(c, b.now);
    b.run(millis(50));
    CHECK(b.link.status() == ArmLinkStatus::kRefused);
  }
  SECTION("the arm reboots: it is started again") {
    b.arm.start(b.now);  // boot-up heartbeat, pre-operational
    b.run(millis(5));
    CHECK(b.arm.nmt_state() == co::NmtState::kOperational);
  }
  SECTION("bus-off is reported until the controller restarts") {
    CanFrame err;
    err.error = true;
    err.id = kCanErrBusOff | kCanErrController;
    err.len = 8;
    b.wire.a().inject(err);
    b.run(millis(5));
    CHECK(b.link.status() == ArmLinkStatus::kBusOff);
    CHECK(b.link.counters().bus_errors == 1);
    err.id = kCanErrRestarted;
    b.wire.a().inject(err);
    b.run(millis(50));
    CHECK(b.link.status() == ArmLinkStatus::kOk);
    CHECK(b.link.counters().restarts == 1);
  }
}

TEST_CASE("SocketCAN: opening names the interface and what is missing") {
  SocketCanBus bus(SocketCanConfig{"mcnone0", false, {}, 0});
  const int probe = ::socket(PF_CAN, SOCK_RAW, CAN_RAW);
  if (probe < 0) {
    // This kernel has no CAN (the development machine): the message says so.
    CHECK_THROWS_WITH(bus.open(), "CAN interface 'mcnone0': socket(PF_CAN) (does the kernel have CAN and can_raw?): "
                                  "Address family not supported by protocol");
  } else {
    ::close(probe);
    CHECK_THROWS_WITH(bus.open(), "CAN interface 'mcnone0': no such interface (ip link shows them): No such device");
  }
  CHECK_FALSE(bus.is_open());
  CHECK(bus.send(CanFrame{}) == CanStatus::kNotOpen);
}
