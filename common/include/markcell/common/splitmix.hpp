#pragma once
// SplitMix64: a tiny, seeded, allocation-free generator with the same sequence on every
// platform (the standard library's distributions are not specified bit for bit, and the
// rig's images and the RANSAC draws must be the same everywhere).
#include <cstddef>
#include <cstdint>

namespace markcell {

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
};

}  // namespace markcell
