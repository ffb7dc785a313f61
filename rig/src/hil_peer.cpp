#include "markcell/rig/hil_peer.hpp"

#include <fcntl.h>
#include <pthread.h>
#include <sched.h>
#include <time.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>
#include <system_error>

namespace markcell::rig {

// The rig runs the service's cell: its configuration, its cell and their helpers.
using namespace markcell::host;

namespace {

constexpr Nanos kPeriod = millis(1);
constexpr std::size_t kLogCapacity = std::size_t{1} << 18;

drivers::SocketCanConfig peer_socket(const CanConfig& can) {
  drivers::SocketCanConfig c;
  c.interface = can.interface;
  c.fd = can.link.fd;
  return c;  // no filter: the arm hears everything on its bus, as a node does
}

}  // namespace

int HilPeer::TappedBus::receive(std::span<drivers::CanFrame> out, Nanos timeout) noexcept {
  const int n = bus_.receive(out, timeout);
  for (int i = 0; i < n; ++i)
    if (!out[static_cast<std::size_t>(i)].error) log_.frame(out[static_cast<std::size_t>(i)].time, out[static_cast<std::size_t>(i)]);
  return n;
}

HilPeer::HilPeer(const CellConfig& config, std::string gpio_sim_dir, const std::array<unsigned, kLineRoleCount>& offsets,
                 int priority, std::string arm_serial_peer)
    : config_(config),
      dir_(std::move(gpio_sim_dir)),
      offsets_(offsets),
      priority_(priority),
      serial_peer_(std::move(arm_serial_peer)) {
  log_.reserve(kLogCapacity);
  const auto& arm = config.arm;
  if (arm.transport == ArmTransport::kCan) {
    bus_.emplace(peer_socket(arm.can), log_);
    can_arm_.emplace(*bus_, arm.can.link.node_id, sim_arm_limits(arm), millis(10),
                     arm.can.link.heartbeat_period, arm.can.link.heartbeat_timeout, arm.can.link.fd);
  } else if (arm.transport == ArmTransport::kSerial && !serial_peer_.empty()) {
    serial_arm_.emplace(sim_arm_limits(arm), millis(10));
    serial_arm_->set_tap(&HilPeer::tap_serial, this);
  } else {  // the replay's check_real_devices refuses these, naming the file
    throw std::logic_error("the rig's peer needs a real arm link: CAN, or a serial line with its other end");
  }
}

HilPeer::~HilPeer() { stop(); }

std::string HilPeer::attribute(LineRole role, const char* name) const {
  return dir_ + "/sim_gpio" + std::to_string(offsets_[static_cast<std::size_t>(role)]) + "/" + name;
}

void HilPeer::drive(LineRole role, bool logical) {
  const bool physical = logical != config_.gpio.lines[static_cast<std::size_t>(role)].active_low;
  const std::string path = attribute(role, "pull");
  const int fd = ::open(path.c_str(), O_WRONLY | O_CLOEXEC);
  if (fd < 0) throw std::system_error(errno, std::generic_category(), path + ": cannot open the simulated line's pull");
  const char* value = physical ? "pull-up" : "pull-down";
  const auto len = static_cast<ssize_t>(std::strlen(value));
  const bool ok = ::write(fd, value, static_cast<std::size_t>(len)) == len;
  const int err = errno;
  ::close(fd);
  if (!ok) throw std::system_error(err, std::generic_category(), path + ": cannot write '" + value + "'");
}

void HilPeer::start() {
  if (thread_.joinable()) throw std::logic_error("the rig's peer is already running");
  for (std::size_t i = 0; i < kLineRoleCount; ++i)
    if (!is_output(static_cast<LineRole>(i))) drive(static_cast<LineRole>(i), false);
  drive(LineRole::kPlcCycleEnable, true);  // a running line enables the cycle; scripts do the rest
  const std::string value = attribute(LineRole::kSprayValve, "value");
  valve_fd_ = ::open(value.c_str(), O_RDONLY | O_CLOEXEC);
  if (valve_fd_ < 0) throw std::system_error(errno, std::generic_category(), value + ": cannot open the valve line's value");
  if (can_arm_) {
    bus_->open();
    can_arm_->start(monotonic_now());
  } else {
    serial_arm_->open(serial_peer_, config_.arm.serial.baud);
  }
  stop_.store(false, std::memory_order_release);
  thread_ = std::thread([this] { run(); });
  if (priority_ > 0) {
    sched_param p{};
    p.sched_priority = priority_;
    priority_refused_ = pthread_setschedparam(thread_.native_handle(), SCHED_FIFO, &p) != 0;
  }
}

void HilPeer::stop() noexcept {
  stop_.store(true, std::memory_order_release);
  if (thread_.joinable()) thread_.join();
  if (bus_) bus_->close();
  if (serial_arm_) serial_arm_->close();
  if (valve_fd_ >= 0) ::close(valve_fd_);
  valve_fd_ = -1;
}

void HilPeer::run() noexcept {
  const bool active_low = config_.gpio.lines[static_cast<std::size_t>(LineRole::kSprayValve)].active_low;
  Nanos next = monotonic_now();
  while (!stop_.load(std::memory_order_acquire)) {
    next += kPeriod;
    const timespec ts{static_cast<time_t>(next / kNanosPerSecond), static_cast<long>(next % kNanosPerSecond)};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    }
    const Nanos now = monotonic_now();
    if (now - next > kPeriod) {
      ++late_ticks_;
      next = now;  // no burst of catch-up ticks after a stall
    }
    if (can_arm_) can_arm_->poll(now);
    else serial_arm_->poll(now);
    char level[4] = {};
    if (::pread(valve_fd_, level, sizeof level, 0) <= 0 || (level[0] != '0' && level[0] != '1')) {
      error_ = attribute(LineRole::kSprayValve, "value") + ": cannot read the valve's level (" + std::strerror(errno) + ")";
      return;
    }
    const auto& tool = can_arm_ ? can_arm_->model().tool() : serial_arm_->model().tool();
    nozzle_.observe(now, (level[0] == '1') != active_low, tool, log_);
  }
}

}  // namespace markcell::rig
