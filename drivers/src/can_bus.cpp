#include "markcell/drivers/can_bus.hpp"
#include "markcell/common/wait.hpp"

#include <linux/can.h>
#include <linux/can/error.h>
#include <linux/can/raw.h>
#include <net/if.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>
#include <system_error>

namespace markcell::drivers {

static_assert(kCanErrBusOff == CAN_ERR_BUSOFF && kCanErrRestarted == CAN_ERR_RESTARTED &&
              kCanErrController == CAN_ERR_CRTL);

void SocketCanBus::open() {
  close();
  if (config_.interface.empty() || config_.interface.size() >= IFNAMSIZ)
    throw std::invalid_argument("CAN interface name '" + config_.interface + "' is empty or longer than 15 characters");
  const int fd = ::socket(PF_CAN, SOCK_RAW | SOCK_CLOEXEC | SOCK_NONBLOCK, CAN_RAW);
  if (fd < 0)
    throw std::system_error(errno, std::generic_category(),
                            "CAN interface '" + config_.interface + "': socket(PF_CAN) (does the kernel have CAN and can_raw?)");
  auto fail = [&](const std::string& what) {
    const int err = errno;
    ::close(fd);
    throw std::system_error(err, std::generic_category(), "CAN interface '" + config_.interface + "': " + what);
  };
  ifreq ifr{};
  std::strncpy(ifr.ifr_name, config_.interface.c_str(), IFNAMSIZ - 1);
  if (::ioctl(fd, SIOCGIFINDEX, &ifr) != 0) fail("no such interface (ip link shows them)");
  if (config_.filter_count > 0) {
    std::array<can_filter, 16> filters{};
    for (int i = 0; i < config_.filter_count; ++i)
      filters[static_cast<std::size_t>(i)] = can_filter{config_.filter_ids[static_cast<std::size_t>(i)], CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG};
    if (::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FILTER, filters.data(),
                     static_cast<socklen_t>(sizeof(can_filter) * static_cast<std::size_t>(config_.filter_count))) != 0)
      fail("CAN_RAW_FILTER");
  }
  const can_err_mask_t errors = CAN_ERR_MASK;  // every error class: bus-off, restarts, controller problems
  if (::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_ERR_FILTER, &errors, sizeof(errors)) != 0) fail("CAN_RAW_ERR_FILTER");
  if (config_.fd) {
    const int on = 1;
    if (::setsockopt(fd, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof(on)) != 0) fail("CAN_RAW_FD_FRAMES (is it a CAN FD interface?)");
  }
  sockaddr_can addr{};
  addr.can_family = AF_CAN;
  addr.can_ifindex = ifr.ifr_ifindex;
  if (::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) != 0) fail("bind");
  fd_ = fd;
}

void SocketCanBus::close() noexcept {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

CanStatus SocketCanBus::send(const CanFrame& f) noexcept {
  if (fd_ < 0) return CanStatus::kNotOpen;
  if ((!f.fd && f.len > CAN_MAX_DLEN) || f.len > CANFD_MAX_DLEN || (f.fd && !config_.fd)) return CanStatus::kTooLong;
  canfd_frame raw{};
  raw.can_id = f.id | (f.extended ? CAN_EFF_FLAG : 0U);
  raw.len = f.len;
  std::memcpy(raw.data, f.data.data(), f.len);
  const std::size_t size = f.fd ? CANFD_MTU : CAN_MTU;
  const ssize_t n = ::send(fd_, &raw, size, MSG_DONTWAIT);
  if (n == static_cast<ssize_t>(size)) return CanStatus::kOk;
  // TX queue full, or the interface is down (ip link set down, a controller restarting):
  // transient, and the heartbeat supervision reports it if it lasts.
  if (n < 0 && (errno == EAGAIN || errno == ENOBUFS || errno == ENETDOWN)) return CanStatus::kWouldBlock;
  return CanStatus::kIoError;
}

int SocketCanBus::receive(std::span<CanFrame> out, Nanos timeout) noexcept {
  if (fd_ < 0) return -1;
  const WaitResult w = wait_readable(fd_, timeout);
  if (w == WaitResult::kTimeout) return 0;
  if (w == WaitResult::kError) return -1;
  // kHangup on a CAN socket is POLLERR: a pending socket error (ENETDOWN when the
  // interface goes down) that recv() reports below, and that passes.
  int n = 0;
  while (static_cast<std::size_t>(n) < out.size()) {
    canfd_frame raw{};
    const ssize_t got = ::recv(fd_, &raw, sizeof(raw), MSG_DONTWAIT);
    if (got < 0) {
      if (errno == EAGAIN) break;
      if (errno == ENETDOWN) {  // reported once when the interface goes down: not fatal
        ++down_events_;
        break;
      }
      return n > 0 ? n : -1;
    }
    if (got != CAN_MTU && got != CANFD_MTU) {
      ++dropped_;
      continue;
    }
    CanFrame& f = out[static_cast<std::size_t>(n++)];
    f.error = (raw.can_id & CAN_ERR_FLAG) != 0;
    f.extended = (raw.can_id & CAN_EFF_FLAG) != 0;
    f.fd = got == CANFD_MTU;
    f.id = f.error ? (raw.can_id & CAN_ERR_MASK) : (raw.can_id & (f.extended ? CAN_EFF_MASK : CAN_SFF_MASK));
    f.len = raw.len > CANFD_MAX_DLEN ? CANFD_MAX_DLEN : raw.len;
    std::memcpy(f.data.data(), raw.data, f.len);
    f.time = monotonic_now();
  }
  return n;
}

SimCanWire::SimCanWire() {
  a_.peer_ = &b_;
  b_.peer_ = &a_;
}

void SimCanWire::set_time_source(Nanos (*now)(void*), void* user) {
  a_.now_ = b_.now_ = now;
  a_.now_user_ = b_.now_user_ = user;
}

void SimCanWire::set_tap(void (*tap)(void*, const CanFrame&, Nanos), void* user) {
  a_.tap_ = tap;
  a_.tap_user_ = user;
}

void SimCanWire::End::inject(const CanFrame& frame) noexcept {
  if (!open_) return;
  if (count_ == kQueue) {
    ++dropped_;
    return;
  }
  CanFrame& slot = queue_[(head_ + count_) % kQueue];
  slot = frame;
  slot.time = now_ != nullptr ? now_(now_user_) : monotonic_now();
  ++count_;
}

CanStatus SimCanWire::End::send(const CanFrame& frame) noexcept {
  if (!open_) return CanStatus::kNotOpen;
  if ((!frame.fd && frame.len > 8) || frame.len > 64) return CanStatus::kTooLong;
  peer_->inject(frame);  // a closed peer simply does not hear it, as on a real bus
  if (tap_ != nullptr) tap_(tap_user_, frame, now_ != nullptr ? now_(now_user_) : monotonic_now());
  return CanStatus::kOk;
}

int SimCanWire::End::receive(std::span<CanFrame> out, Nanos) noexcept {
  if (!open_) return -1;
  int n = 0;
  while (count_ > 0 && static_cast<std::size_t>(n) < out.size()) {
    out[static_cast<std::size_t>(n++)] = queue_[head_];
    head_ = (head_ + 1) % kQueue;
    --count_;
  }
  return n;
}

}  // namespace markcell::drivers
