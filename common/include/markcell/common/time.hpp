#pragma once
// Time inside markcell is integer nanoseconds on a monotonic time base: the real
// CLOCK_MONOTONIC or the simulated clock. Integers keep the simulated runs bit-exact.
#include <cstdint>
#include <ctime>

namespace markcell {

using Nanos = std::int64_t;

constexpr Nanos kNanosPerMicro = 1'000;
constexpr Nanos kNanosPerMilli = 1'000'000;
constexpr Nanos kNanosPerSecond = 1'000'000'000;

constexpr Nanos micros(std::int64_t us) { return us * kNanosPerMicro; }
constexpr Nanos millis(std::int64_t ms) { return ms * kNanosPerMilli; }
constexpr Nanos seconds(std::int64_t s) { return s * kNanosPerSecond; }
constexpr double to_seconds(Nanos t) { return static_cast<double>(t) * 1e-9; }
constexpr double to_micros(Nanos t) { return static_cast<double>(t) * 1e-3; }

constexpr timespec to_timespec(Nanos t) {
  return timespec{static_cast<time_t>(t / kNanosPerSecond), static_cast<long>(t % kNanosPerSecond)};
}
constexpr Nanos from_timespec(const timespec& ts) {
  return static_cast<Nanos>(ts.tv_sec) * kNanosPerSecond + ts.tv_nsec;
}

// CLOCK_MONOTONIC now. Used for measuring; logic that must be deterministic asks the
// injected executive clock instead.
inline Nanos monotonic_now() {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return from_timespec(ts);
}

// CLOCK_REALTIME now, nanoseconds since the epoch: only for the UTC times written beside
// the cell's own (never for deciding anything: the wall clock may jump).
inline std::int64_t realtime_now() {
  timespec ts{};
  clock_gettime(CLOCK_REALTIME, &ts);
  return from_timespec(ts);
}

}  // namespace markcell
