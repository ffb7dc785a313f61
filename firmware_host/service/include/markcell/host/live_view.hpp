#pragma once
// The operator page's live view: the newest stereo pair the vision task tracked, with the
// frame's estimate, handed from the vision lane to the page's thread through a triple
// buffer. The lane copies a pair only when the page asked for one since its last copy
// (one copy per request at most, one per frame at most), so a cell nobody watches copies
// nothing; a copy is bounded (at most kMaxWidth x kMaxHeight bytes per camera, every
// `scale`-th pixel of the frame) and allocates nothing: the buffer's 2 MiB are taken once,
// before the lanes start.
#include <array>
#include <atomic>
#include <cstdint>

#include "markcell/common/time.hpp"
#include "markcell/common/triple_buffer.hpp"
#include "markcell/msg/pose_estimate.hpp"

namespace cv {
class Mat;
}

namespace markcell::host {

struct LiveView {
  static constexpr int kMaxWidth = 640;
  static constexpr int kMaxHeight = 512;
  std::uint64_t copies = 0;  // 0: nothing yet
  std::uint64_t seq = 0;     // the frame pair's
  Nanos time = 0;            // its capture time (the cell's clock)
  int width = 0, height = 0;  // of the reduced images, kMaxWidth x kMaxHeight at most
  int scale = 1;              // frame pixels per reduced pixel, in each direction
  std::array<std::uint8_t, kMaxWidth * kMaxHeight> left{}, right{};  // 8-bit grey, rows of `width`
  msg::PoseEstimate pose;     // the tracker's estimate of that pair (MF pixels in frame pixels)
};

// The frame reduced into `out` (grey: an 8-bit frame as it is, a 3-channel one's green):
// every `scale`-th pixel, scale the least that fits kMaxWidth x kMaxHeight. False, and
// nothing written, for any other pixel type or an empty frame.
bool reduce_frame(const cv::Mat& frame, std::uint8_t* out, int& width, int& height, int& scale) noexcept;

class LiveViewChannel {
 public:
  // The page's thread: a view is wanted (the next tracked pair is copied).
  void request() { requested_.fetch_add(1, std::memory_order_release); }
  // The vision lane, with each tracked pair: copied when a request came since the last.
  void offer(std::uint64_t seq, Nanos time, const cv::Mat& left, const cv::Mat& right,
             const msg::PoseEstimate& estimate) noexcept;
  // The page's thread (one reader, whoever holds the page's view lock): the newest copy.
  const LiveView& newest() {
    views_.update();
    return views_.read();
  }

 private:
  std::atomic<std::uint64_t> requested_{0};
  std::uint64_t served_ = 0;  // the vision lane's: the request count at its last copy
  std::uint64_t copies_ = 0;
  TripleBuffer<LiveView> views_;
};

}  // namespace markcell::host
