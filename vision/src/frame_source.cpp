#include "markcell/vision/frame_source.hpp"

#include <pthread.h>
#include <sched.h>

#include <algorithm>

namespace markcell::vision {

RecordingFrameSource::RecordingFrameSource(const std::string& folder, Nanos latency, bool simulated_time,
                                           Nanos stall_timeout, int loader_priority)
    : recording_(Recording::open(folder)),
      latency_(latency),
      simulated_(simulated_time),
      stall_timeout_(stall_timeout),
      loader_priority_(loader_priority) {
  times_.reserve(recording_.size());
  // A time that does not increase makes its frame a dropped one (Recording::read says
  // so); for delivery it is held at its predecessor's time, keeping the order.
  for (std::size_t i = 0; i < recording_.size(); ++i)
    times_.push_back(std::max(recording_.entry(i).time - recording_.entry(0).time, i > 0 ? times_.back() : Nanos{0}));
  time_base_ = recording_.size() > 0 ? recording_.entry(0).time : 0;
}

RecordingFrameSource::~RecordingFrameSource() { stop(); }

void RecordingFrameSource::start(Nanos epoch) {
  epoch_ = epoch;
  thread_ = std::thread([this] { loader(); });
  if (loader_priority_ > 0) {
    // Refused (no privilege): the loader runs at normal priority, as the lanes then do too.
    sched_param p{};
    p.sched_priority = loader_priority_;
    (void)pthread_setschedparam(thread_.native_handle(), SCHED_FIFO, &p);
  }
}

void RecordingFrameSource::stop() noexcept {
  {
    std::lock_guard lock(mutex_);
    stop_ = true;
  }
  free_cv_.notify_all();
  loaded_cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

Nanos RecordingFrameSource::end_time() const { return times_.empty() ? epoch_ : epoch_ + times_.back() + latency_; }

void RecordingFrameSource::loader() {
  for (std::size_t i = 0; i < times_.size(); ++i) {
    {
      std::unique_lock lock(mutex_);
      free_cv_.wait(lock, [&] { return stop_ || loaded_ - consumed_ < kRing; });
      if (stop_) return;
    }
    // Decoding outside the lock. Nothing escapes the loader's thread: whatever a frame's
    // files do to the decoder, that frame is dropped with the reason.
    ReplayFrame f;
    try {
      f = recording_.read(i);
    } catch (const std::exception& e) {
      f = ReplayFrame{};
      f.index = i;
      f.dropped = true;
      f.problem = "frame " + std::to_string(i) + ": " + e.what();
    }
    {
      std::lock_guard lock(mutex_);
      ring_[i % kRing] = std::move(f);
      loaded_ = i + 1;
    }
    loaded_cv_.notify_all();
  }
}

FrameResult RecordingFrameSource::next(Nanos now, StereoFrameRef& out) noexcept {
  // The newest frame delivered by now: the last i with epoch + t_i + latency <= now.
  const auto it = std::upper_bound(times_.begin(), times_.end(), now - epoch_ - latency_);
  std::unique_lock lock(mutex_);
  if (holding_) {  // release the pair handed out last time
    holding_ = false;
    ++consumed_;
    free_cv_.notify_all();
  }
  if (it == times_.begin()) return FrameResult::kNone;
  const std::size_t target = static_cast<std::size_t>(it - times_.begin()) - 1;
  if (target < consumed_) return consumed_ >= times_.size() ? FrameResult::kEnd : FrameResult::kNone;
  if (simulated_) {
    // The loader keeps at most kRing frames; skipped ones are released as they come.
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::nanoseconds(stall_timeout_);
    while (consumed_ < target) {
      if (!loaded_cv_.wait_until(lock, deadline, [&] { return stop_ || loaded_ > consumed_; })) return FrameResult::kStalled;
      if (stop_) return FrameResult::kEnd;
      ++consumed_;
      ++skipped_;
      free_cv_.notify_all();
    }
    if (!loaded_cv_.wait_until(lock, deadline, [&] { return stop_ || loaded_ > target; })) return FrameResult::kStalled;
    if (stop_) return FrameResult::kEnd;
  } else {
    while (consumed_ < target && loaded_ > consumed_ + 1) {
      ++consumed_;
      ++skipped_;
    }
    free_cv_.notify_all();
    if (loaded_ <= consumed_) return FrameResult::kNone;
  }
  const ReplayFrame& f = ring_[consumed_ % kRing];
  holding_ = true;
  out.seq = f.seq;
  out.time = to_cell_time(f.time);
  out.index = f.index;
  out.left = &f.left;
  out.right = &f.right;
  out.dropped = f.dropped;
  out.problem = f.problem;
  return FrameResult::kFrame;
}

FrameResult MemoryFrameSource::next(Nanos now, StereoFrameRef& out) noexcept {
  std::size_t target = next_;
  while (target < pairs_.size() && epoch_ + pairs_[target].time + latency_ <= now) ++target;
  if (target == next_) return next_ >= pairs_.size() ? FrameResult::kEnd : FrameResult::kNone;
  skipped_ += target - next_ - 1;
  const Pair& p = pairs_[target - 1];
  next_ = target;
  out.seq = seq_base_ + p.seq;
  out.time = epoch_ + p.time;
  out.index = target - 1;
  out.left = &p.left;
  out.right = &p.right;
  out.dropped = false;
  out.problem = {};
  return FrameResult::kFrame;
}

}  // namespace markcell::vision
