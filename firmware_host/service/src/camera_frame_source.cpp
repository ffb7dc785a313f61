#include "markcell/host/camera_frame_source.hpp"

#include <cstring>
#include <stdexcept>

namespace markcell::host {

namespace {
std::string lost_text(const drivers::Camera& c, Nanos silence) {
  return "camera '" + c.id() + "' lost (no frame for " + std::to_string(to_seconds(silence)).substr(0, 4) +
         " s or its control channel closed); reconnecting";
}
}  // namespace

CameraFrameSource::CameraFrameSource(std::unique_ptr<drivers::Camera> left, std::unique_ptr<drivers::Camera> right,
                                     int width, int height, double fps, bool software_trigger, Nanos latency,
                                     Nanos silence)
    : left_(std::move(left)),
      right_(std::move(right)),
      width_(width),
      height_(height),
      period_(static_cast<Nanos>(1e9 / fps)),
      software_trigger_(software_trigger),
      latency_(latency),
      silence_(silence),
      left_lost_text_(lost_text(*left_, silence)),
      right_lost_text_(lost_text(*right_, silence)) {
  if (width <= 0 || height <= 0 || !(fps > 0)) throw std::invalid_argument("CameraFrameSource: size and rate must be positive");
}

CameraFrameSource::~CameraFrameSource() { stop(); }

void CameraFrameSource::start(Nanos) {
  // Allocations happen here, before the lanes run: the image pairs and the cameras'
  // buffer pools.
  for (int i = 0; i < kSlots; ++i) {
    left_images_[static_cast<std::size_t>(i)].create(height_, width_, CV_8UC1);
    right_images_[static_cast<std::size_t>(i)].create(height_, width_, CV_8UC1);
  }
  left_->activate();
  right_->activate();
  // Frames are paired within half a frame period.
  pair_.emplace(*left_, *right_, period_ / 2, silence_);
  {
    std::lock_guard lock(mutex_);
    stop_ = false;
  }
  thread_ = std::thread([this] { receive(); });
}

void CameraFrameSource::stop() noexcept {
  {
    std::lock_guard lock(mutex_);
    stop_ = true;
  }
  stop_cv_.notify_all();
  if (thread_.joinable()) thread_.join();
  left_->deactivate();
  right_->deactivate();
}

void CameraFrameSource::copy_into(int slot, const drivers::StereoFrame& f) noexcept {
  // The slot is neither published nor held, so the vision task cannot be reading it.
  const auto copy = [&](const drivers::FrameView& v, cv::Mat& to) {
    const int rows = std::min(v.height, height_);
    const auto cols = static_cast<std::size_t>(std::min(v.width, width_));
    for (int r = 0; r < rows; ++r)
      std::memcpy(to.ptr<std::uint8_t>(r), v.pixels + static_cast<std::ptrdiff_t>(r) * v.stride, cols);
  };
  copy(f.left, left_images_[static_cast<std::size_t>(slot)]);
  copy(f.right, right_images_[static_cast<std::size_t>(slot)]);
}

void CameraFrameSource::publish(int slot, Nanos time) noexcept {
  std::lock_guard lock(mutex_);
  times_[static_cast<std::size_t>(slot)] = time;
  seqs_[static_cast<std::size_t>(slot)] = next_seq_++;
  published_ = slot;
  ++counters_.pairs;
}

void CameraFrameSource::report_lost(const std::string& text) noexcept {
  std::lock_guard lock(mutex_);
  lost_report_ = &text;
  ++counters_.losses;
}

bool CameraFrameSource::try_reconnect() noexcept {
  // The camera reported is reopened even when its control channel still answers: a
  // camera that went silent is as unusable as one that went away.
  std::string why;
  if (lost_left_ || left_->lost()) lost_left_ = !left_->reconnect(why);
  if (lost_right_ || right_->lost()) lost_right_ = !right_->reconnect(why);
  if (lost_left_ || lost_right_) return false;
  pair_.emplace(*left_, *right_, period_ / 2, silence_);
  std::lock_guard lock(mutex_);
  ++counters_.reconnects;
  return true;
}

void CameraFrameSource::receive() noexcept {
  Nanos next_trigger = monotonic_now();
  // Bounded: every pass waits at most one second (a reconnection attempt) or one
  // silence period (a pair), and the loop ends on stop.
  for (;;) {
    {
      std::unique_lock lock(mutex_);
      if (stop_) return;
      if (lost_) {
        if (stop_cv_.wait_for(lock, std::chrono::seconds(1), [this] { return stop_; })) return;
      }
    }
    if (lost_) {
      lost_ = !try_reconnect();
      continue;
    }
    if (software_trigger_) {
      const Nanos now = monotonic_now();
      if (next_trigger > now) {
        std::unique_lock lock(mutex_);
        if (stop_cv_.wait_for(lock, std::chrono::nanoseconds(next_trigger - now), [this] { return stop_; })) return;
      }
      pair_->trigger();
      next_trigger = std::max(next_trigger + period_, monotonic_now());
    }
    drivers::StereoFrame f;
    const drivers::PairStatus s = pair_->next(f, software_trigger_ ? period_ : std::min(silence_, 4 * period_));
    if (s == drivers::PairStatus::kPair) {
      int slot = 0;
      {
        std::lock_guard lock(mutex_);
        while (slot == published_ || slot == held_) ++slot;  // kSlots = 3: one is always free
      }
      copy_into(slot, f);
      publish(slot, f.time - latency_);
    } else if (s == drivers::PairStatus::kTimeout) {
      std::lock_guard lock(mutex_);
      ++counters_.timeouts;
    } else {
      const bool left = s == drivers::PairStatus::kLeftLost;
      report_lost(left ? left_lost_text_ : right_lost_text_);
      (left ? lost_left_ : lost_right_) = true;
      lost_ = true;
    }
  }
}

vision::FrameResult CameraFrameSource::next(Nanos, vision::StereoFrameRef& out) noexcept {
  std::lock_guard lock(mutex_);
  if (lost_report_ != nullptr) {
    out = {};
    out.seq = handed_seq_;
    out.time = monotonic_now();
    out.dropped = true;
    out.problem = *lost_report_;
    lost_report_ = nullptr;
    return vision::FrameResult::kFrame;
  }
  if (published_ < 0) return vision::FrameResult::kNone;
  const auto p = static_cast<std::size_t>(published_);
  if (seqs_[p] <= handed_seq_) return vision::FrameResult::kNone;
  if (handed_seq_ > 0) skipped_ += seqs_[p] - handed_seq_ - 1;
  handed_seq_ = seqs_[p];
  held_ = published_;
  out = {};
  out.seq = seqs_[p];
  out.time = times_[p];
  out.index = static_cast<std::size_t>(seqs_[p] - 1);
  out.left = &left_images_[p];
  out.right = &right_images_[p];
  return vision::FrameResult::kFrame;
}

std::uint64_t CameraFrameSource::skipped() const {
  std::lock_guard lock(mutex_);
  return skipped_;
}

CameraFrameSourceCounters CameraFrameSource::counters() const {
  std::lock_guard lock(mutex_);
  return counters_;
}

}  // namespace markcell::host
