#pragma once
// A datagram socket standing in for systemd's notify socket (NOTIFY_SOCKET): the tests
// of the notify protocol, in-process and of the real binary, collect what arrives.
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <cstring>
#include <string>
#include <vector>

#include "markcell/common/time.hpp"

namespace markcell::test {

class NotifySocket {
 public:
  explicit NotifySocket(const std::string& path) {
    fd_ = socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    REQUIRE(fd_ >= 0);
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    REQUIRE(path.size() < sizeof(addr.sun_path));
    path.copy(addr.sun_path, path.size());
    REQUIRE(bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) == 0);
    timeval tv{0, 20'000};
    setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
    // The kernel stamps each datagram as it is sent (AF_UNIX stamps at sendmsg): pacing is
    // judged by when the sender sent, not by when this reader, maybe descheduled on a
    // loaded machine, got round to reading two queued messages.
    const int on = 1;
    REQUIRE(setsockopt(fd_, SOL_SOCKET, SO_TIMESTAMPNS, &on, sizeof(on)) == 0);
  }
  ~NotifySocket() { close(fd_); }
  NotifySocket(const NotifySocket&) = delete;
  NotifySocket& operator=(const NotifySocket&) = delete;
  struct Message {
    Nanos time;  // monotonic, when read
    Nanos sent;  // CLOCK_REALTIME, when sent (kernel's stamp): only differences are meaningful
    std::string text;
  };
  // Collects every datagram until `until()` holds or `timeout` passes; returns until().
  template <typename Until>
  bool collect(Nanos timeout, Until until) {
    const Nanos end = monotonic_now() + timeout;
    char buf[512];
    while (monotonic_now() < end && !until()) {
      iovec iov{buf, sizeof(buf)};
      alignas(cmsghdr) char control[CMSG_SPACE(sizeof(timespec))];
      msghdr msg{};
      msg.msg_iov = &iov;
      msg.msg_iovlen = 1;
      msg.msg_control = control;
      msg.msg_controllen = sizeof(control);
      const auto n = recvmsg(fd_, &msg, 0);
      if (n <= 0) continue;
      Nanos sent = -1;
      for (cmsghdr* c = CMSG_FIRSTHDR(&msg); c != nullptr; c = CMSG_NXTHDR(&msg, c)) {
        if (c->cmsg_level != SOL_SOCKET || c->cmsg_type != SCM_TIMESTAMPNS) continue;
        timespec ts{};
        std::memcpy(&ts, CMSG_DATA(c), sizeof(ts));
        sent = static_cast<Nanos>(ts.tv_sec) * kNanosPerSecond + ts.tv_nsec;
      }
      REQUIRE(sent >= 0);  // SO_TIMESTAMPNS was set: every datagram carries its stamp
      messages.push_back({monotonic_now(), sent, std::string(buf, static_cast<std::size_t>(n))});
    }
    return until();
  }
  void collect(Nanos duration) {
    collect(duration, [] { return false; });
  }
  int count(const std::string& text) const {
    int n = 0;
    for (const auto& m : messages) n += m.text == text ? 1 : 0;
    return n;
  }
  std::vector<Message> messages;

 private:
  int fd_ = -1;
};

}  // namespace markcell::test
