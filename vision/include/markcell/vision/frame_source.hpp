#pragma once
// Where the vision task's stereo pairs come from: the cameras, or a recording replayed in
// real or simulated time. The vision task asks, at each of its runs, for the newest pair
// delivered by then; it never blocks on a live source.
#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include <opencv2/core.hpp>

#include "markcell/common/time.hpp"
#include "markcell/msg/pose_estimate.hpp"
#include "markcell/vision/recording.hpp"

namespace markcell::vision {

struct StereoFrameRef {
  std::uint64_t seq = 0;
  Nanos time = 0;               // capture time on the cell's clock
  std::size_t index = 0;        // position in the source (recordings: frames.csv row)
  const cv::Mat* left = nullptr;
  const cv::Mat* right = nullptr;
  bool dropped = false;         // the pair cannot be used; `problem` says why
  std::string_view problem;     // valid until the next call
};

enum class FrameResult : std::uint8_t { kFrame, kNone, kEnd, kStalled };

class FrameSource {
 public:
  virtual ~FrameSource() = default;
  // Frames are on the cell's clock from `epoch` on.
  virtual void start(Nanos epoch) = 0;
  virtual void stop() noexcept = 0;
  // The newest pair delivered by `now` not handed out before (older undelivered ones are
  // skipped and counted). The pair stays valid until the next call.
  virtual FrameResult next(Nanos now, StereoFrameRef& out) noexcept = 0;
  virtual std::uint64_t skipped() const = 0;
  // What the tracker made of the last pair handed out (vision lane, after each tracked
  // pair). A source that changes its pairs (the rig's arm drawn over them) learns here
  // what that cost; the others ignore it. Must not allocate or block.
  virtual void tracked(const msg::PoseEstimate& /*estimate*/) noexcept {}
};

// A recording replayed: frame i is delivered at epoch + time_i + latency. A loader thread
// (a device twin, like a camera's receive thread: it allocates while decoding PNGs)
// decodes ahead into a small ring. In simulated time the caller waits for the loader
// (real time, bounded by `stall_timeout`), so that a replay is the same however fast
// the machine is; in real time it takes what is loaded.
class RecordingFrameSource final : public FrameSource {
 public:
  // `loader_priority`: SCHED_FIFO priority of the loader thread (0: normal). In real time
  // it feeds a vision lane that may run at a real-time priority: below it, the loader
  // starves and the frames it hands out fall ever further behind.
  RecordingFrameSource(const std::string& folder, Nanos latency, bool simulated_time,
                       Nanos stall_timeout = seconds(60), int loader_priority = 0);
  ~RecordingFrameSource() override;
  void start(Nanos epoch) override;
  void stop() noexcept override;
  FrameResult next(Nanos now, StereoFrameRef& out) noexcept override;
  std::uint64_t skipped() const override { return skipped_; }
  const Recording& recording() const { return recording_; }
  // When the last frame is delivered, on the cell's clock.
  Nanos end_time() const;
  // A recording's own time base on the cell's clock: its first frame is at the epoch.
  Nanos to_cell_time(Nanos recording_time) const { return epoch_ + recording_time - time_base_; }

 private:
  static constexpr std::size_t kRing = 4;
  void loader();
  Recording recording_;
  const Nanos latency_;
  const bool simulated_;
  const Nanos stall_timeout_;
  const int loader_priority_;
  Nanos epoch_ = 0;
  Nanos time_base_ = 0;       // the first frame's capture time
  std::vector<Nanos> times_;  // frames' capture times, read-only after construction
  std::mutex mutex_;
  std::condition_variable loaded_cv_, free_cv_;
  std::array<ReplayFrame, kRing> ring_{};
  std::size_t loaded_ = 0;     // frames loaded so far (ring holds [consumed_, loaded_))
  std::size_t consumed_ = 0;   // frames released by the consumer
  bool holding_ = false;       // the consumer holds ring_[(consumed_) % kRing]
  bool stop_ = false;
  std::uint64_t skipped_ = 0;
  std::thread thread_;
};

// Stereo pairs held in memory, delivered like a recording's (frame i at epoch + time_i +
// latency): for tests and benchmarks that must not decode images while they measure.
class MemoryFrameSource final : public FrameSource {
 public:
  struct Pair {
    std::uint64_t seq = 0;
    Nanos time = 0;  // from the first pair's capture
    cv::Mat left, right;
  };
  MemoryFrameSource(std::vector<Pair> pairs, Nanos latency) : pairs_(std::move(pairs)), latency_(latency) {}
  void start(Nanos epoch) override { epoch_ = epoch; }
  void stop() noexcept override {}
  FrameResult next(Nanos now, StereoFrameRef& out) noexcept override;
  std::uint64_t skipped() const override { return skipped_; }
  // The same pairs again from `epoch`, as the next panel (soak runs). Sequence numbers
  // go on increasing. Only between the vision task's runs (a simulated clock between
  // run_until calls).
  void rewind(Nanos epoch) noexcept {
    epoch_ = epoch;
    next_ = 0;
    seq_base_ += pairs_.empty() ? 0 : pairs_.back().seq + 1;
  }

 private:
  std::vector<Pair> pairs_;
  Nanos latency_;
  Nanos epoch_ = 0;
  std::uint64_t seq_base_ = 0;
  std::size_t next_ = 0;
  std::uint64_t skipped_ = 0;
};

}  // namespace markcell::vision
