#pragma once
// Fixed-size log-linear histogram of durations (ns): 16 sub-buckets per power of two,
// so any percentile is known to within 1/16 (6.25 %) of its value, from 1 ns to 2^63 ns,
// in 8 KiB that never grow. One writer (the lane that owns it); readers may look at it
// while it runs (relaxed atomics: a live report may be one sample behind).
#include <array>
#include <atomic>
#include <cstdint>
#include <limits>

#include "markcell/common/time.hpp"

namespace markcell::control {

class Histogram {
 public:
  static constexpr int kSubBits = 4;
  static constexpr int kSub = 1 << kSubBits;
  static constexpr int kBuckets = (64 - kSubBits + 1) * kSub;

  void record(Nanos value);
  void reset();

  std::uint64_t count() const { return count_.load(std::memory_order_relaxed); }
  Nanos min() const;
  Nanos max() const { return max_.load(std::memory_order_relaxed); }
  double mean() const;
  // Smallest bucket upper bound below which at least fraction p of the samples lie,
  // clamped to the largest sample seen. 0 when empty.
  Nanos percentile(double p) const;

  // Merges another histogram in (reports only, not the real-time path).
  void merge(const Histogram& other);

  static int bucket_of(Nanos value);
  static Nanos bucket_upper(int bucket);

 private:
  void bump(std::atomic<std::uint64_t>& a, std::uint64_t by = 1) {
    a.store(a.load(std::memory_order_relaxed) + by, std::memory_order_relaxed);
  }
  std::array<std::atomic<std::uint64_t>, kBuckets> buckets_{};
  std::atomic<std::uint64_t> count_{0};
  std::atomic<std::uint64_t> sum_{0};
  std::atomic<Nanos> min_{std::numeric_limits<Nanos>::max()};
  std::atomic<Nanos> max_{0};
};

}  // namespace markcell::control
