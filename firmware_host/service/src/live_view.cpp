#include "markcell/host/live_view.hpp"

#include <algorithm>

#include <opencv2/core.hpp>

namespace markcell::host {

bool reduce_frame(const cv::Mat& frame, std::uint8_t* out, int& width, int& height, int& scale) noexcept {
  if (frame.empty() || frame.dims != 2 || (frame.type() != CV_8UC1 && frame.type() != CV_8UC3)) return false;
  const int s = std::max({1, (frame.cols + LiveView::kMaxWidth - 1) / LiveView::kMaxWidth,
                          (frame.rows + LiveView::kMaxHeight - 1) / LiveView::kMaxHeight});
  const int w = frame.cols / s, h = frame.rows / s;
  const int channels = frame.channels();
  const int offset = channels == 3 ? 1 : 0;  // BGR's green: the grey a camera's luminance is nearest
  for (int y = 0; y < h; ++y) {
    const std::uint8_t* row = frame.ptr<std::uint8_t>(y * s);
    std::uint8_t* dst = out + static_cast<std::ptrdiff_t>(y) * w;
    for (int x = 0; x < w; ++x) dst[x] = row[static_cast<std::ptrdiff_t>(x) * s * channels + offset];
  }
  width = w;
  height = h;
  scale = s;
  return true;
}

void LiveViewChannel::offer(std::uint64_t seq, Nanos time, const cv::Mat& left, const cv::Mat& right,
                            const msg::PoseEstimate& estimate) noexcept {
  const std::uint64_t wanted = requested_.load(std::memory_order_acquire);
  if (wanted == served_) return;
  served_ = wanted;
  LiveView& v = views_.write_slot();
  int wr = 0, hr = 0, sr = 0;
  if (!reduce_frame(left, v.left.data(), v.width, v.height, v.scale) ||
      !reduce_frame(right, v.right.data(), wr, hr, sr) || wr != v.width || hr != v.height) {
    return;  // (a pair the tracker took has one type and size: nothing to show otherwise)
  }
  v.copies = ++copies_;
  v.seq = seq;
  v.time = time;
  v.pose = estimate;
  views_.publish();
}

}  // namespace markcell::host
