#pragma once
// The live cameras as the vision task's frame source.
//
// A receive thread (a device thread, like Aravis's own stream thread) waits for stereo
// pairs with a bounded timeout, copies each pair into one of three image pairs allocated
// at start, and publishes it; in software-trigger mode it also fires both cameras at the
// configured rate. The vision task takes the newest published pair without blocking
// (the lock is held only to swap indices, never during a copy), so a slow vision run
// skips frames (counted) rather than delaying the lane.
//
// A camera that stops delivering is reported once, as a dropped pair naming the camera;
// the receive thread then tries to reconnect it once a second and pairs flow again.
#include <array>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include <opencv2/core.hpp>

#include "markcell/drivers/camera.hpp"
#include "markcell/vision/frame_source.hpp"

namespace markcell::host {

struct CameraFrameSourceCounters {
  std::uint64_t pairs = 0;        // published by the receive thread
  std::uint64_t timeouts = 0;     // waits that ended with no pair
  std::uint64_t losses = 0;       // a camera reported lost
  std::uint64_t reconnects = 0;   // a lost camera brought back
};

class CameraFrameSource final : public vision::FrameSource {
 public:
  // `latency`: exposure to frame in memory; a pair's capture time is its arrival minus
  // this. `software_trigger`: fire both cameras at `fps` from the receive thread
  // (otherwise a hardware line does, e.g. the camera_trigger task).
  CameraFrameSource(std::unique_ptr<drivers::Camera> left, std::unique_ptr<drivers::Camera> right, int width, int height,
                    double fps, bool software_trigger, Nanos latency, Nanos silence);
  ~CameraFrameSource() override;
  // Activates both cameras (throws naming one that cannot be opened), allocates the
  // image pairs and starts the receive thread.
  void start(Nanos epoch) override;
  void stop() noexcept override;
  vision::FrameResult next(Nanos now, vision::StereoFrameRef& out) noexcept override;
  std::uint64_t skipped() const override;
  CameraFrameSourceCounters counters() const;

 private:
  static constexpr int kSlots = 3;  // one being written, one published, one held by the vision task
  void receive() noexcept;
  void copy_into(int slot, const drivers::StereoFrame& f) noexcept;
  void publish(int slot, Nanos time) noexcept;
  void report_lost(const std::string& text) noexcept;
  bool try_reconnect() noexcept;

  std::unique_ptr<drivers::Camera> left_, right_;
  const int width_, height_;
  const Nanos period_;
  const bool software_trigger_;
  const Nanos latency_;
  const Nanos silence_;
  const std::string left_lost_text_, right_lost_text_;
  std::optional<drivers::StereoCamera> pair_;
  std::array<cv::Mat, kSlots> left_images_, right_images_;
  std::array<Nanos, kSlots> times_{};
  std::array<std::uint64_t, kSlots> seqs_{};

  mutable std::mutex mutex_;
  std::condition_variable stop_cv_;
  bool stop_ = false;
  int published_ = -1;             // newest pair, not yet handed out when seqs_ > handed_seq_
  int held_ = -1;                  // the pair the vision task holds
  std::uint64_t handed_seq_ = 0;
  std::uint64_t next_seq_ = 1;
  const std::string* lost_report_ = nullptr;  // a loss not yet handed to the vision task
  bool lost_ = false;              // receive thread only: waiting to reconnect
  bool lost_left_ = false, lost_right_ = false;
  std::uint64_t skipped_ = 0;
  CameraFrameSourceCounters counters_;
  std::thread thread_;
};

}  // namespace markcell::host
