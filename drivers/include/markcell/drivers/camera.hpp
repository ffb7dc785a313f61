#pragma once
// Cameras: one interface, the GigE Vision one through Aravis, and the stereo pairing of
// two of them.
//
// A camera is opened by its Aravis device id or by its IP address, set to Mono8 at the
// configured size, frame rate, exposure and gain, its GigE Vision packet size and
// inter-packet delay, and triggered either by software or by a hardware line (both
// cameras on the same trigger line expose at the same instant); what it is set to is
// read back, and what it does not offer is refused naming the camera and what it offers.
// Frames come from a pool of buffers allocated at activation; next() hands out one frame
// at a time and takes the previous one back. Lost and incomplete frames
// are counted, and a camera that stops delivering is reported as lost.
#include <atomic>
#include <cstdint>
#include <string>

#include "markcell/common/param.hpp"
#include "markcell/common/time.hpp"

namespace markcell::drivers {

enum class TriggerMode : std::uint8_t { kSoftware, kHardware };

// GenICam's TriggerActivation: which edge or level of the trigger line starts an exposure
// (a PLC or a light barrier may give either polarity).
enum class TriggerActivation : std::uint8_t { kRisingEdge, kFallingEdge, kAnyEdge, kLevelHigh, kLevelLow };
const char* genicam_name(TriggerActivation a);  // "RisingEdge", ...

// What each camera of a pair is set to on its own. Two cameras see the panel from two
// sides (exposure and gain differ), and share one link to the computer: their stream
// packets must fit its MTU and, interleaved, not overrun the switch (an inter-packet delay
// on each), as every GigE Vision maker's set-up guide asks.
struct CameraUnitSettings {
  std::string id;                // Aravis device id, or an IP address
  double exposure_us = 4000.0;
  double gain_db = 0.0;
  int packet_size = 0;           // GevSCPSPacketSize: bytes per stream packet; 0 = as the camera has it
  int packet_delay_ticks = 0;    // GevSCPD: the gap between stream packets, in the camera's timestamp ticks

  template <class V>
  void Visit(V& v) {
    v(Param{"id", Unit::kNone, 1, 255, "Aravis device id (arv-tool-0.8 lists them) or IP address; required with source: aravis"}, id);
    v(Param{"exposure_us", Unit::kNone, 1.0, 1e6, "exposure time in microseconds"}, exposure_us);
    v(Param{"gain_db", Unit::kNone, 0.0, 48.0, "analogue gain in dB"}, gain_db);
    v(Param{"packet_size", Unit::kNone, 0, 65535,
            "GigE Vision stream packet size in bytes (GevSCPSPacketSize); 0: as the camera has it; above 1500 needs jumbo frames on the link"},
      packet_size);
    v(Param{"packet_delay_ticks", Unit::kNone, 0, 2147483647,
            "GigE Vision inter-packet delay (GevSCPD) in the camera's timestamp ticks; 0: none"},
      packet_delay_ticks);
  }
};

// One camera as the driver opens it: the pair's shared settings and its own.
struct CameraSettings {
  std::string id;                  // Aravis device id, or an IP address
  int width = 640;
  int height = 480;
  double fps = 30.0;               // acquisition rate (free running) or expected trigger rate
  double exposure_us = 4000.0;
  double gain_db = 0.0;
  TriggerMode trigger = TriggerMode::kHardware;
  std::string trigger_source = "Line0";  // GenICam TriggerSource of the hardware trigger
  TriggerActivation trigger_activation = TriggerActivation::kRisingEdge;
  int packet_size = 0;             // GevSCPSPacketSize; 0 = as the camera has it
  int packet_delay_ticks = 0;      // GevSCPD
  int buffers = 8;

