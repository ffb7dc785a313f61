#include <arv.h>
#include <time.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "markcell/drivers/camera.hpp"

namespace markcell::drivers {

namespace {

ArvCamera* cam(void* p) { return static_cast<ArvCamera*>(p); }
ArvStream* stream(void* p) { return static_cast<ArvStream*>(p); }

Nanos realtime_now() {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return from_timespec(ts);
}

void on_control_lost(ArvDevice*, gpointer self) {
  static_cast<std::atomic<bool>*>(self)->store(true, std::memory_order_release);
}

// Throws with the camera named when a GError was set.
void check(GError*& error, const std::string& id, const char* what) {
  if (error == nullptr) return;
  const std::string message = "camera '" + id + "': " + what + ": " + error->message;
  g_clear_error(&error);
  throw std::runtime_error(message);
}

// Refuses `value` for an enumeration feature (TriggerSource, TriggerActivation) the camera
// does not offer, naming what it offers ("A, B, C"); `label` names the setting.
void require_offered(ArvCamera* c, const char* feature, const char* label, const std::string& value, const std::string& id) {
  GError* error = nullptr;
  guint n = 0;
  const char** names = arv_camera_dup_available_enumerations_as_strings(c, feature, &n, &error);
  check(error, id, (std::string("list its ") + feature + " values").c_str());
  std::string list;
  bool has = false;
  for (guint i = 0; i < n; ++i) {
    list += (i > 0 ? ", " : "") + std::string(names[i]);
    if (value == names[i]) has = true;
  }
  g_free(static_cast<gpointer>(names));
  if (!has)
    throw std::runtime_error("camera '" + id + "': " + label + " '" + value + "' is not one it offers (" + list + ")");
}

// Sets an integer feature the camera declares a range (and step) for, and reads it back.
// The range is checked here: Aravis writes whatever it is given, and a camera may clamp
// or round it silently; a value outside, off the step or read back different is refused
// with the numbers rather than run on a value nobody configured.
void set_integer_exact(ArvCamera* c, const char* feature, gint64 value, const char* what, const std::string& id) {
  const std::string named = "camera '" + id + "': " + what + " " + std::to_string(value) + " (" + feature + ")";
  GError* error = nullptr;
  gint64 lo = 0, hi = 0;
  arv_camera_get_integer_bounds(c, feature, &lo, &hi, &error);
  check(error, id, (std::string("read the range of ") + feature).c_str());
  gint64 step = arv_camera_get_integer_increment(c, feature, &error);
  if (error != nullptr) {  // no increment declared: any integer in the range
    g_clear_error(&error);
    step = 1;
  }
  if (value < lo || value > hi || (step > 1 && (value - lo) % step != 0))
    throw std::runtime_error(named + ": it takes " + std::to_string(lo) + " to " + std::to_string(hi) +
                             (step > 1 ? " in steps of " + std::to_string(step) : ""));
  arv_camera_set_integer(c, feature, value, &error);
  check(error, id, (std::string("set ") + feature).c_str());
  const gint64 got = arv_camera_get_integer(c, feature, &error);
  check(error, id, (std::string("read back ") + feature).c_str());
  if (got != value) throw std::runtime_error(named + ": it gives " + std::to_string(got));
}

}  // namespace

const char* genicam_name(TriggerActivation a) {
  switch (a) {
    case TriggerActivation::kRisingEdge: return "RisingEdge";
    case TriggerActivation::kFallingEdge: return "FallingEdge";
    case TriggerActivation::kAnyEdge: return "AnyEdge";
    case TriggerActivation::kLevelHigh: return "LevelHigh";
    case TriggerActivation::kLevelLow: return "LevelLow";
  }
  return "RisingEdge";
}

AravisCamera::AravisCamera(CameraSettings settings) : settings_(std::move(settings)) {}

AravisCamera::~AravisCamera() { deactivate(); }

void AravisCamera::activate() {
  if (camera_ != nullptr) return;
  GError* error = nullptr;
  ArvCamera* c = arv_camera_new(settings_.id.c_str(), &error);
  check(error, settings_.id, "open");
  camera_ = c;
  try {
    control_lost_.store(false);
    control_lost_handler_ =
        g_signal_connect(arv_camera_get_device(c), "control-lost", G_CALLBACK(on_control_lost), &control_lost_);
    arv_camera_set_region(c, 0, 0, settings_.width, settings_.height, &error);
    check(error, settings_.id, "set the image size");
    gint x = 0, y = 0, w = 0, h = 0;
    arv_camera_get_region(c, &x, &y, &w, &h, &error);
    check(error, settings_.id, "read the image size");
    if (w != settings_.width || h != settings_.height)
      throw std::runtime_error("camera '" + settings_.id + "': asked for " + std::to_string(settings_.width) + "x" +
                               std::to_string(settings_.height) + ", it gives " + std::to_string(w) + "x" + std::to_string(h));
    arv_camera_set_pixel_format(c, ARV_PIXEL_FORMAT_MONO_8, &error);
    check(error, settings_.id, "set Mono8");
    arv_camera_set_exposure_time(c, settings_.exposure_us, &error);
    check(error, settings_.id, "set the exposure");
    if (arv_camera_is_gain_available(c, nullptr)) {
      arv_camera_set_gain(c, settings_.gain_db, &error);
      check(error, settings_.id, "set the gain");
    }
    if (settings_.trigger == TriggerMode::kSoftware) {
      arv_camera_set_trigger(c, "Software", &error);
      check(error, settings_.id, "set the software trigger");
    } else {
      // The source first checked against what the camera offers: Aravis would otherwise
      // fail with GenICam's own words, or a camera without that line take another. Then
      // trigger mode on for the frame start, that source, and a rising edge where it has
      // TriggerActivation; then the configured activation.
      require_offered(c, "TriggerSource", "trigger source", settings_.trigger_source, settings_.id);
      arv_camera_set_trigger(c, settings_.trigger_source.c_str(), &error);
      check(error, settings_.id, "set the hardware trigger");
      const char* activation = genicam_name(settings_.trigger_activation);
      if (arv_camera_is_feature_available(c, "TriggerActivation", nullptr)) {
        require_offered(c, "TriggerActivation", "TriggerActivation", activation, settings_.id);
        arv_camera_set_string(c, "TriggerActivation", activation, &error);
        check(error, settings_.id, "set TriggerActivation");
      } else if (settings_.trigger_activation != TriggerActivation::kRisingEdge) {
        throw std::runtime_error("camera '" + settings_.id + "': it has no TriggerActivation, so it cannot be set to " +
                                 activation + " (leave trigger_activation at rising_edge)");
      }
    }
    // GigE Vision's stream settings, before the stream exists (the camera locks them while
    // it streams). With a configured size, Aravis must not replace it with one it finds by
    // probing the link: the integrator's figure stands, or the camera is refused.
    const bool gige = arv_camera_is_gv_device(c);
    if (settings_.packet_size > 0) {
      if (!gige)
        throw std::runtime_error("camera '" + settings_.id + "': packet_size is set, but it is not a GigE Vision camera");
      arv_camera_gv_set_packet_size_adjustment(c, ARV_GV_PACKET_SIZE_ADJUSTMENT_NEVER);
      set_integer_exact(c, "GevSCPSPacketSize", settings_.packet_size, "packet size", settings_.id);
    }
    if (gige && arv_camera_is_feature_available(c, "GevSCPD", nullptr)) {
      set_integer_exact(c, "GevSCPD", settings_.packet_delay_ticks, "inter-packet delay", settings_.id);
    } else if (settings_.packet_delay_ticks > 0) {
      throw std::runtime_error("camera '" + settings_.id + "': packet_delay_ticks is set, but it has no GevSCPD");
    }
    const guint payload = arv_camera_get_payload(c, &error);
    check(error, settings_.id, "read the payload size");
    ArvStream* s = arv_camera_create_stream(c, nullptr, nullptr, &error);
    check(error, settings_.id, "create the stream");
    stream_ = s;
    for (int i = 0; i < settings_.buffers; ++i) arv_stream_push_buffer(s, arv_buffer_new(payload, nullptr));
    arv_camera_start_acquisition(c, &error);
    check(error, settings_.id, "start the acquisition");
  } catch (...) {
    deactivate();
    throw;
  }
}

void AravisCamera::release_held() noexcept {
  if (held_ != nullptr && stream_ != nullptr) arv_stream_push_buffer(stream(stream_), static_cast<ArvBuffer*>(held_));
  held_ = nullptr;
}

void AravisCamera::deactivate() noexcept {
  if (camera_ == nullptr) return;
  // A camera that is gone answers nothing: stopping it would only wait for time-outs.
  if (!lost()) arv_camera_stop_acquisition(cam(camera_), nullptr);
  if (held_ != nullptr) g_object_unref(static_cast<ArvBuffer*>(held_));
  held_ = nullptr;
  if (stream_ != nullptr) {
    guint64 completed = 0, failures = 0, underruns = 0;
    arv_stream_get_statistics(stream(stream_), &completed, &failures, &underruns);
    counters_.lost = failures;
    counters_.underruns = underruns;
    g_object_unref(stream(stream_));
  }
  stream_ = nullptr;
  if (control_lost_handler_ != 0) g_signal_handler_disconnect(arv_camera_get_device(cam(camera_)), control_lost_handler_);
  control_lost_handler_ = 0;
  g_object_unref(cam(camera_));
  camera_ = nullptr;
}

bool AravisCamera::software_trigger() noexcept {
  if (camera_ == nullptr || lost()) return false;
  GError* error = nullptr;
  arv_camera_software_trigger(cam(camera_), &error);
  if (error != nullptr) {
    g_clear_error(&error);
    return false;
  }
  return true;
}

FrameStatus AravisCamera::next(FrameView& frame, Nanos timeout) noexcept {
  if (camera_ == nullptr) return FrameStatus::kNotActive;
  release_held();
  if (lost()) return FrameStatus::kCameraLost;
  const auto us = static_cast<guint64>(timeout > 0 ? (timeout + 999) / 1000 : 0);
  ArvBuffer* b = arv_stream_timeout_pop_buffer(stream(stream_), us);
  if (b == nullptr) {
    ++counters_.timeouts;
    return lost() ? FrameStatus::kCameraLost : FrameStatus::kTimeout;
  }
  if (arv_buffer_get_status(b) != ARV_BUFFER_STATUS_SUCCESS || arv_buffer_get_image_width(b) != settings_.width ||
      arv_buffer_get_image_height(b) != settings_.height ||
      arv_buffer_get_image_pixel_format(b) != ARV_PIXEL_FORMAT_MONO_8) {
    ++counters_.incomplete;
    arv_stream_push_buffer(stream(stream_), b);
    return FrameStatus::kIncomplete;
  }
  std::size_t size = 0;
  frame.pixels = static_cast<const std::uint8_t*>(arv_buffer_get_image_data(b, &size));
  frame.width = settings_.width;
  frame.height = settings_.height;
  frame.stride = settings_.width;
  // The system timestamp is CLOCK_REALTIME; bring it onto the monotonic time base.
  const auto system = static_cast<Nanos>(arv_buffer_get_system_timestamp(b));
  frame.time = monotonic_now() - (realtime_now() - system);
  frame.device_time = static_cast<Nanos>(arv_buffer_get_timestamp(b));
  frame.frame_id = arv_buffer_get_frame_id(b);
  held_ = b;
  ++counters_.frames;
  return FrameStatus::kFrame;
}

CameraCounters AravisCamera::counters() const {
  CameraCounters c = counters_;
  if (stream_ != nullptr) {
    guint64 completed = 0, failures = 0, underruns = 0;
    arv_stream_get_statistics(stream(stream_), &completed, &failures, &underruns);
    c.lost = failures;
    c.underruns = underruns;
  }
  return c;
}

bool AravisCamera::reconnect(std::string& why) noexcept {
  deactivate();
  try {
    activate();
    return true;
  } catch (const std::exception& e) {
    why = e.what();
    return false;
  }
}

StereoCamera::StereoCamera(Camera& left, Camera& right, Nanos pair_tolerance, Nanos silence)
    : left_(left), right_(right), tolerance_(pair_tolerance), silence_(silence) {
  last_left_ = last_right_ = monotonic_now();
}

bool StereoCamera::trigger() noexcept {
  // Silence is counted from the first trigger a camera has not answered (not from its
  // last frame): a camera idle between software-triggered shots is not a lost one.
  const Nanos now = monotonic_now();
  if (!awaiting_left_) last_left_ = std::max(last_left_, now), awaiting_left_ = true;
  if (!awaiting_right_) last_right_ = std::max(last_right_, now), awaiting_right_ = true;
  const bool l = left_.software_trigger();
  const bool r = right_.software_trigger();
  return l && r;
}

PairStatus StereoCamera::next(StereoFrame& out, Nanos timeout) noexcept {
  const Nanos deadline = monotonic_now() + timeout;
  // Bounded: each round takes at least one frame or ends on the deadline.
  for (int round = 0; round < 16; ++round) {
    const Nanos now = monotonic_now();
    const Nanos left_wait = deadline > now ? deadline - now : 0;
    if (!have_left_) {
      const FrameStatus s = left_.next(pending_left_, left_wait);
      if (s == FrameStatus::kFrame) {
        have_left_ = true;
        awaiting_left_ = false;
        last_left_ = pending_left_.time;
      }
    }
    const Nanos now2 = monotonic_now();
    if (!have_right_) {
      const FrameStatus s = right_.next(pending_right_, deadline > now2 ? deadline - now2 : 0);
      if (s == FrameStatus::kFrame) {
        have_right_ = true;
        awaiting_right_ = false;
        last_right_ = pending_right_.time;
      }
    }
    const Nanos t = monotonic_now();
    if (left_.lost() || (!have_left_ && t - last_left_ > silence_)) return PairStatus::kLeftLost;
    if (right_.lost() || (!have_right_ && t - last_right_ > silence_)) return PairStatus::kRightLost;
    if (have_left_ && have_right_) {
      const Nanos dt = pending_left_.time - pending_right_.time;
      if (dt <= tolerance_ && dt >= -tolerance_) {
        out.left = pending_left_;
        out.right = pending_right_;
        out.time = dt > 0 ? pending_left_.time : pending_right_.time;
        out.index = counters_.pairs++;
        have_left_ = have_right_ = false;
        return PairStatus::kPair;
      }
      // No partner: the older frame goes.
      if (dt < 0) {
        have_left_ = false;
        ++counters_.unpaired_left;
      } else {
        have_right_ = false;
        ++counters_.unpaired_right;
      }
      continue;
    }
    if (t >= deadline) break;
  }
  return PairStatus::kTimeout;
}

}  // namespace markcell::drivers
