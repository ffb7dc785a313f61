#include "markcell/control/plc_io.hpp"

#include <algorithm>

namespace markcell::control {

void InputFilter::start(bool level, Nanos now) noexcept {
  raw_ = value_ = level;
  raw_since_ = value_since_ = now;
}

void InputFilter::take(bool level, Nanos began) noexcept {
  value_ = level;
  value_since_ = began;
  if (level) ++rises_;
  else ++falls_;
}

void InputFilter::edge(bool level, Nanos time, Nanos now) noexcept {
  if (level == raw_) return;  // the same level again: an edge the queue folded, nothing changes
  const Nanos t = std::clamp(time, raw_since_, std::max(raw_since_, now));
  // The level that ends here lasted [raw_since_, t): long enough, it was the value.
  if (raw_ != value_) {
    if (t - raw_since_ >= filter_) take(raw_, raw_since_);
    else ++glitches_;
  }
  raw_ = level;
  raw_since_ = t;
}

void InputFilter::settle(bool level, Nanos now) noexcept {
  if (level != raw_) edge(level, now, now);
  if (raw_ != value_ && now - raw_since_ >= filter_) take(raw_, raw_since_);
}

TaskResult PlcIo::step(const TaskContext& ctx) noexcept {
  const Nanos now = ctx.now();
  auto read = [&](int line, bool& out) {
    if (line < 0) return false;
    if (lines_.get(line, out) != drivers::GpioStatus::kOk) {
      ++io_errors_;
      return false;
    }
    return true;
  };
  if (!started_) {
    bool level = false;
    panel_.start(read(map_.panel_present, level) && level, now);
    level = false;
    cycle_.start(read(map_.cycle_enable, level) && level, now);
    started_ = true;
  }
  // Edges first, each with its kernel time: the filters see every pulse, however short
  // and wherever it falls between two runs. A queue that stays full after four drains
  // is a line toggling faster than the task can follow: the valve is not permitted.
  bool panel_fell = false, estop_seen = false, overflow = true;
  for (int round = 0; round < 4; ++round) {
    const int n = lines_.read_events(events_, 0);
    for (int i = 0; i < n; ++i) {
      const auto& e = events_[static_cast<std::size_t>(i)];
      if (e.line == map_.panel_present) {
        panel_.edge(e.active, e.time, now);
        panel_fell = panel_fell || !e.active;
      } else if (e.line == map_.cycle_enable) {
        cycle_.edge(e.active, e.time, now);
      } else if (e.line == map_.estop && e.active) {
        estop_seen = true;
      }
    }
    if (n < static_cast<int>(events_.size())) {
      overflow = false;
      break;
    }
  }
  bool level = false;
  const bool panel_ok = read(map_.panel_present, level);
  const bool panel_now = panel_ok && level;
  panel_.settle(panel_now, now);
  level = false;
  cycle_.settle(read(map_.cycle_enable, level) && level, now);
  level = false;
  const bool estop_now = read(map_.estop, level) && level;

  inputs_.panel_present = panel_.value();
  inputs_.panel_present_since = panel_.value_since();
  inputs_.cycle_enable = cycle_.value();
  inputs_.estop = estop_now || estop_seen;
  inputs_.panel_present_drops = panel_.falls();
  inputs_.glitches = panel_.glitches() + cycle_.glitches();
  inputs_.spray_permitted =
      map_.panel_present >= 0 && panel_now && !panel_fell && !overflow && !inputs_.estop && panel_.steady_high(now);

  if (inputs_.estop && !safe_stop_.active())
    safe_stop_.trigger(now, FaultCode::kOperatorStop, "plc_estop", estop_now ? "e-stop input active" : "e-stop pulse (edge latched)");
  // Glitches are ignored by the filter but not hidden: one fault-log entry a second at
  // most, with the count.
  if (inputs_.glitches != glitches_reported_ && now - glitch_report_at_ >= seconds(1)) {
    Fault f;
    f.time = now;
    f.code = FaultCode::kInputGlitch;
    f.source.assign("plc_io");
    f.detail.format("%llu input pulse(s) shorter than the filter ignored (panel present %llu, cycle enable %llu in all)",
                    static_cast<unsigned long long>(inputs_.glitches - glitches_reported_),
                    static_cast<unsigned long long>(panel_.glitches()), static_cast<unsigned long long>(cycle_.glitches()));
    safe_stop_.log().push(f);
    glitches_reported_ = inputs_.glitches;
    glitch_report_at_ = now;
  }
  rearm_if_asked();
  const bool stopped = safe_stop_.active();
  auto write = [&](int line, bool value) {
    if (line >= 0 && lines_.set(line, value) != drivers::GpioStatus::kOk) ++io_errors_;
  };
  write(map_.ready, inputs_.cycle_enable && !stopped);
  if (stopped) write(map_.fault, true);
  else if (safe_stop_.stops() != stop_seen_) {
    // Re-armed: the stop's fault line drops (a panel's own fault is the marking's to hold).
    write(map_.fault, false);
    stop_seen_ = safe_stop_.stops();
    estop_released_ = false;
  }
  return TaskResult::kOk;
}

void PlcIo::rearm_if_asked() noexcept {
  if (!safe_stop_.done() || safe_stop_.stops() == stop_seen_ || rearm_ == RearmPolicy::kNever) return;
  if (!safe_stop_.recoverable() || safe_stop_.rearm_requested()) return;
  // The e-stop must be released first; a reset edge of cycle enable counts only after it.
  if (inputs_.estop) {
    estop_released_ = false;
    return;
  }
  if (!estop_released_) {
    estop_released_ = true;
    rises_at_release_ = cycle_.rises();
    return;
  }
  if (cycle_.rises() != rises_at_release_ && inputs_.cycle_enable) {
    rises_at_release_ = cycle_.rises();
    safe_stop_.request_rearm();
  }
}

}  // namespace markcell::control