  // The keys `devices.cameras` gives both cameras of the pair (each camera's own are
  // CameraUnitSettings's, under `left` and `right`).
  template <class V>
  void Visit(V& v) {
    v(Param{"width", Unit::kPixel, 16, 16384, "image width", true}, width);
    v(Param{"height", Unit::kPixel, 16, 16384, "image height", true}, height);
    v(Param{"fps", Unit::kNone, 0.1, 1000.0, "frames a second (free running) or the expected trigger rate", true}, fps);
    v(Param{"trigger", Unit::kNone, 0, 0, "hardware: both cameras on the trigger line; software", true},
      Choice<TriggerMode, 2>{trigger, {{{"software", TriggerMode::kSoftware}, {"hardware", TriggerMode::kHardware}}}});
    v(Param{"trigger_source", Unit::kNone, 1, 64, "with trigger: hardware, the cameras' input the line is wired to (GenICam TriggerSource: Line0, Line1, ...)"},
      trigger_source);
    v(Param{"trigger_activation", Unit::kNone, 0, 0, "with trigger: hardware, what of the line starts an exposure (GenICam TriggerActivation)"},
      Choice<TriggerActivation, 5>{trigger_activation,
                                   {{{"rising_edge", TriggerActivation::kRisingEdge},
                                     {"falling_edge", TriggerActivation::kFallingEdge},
                                     {"any_edge", TriggerActivation::kAnyEdge},
                                     {"level_high", TriggerActivation::kLevelHigh},
                                     {"level_low", TriggerActivation::kLevelLow}}}});
  }
  void set_own(const CameraUnitSettings& own) {
    id = own.id;
    exposure_us = own.exposure_us;
    gain_db = own.gain_db;
    packet_size = own.packet_size;
    packet_delay_ticks = own.packet_delay_ticks;
  }
};

struct FrameView {
  const std::uint8_t* pixels = nullptr;  // Mono8, row-major
  int width = 0;
  int height = 0;
  int stride = 0;                        // bytes per row
  Nanos time = 0;                        // CLOCK_MONOTONIC, when the frame arrived
  Nanos device_time = 0;                 // the camera's own timestamp
  std::uint64_t frame_id = 0;
};

enum class FrameStatus : std::uint8_t { kFrame, kTimeout, kIncomplete, kCameraLost, kNotActive };

struct CameraCounters {
  std::uint64_t frames = 0;
  std::uint64_t incomplete = 0;   // a buffer that arrived with missing packets or the wrong size
  std::uint64_t lost = 0;         // frames the stream reports as failed
  std::uint64_t underruns = 0;    // no buffer free when a frame came
  std::uint64_t timeouts = 0;
};

class Camera {
 public:
  virtual ~Camera() = default;
  virtual void activate() = 0;      // opens, configures, allocates the buffer pool; throws naming the camera
  virtual void deactivate() noexcept = 0;
  virtual bool active() const = 0;
  virtual bool lost() const = 0;    // the camera went away (control channel lost)
  virtual const std::string& id() const = 0;
  virtual bool software_trigger() noexcept = 0;
  // Waits at most `timeout` for the next frame. The view stays valid until the next
  // call (the buffer goes back to the pool then).
  virtual FrameStatus next(FrameView& frame, Nanos timeout) noexcept = 0;
  virtual CameraCounters counters() const = 0;
  // Off the real-time path: closes and opens the camera again. Returns false (with the
  // reason in `why`) while it is still unreachable.
  virtual bool reconnect(std::string& why) noexcept = 0;
};

class AravisCamera final : public Camera {
 public:
  explicit AravisCamera(CameraSettings settings);
  ~AravisCamera() override;
  void activate() override;
  void deactivate() noexcept override;
  bool active() const override { return camera_ != nullptr; }
  bool lost() const override { return control_lost_.load(std::memory_order_acquire); }
  const std::string& id() const override { return settings_.id; }
  bool software_trigger() noexcept override;
  FrameStatus next(FrameView& frame, Nanos timeout) noexcept override;
  CameraCounters counters() const override;
  bool reconnect(std::string& why) noexcept override;

 private:
  void release_held() noexcept;
  CameraSettings settings_;
  void* camera_ = nullptr;  // ArvCamera*
  void* stream_ = nullptr;  // ArvStream*
  void* held_ = nullptr;    // ArvBuffer* handed out by next()
  unsigned long control_lost_handler_ = 0;
  std::atomic<bool> control_lost_{false};
  CameraCounters counters_;
};

// Two cameras as one stereo pair: frames are paired by their arrival times; a frame
// with no partner within the tolerance is dropped and counted; a camera that delivers
// nothing for `silence` (since its last frame, or since the first software trigger it has
// not answered, whichever is later) is reported.
struct StereoFrame {
  FrameView left;
  FrameView right;
  Nanos time = 0;  // the later of the two
  std::uint64_t index = 0;
};

enum class PairStatus : std::uint8_t { kPair, kTimeout, kLeftLost, kRightLost };

struct StereoCounters {
  std::uint64_t pairs = 0;
  std::uint64_t unpaired_left = 0;
  std::uint64_t unpaired_right = 0;
};

class StereoCamera {
 public:
  StereoCamera(Camera& left, Camera& right, Nanos pair_tolerance, Nanos silence);
  // Both software triggers (software trigger mode; with a hardware line the PLC or the
  // camera-trigger GPIO fires both).
  bool trigger() noexcept;
  PairStatus next(StereoFrame& out, Nanos timeout) noexcept;
  const StereoCounters& counters() const { return counters_; }

 private:
  Camera& left_;
  Camera& right_;
  Nanos tolerance_;
  Nanos silence_;
  Nanos last_left_ = 0, last_right_ = 0;
  bool have_left_ = false, have_right_ = false;
  bool awaiting_left_ = false, awaiting_right_ = false;  // triggered, no frame since
  FrameView pending_left_, pending_right_;
  StereoCounters counters_;
};

}  // namespace markcell::drivers
