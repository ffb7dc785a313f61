#pragma once
// A configurable parameter is declared once, by the struct that uses it, in a Visit()
// member (Drake's Serialize(), PX4's parameter files):
//
//   template <class V> void Visit(V& v) {
//     v(Param{"standoff_m", Unit::kMetre, 0.01, 1.0, "nozzle to surface when spraying"}, standoff);
//     v(Param{"settle_ms", Unit::kMillisecond, 0, 10'000, "on target this long before the pulse"}, settle_time);
//   }
//
// The struct's member initialiser is the parameter's one default; the Param says its key
// in the configuration, the unit the configuration writes it in, its range in that unit,
// and one line on what it does. The field always holds SI (metres, radians, Nanos): the
// unit is converted once, by whoever reads or writes the configuration. Visitors: the
// YAML reader (firmware_host/config.cpp, with FILE:LINE:COL errors), the JSON Schema
// export (`markcell config-schema`), the test that the example configuration documents
// the defaults. A leaf: no YAML, no JSON here.
#include <array>
#include <cstddef>
#include <cstdint>
#include <numbers>
#include <string_view>

#include "markcell/common/time.hpp"

namespace markcell {

// The unit a parameter is written in, in the configuration. Lengths, angles and
// durations are stored in SI whatever the unit; the others are stored as written.
enum class Unit : std::uint8_t {
  kNone,         // a count, a ratio, a choice, a flag
  kPixel,
  kMetre,
  kMillimetre,   // stored in metres
  kDegree,       // stored in radians
  kMicrosecond,  // an integer in the configuration, stored as Nanos
  kMillisecond,  // an integer in the configuration, stored as Nanos
  kSecond,       // a number in the configuration, stored as Nanos
  kMetrePerSecond,
  kMetrePerSecond2,
  kOddWindowPx,  // a window's full width (odd, pixels), stored as its half width
};

// A length or an angle as the configuration writes it, to the stored SI value and back
// (the durations' conversions are to_nanos and from_nanos below). Written as divisions
// and products by exact constants so that 1.5 mm is exactly the double nearest 0.0015 m.
constexpr double to_si(double value, Unit u) {
  switch (u) {
    case Unit::kMillimetre: return value / 1000.0;
    case Unit::kDegree: return value * std::numbers::pi / 180.0;
    default: return value;
  }
}
constexpr double from_si(double value, Unit u) {
  switch (u) {
    case Unit::kMillimetre: return value * 1000.0;
    case Unit::kDegree: return value * 180.0 / std::numbers::pi;
    default: return value;
  }
}

constexpr std::string_view unit_name(Unit u) {
  switch (u) {
    case Unit::kNone: return "";
    case Unit::kPixel: return "px";
    case Unit::kMetre: return "m";
    case Unit::kMillimetre: return "mm";
    case Unit::kDegree: return "deg";
    case Unit::kMicrosecond: return "us";
    case Unit::kMillisecond: return "ms";
    case Unit::kSecond: return "s";
    case Unit::kMetrePerSecond: return "m/s";
    case Unit::kMetrePerSecond2: return "m/s^2";
    case Unit::kOddWindowPx: return "px (odd)";
  }
  return "";
}

struct Param {
  std::string_view key;  // in its section of the configuration
  Unit unit = Unit::kNone;
  double lo = 0, hi = 0;  // the accepted range, in `unit` (both ends included); a text's length
  std::string_view doc;   // one line: what it does
  bool required = false;  // the configuration must write it (else: the declared default)
};

// A choice among named values (an enum parameter): each name as the configuration
// writes it, with its value.
template <typename E>
struct Option {
  std::string_view name;
  E value;
};
template <typename E, std::size_t N>
struct Choice {
  E& value;
  std::array<Option<E>, N> options;
};

// A map nested in a section (`watchdog.device`, `base_calibration.board`): a struct with
// a Visit() of its own, read, checked and described as its own keys under `key`.
template <typename T>
struct Section {
  T& value;
};

// Whether a duration's unit is written as an integer (ms, us) rather than a number (s).
constexpr bool integer_duration(Unit u) { return u == Unit::kMillisecond || u == Unit::kMicrosecond; }

// A duration as the configuration writes it (integer micro- or milliseconds, or seconds)
// and back.
constexpr double nanos_per(Unit u) {
  return u == Unit::kMicrosecond ? 1e3 : u == Unit::kMillisecond ? 1e6 : 1e9;
}
constexpr Nanos to_nanos(double value, Unit u) { return static_cast<Nanos>(value * nanos_per(u)); }
constexpr double from_nanos(Nanos value, Unit u) { return static_cast<double>(value) / nanos_per(u); }

}  // namespace markcell
