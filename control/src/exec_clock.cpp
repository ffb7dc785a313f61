#include "markcell/control/exec_clock.hpp"

#include <time.h>

#include <cerrno>
#include <chrono>

#include "markcell/common/check.hpp"

namespace markcell::control {

Nanos RealClock::cpu_now(int) const {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<Nanos>(ts.tv_sec) * kNanosPerSecond + ts.tv_nsec;
}

WakeResult RealClock::sleep_until(int, Nanos t) {
  const timespec ts = to_timespec(t);
  // EINTR (a signal) just means: sleep again until the same absolute time.
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
    if (stopped_.load(std::memory_order_acquire)) return WakeResult::kStopped;
  }
  return stopped_.load(std::memory_order_acquire) ? WakeResult::kStopped : WakeResult::kReleased;
}

SimClock::SimClock(int lanes, Nanos start, Nanos wedge_timeout)
    : lanes_(lanes), wedge_timeout_(wedge_timeout), now_(start), end_(start) {
  MARKCELL_THROW_UNLESS(lanes >= 1 && lanes <= kMaxLanes, "lanes=" << lanes << " max=" << kMaxLanes);
}

Nanos SimClock::now(int lane) const {
  std::lock_guard lock(mutex_);
  return now_ + lane_[static_cast<std::size_t>(lane)].busy;
}

Nanos SimClock::global_now() const {
  std::lock_guard lock(mutex_);
  return now_;
}

void SimClock::consume(int lane, Nanos duration) {
  std::lock_guard lock(mutex_);
  if (duration > 0) lane_[static_cast<std::size_t>(lane)].busy += duration;
}

WakeResult SimClock::sleep_until(int lane_index, Nanos t) {
  std::unique_lock lock(mutex_);
  Lane& lane = lane_[static_cast<std::size_t>(lane_index)];
  // A lane that consumed time cannot wake before it has finished.
  const Nanos finished = now_ + lane.busy;
  lane.wake = t > finished ? t : finished;
  lane.busy = 0;
  lane.state = LaneState::kWaiting;
  lane.granted = false;
  if (running_ == lane_index) running_ = -1;
  dispatch_locked();
  lane.cv.wait(lock, [&] { return lane.granted || stopped_; });
  if (stopped_) return WakeResult::kStopped;
  lane.state = LaneState::kRunning;
  return WakeResult::kReleased;
}

void SimClock::dispatch_locked() {
  if (running_ >= 0 || paused_ || stopped_) return;
  int next = -1;
  for (int i = 0; i < lanes_; ++i) {
    const Lane& l = lane_[static_cast<std::size_t>(i)];
    if (l.state != LaneState::kWaiting) {
      if (l.state == LaneState::kNotArrived) return;  // everyone must be waiting first
      continue;
    }
    if (next < 0 || l.wake < lane_[static_cast<std::size_t>(next)].wake) next = i;
  }
  if (next < 0) return;
  Lane& l = lane_[static_cast<std::size_t>(next)];
  if (l.wake > end_) {
    paused_ = true;
    controller_cv_.notify_all();
    return;
  }
  if (l.wake > now_) now_ = l.wake;
  running_ = next;
  l.granted = true;
  ++grants_;
  l.cv.notify_one();
}

SimClock::RunResult SimClock::run_until(Nanos t_end) {
  std::unique_lock lock(mutex_);
  if (stopped_) return RunResult::kStopped;
  end_ = t_end;
  paused_ = false;
  dispatch_locked();
  // Watch progress in real time: a lane that holds the turnstile for longer than the
  // wedge timeout without anything else happening is a wedged run.
  std::uint64_t last_grants = grants_;
  const auto timeout = std::chrono::nanoseconds(wedge_timeout_);
  while (!paused_ && !stopped_) {
    if (!controller_cv_.wait_for(lock, timeout, [&] { return paused_ || stopped_; })) {
      if (grants_ == last_grants) return RunResult::kWedged;
      last_grants = grants_;
    }
  }
  return stopped_ ? RunResult::kStopped : RunResult::kReached;
}

void SimClock::stop() {
  std::lock_guard lock(mutex_);
  stopped_ = true;
  for (int i = 0; i < lanes_; ++i) lane_[static_cast<std::size_t>(i)].cv.notify_all();
  controller_cv_.notify_all();
}

}  // namespace markcell::control
