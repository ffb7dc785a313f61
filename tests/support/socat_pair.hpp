#pragma once
// A pseudo-terminal pair joined by socat: two serial device paths whose bytes cross,
// as a null-modem cable would. Killed when the object goes.
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <thread>

#include "test_files.hpp"

namespace markcell::test {

class SocatPair {
 public:
  explicit SocatPair(const TempDir& dir)
      : a_((dir.path() / "ttyA").string()), b_((dir.path() / "ttyB").string()) {
    pid_ = fork();
    if (pid_ == 0) {
      const std::string left = "pty,raw,echo=0,link=" + a_;
      const std::string right = "pty,raw,echo=0,link=" + b_;
      execlp("socat", "socat", left.c_str(), right.c_str(), static_cast<char*>(nullptr));
      _exit(127);
    }
    for (int i = 0; i < 500; ++i) {  // at most 5 s for socat to create both links
      if (std::filesystem::exists(a_) && std::filesystem::exists(b_)) return;
      int status = 0;
      if (waitpid(pid_, &status, WNOHANG) == pid_) throw std::runtime_error("socat exited: is it installed (package socat)?");
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    kill();
    throw std::runtime_error("socat did not create " + a_ + " and " + b_ + " within 5 s");
  }
  ~SocatPair() { kill(); }
  void kill() {
    if (pid_ > 0) {
      ::kill(pid_, SIGTERM);
      waitpid(pid_, nullptr, 0);
      pid_ = -1;
    }
  }
  const std::string& a() const { return a_; }
  const std::string& b() const { return b_; }

 private:
  std::string a_, b_;
  pid_t pid_ = -1;
};

}  // namespace markcell::test
