#pragma once
// SplitMix64: a tiny, seeded, allocation-free generator with the same sequence on every
// platform, and the few transforms the rig draws with (uniform, normal). The standard
// library's distributions are not specified bit for bit (libstdc++ and libc++ give other
// numbers from the same engine), and the rig's scenarios, images and RANSAC draws must be
// the same on every compiler and architecture. The transforms use only + - * / and sqrt,
// which IEEE 754 rounds exactly, so with -ffp-contract=off (the top CMakeLists.txt) they
// give the same bits everywhere; not libm's log, whose last bit may differ between builds.
#include <cmath>
#include <cstddef>
#include <cstdint>

namespace markcell {

// log(x) for finite x > 0 from + - * / alone: x = m 2^e with m in [sqrt(1/2), sqrt(2)),
// log m = 2 atanh(s), s = (m - 1) / (m + 1), |s| < 0.172, whose odd series has converged
// to below 1e-19 after 13 terms. Within a few ulp of std::log (tests/test_geometry.cpp).
inline double portable_log(double x) {
  int e = 0;
  double m = std::frexp(x, &e);  // exact: m in [0.5, 1)
  if (m < 0.70710678118654752440) {
    m *= 2;
    --e;
  }
  const double s = (m - 1) / (m + 1), s2 = s * s;
  double sum = 0;
  for (int k = 25; k >= 1; k -= 2) sum = sum * s2 + 1.0 / k;
  return 2 * s * sum + static_cast<double>(e) * 0.69314718055994530942;
}

struct SplitMix {
  std::uint64_t state;
  std::uint64_t next() {
    std::uint64_t z = (state += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
  }
  std::size_t below(std::size_t n) { return static_cast<std::size_t>(next() % n); }
  double unit() { return static_cast<double>(next() >> 11) * 0x1.0p-53; }  // [0, 1)
  double uniform(double lo, double hi) { return lo + (hi - lo) * unit(); }  // [lo, hi)
  // A standard normal deviate: Marsaglia's polar method (one deviate per accepted pair,
  // so the stream's position never depends on a cached second value). A pair is accepted
  // with probability pi/4; 64 rejections in a row (probability below 1e-42) give 0.
  double normal() {
    for (int tries = 0; tries < 64; ++tries) {
      const double u = 2 * unit() - 1;
      const double v = 2 * unit() - 1;
      const double s = u * u + v * v;
      if (s > 0 && s < 1) return u * std::sqrt(-2 * portable_log(s) / s);
    }
    return 0.0;
  }
  double normal(double mean, double sigma) { return mean + sigma * normal(); }
};

}  // namespace markcell
