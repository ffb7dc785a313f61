#include "markcell/control/histogram.hpp"

#include <bit>

namespace markcell::control {

int Histogram::bucket_of(Nanos value) {
  if (value < kSub) return value < 0 ? 0 : static_cast<int>(value);
  const auto v = static_cast<std::uint64_t>(value);
  const int msb = 63 - std::countl_zero(v);          // >= kSubBits
  const int shift = msb - kSubBits;
  const int sub = static_cast<int>((v >> shift) & (kSub - 1));
  return (shift + 1) * kSub + sub;
}

Nanos Histogram::bucket_upper(int bucket) {
  if (bucket < kSub) return bucket;
  const int shift = bucket / kSub - 1;
  const std::uint64_t sub = static_cast<std::uint64_t>(bucket % kSub) | kSub;
  const std::uint64_t upper = ((sub + 1) << shift) - 1;
  return upper > static_cast<std::uint64_t>(std::numeric_limits<Nanos>::max())
             ? std::numeric_limits<Nanos>::max()
             : static_cast<Nanos>(upper);
}

void Histogram::record(Nanos value) {
  if (value < 0) value = 0;
  bump(buckets_[static_cast<std::size_t>(bucket_of(value))]);
  bump(count_);
  bump(sum_, static_cast<std::uint64_t>(value));
  if (value < min_.load(std::memory_order_relaxed)) min_.store(value, std::memory_order_relaxed);
  if (value > max_.load(std::memory_order_relaxed)) max_.store(value, std::memory_order_relaxed);
}

void Histogram::reset() {
  for (auto& b : buckets_) b.store(0, std::memory_order_relaxed);
  count_.store(0, std::memory_order_relaxed);
  sum_.store(0, std::memory_order_relaxed);
  min_.store(std::numeric_limits<Nanos>::max(), std::memory_order_relaxed);
  max_.store(0, std::memory_order_relaxed);
}

Nanos Histogram::min() const { return count() == 0 ? 0 : min_.load(std::memory_order_relaxed); }

double Histogram::mean() const {
  const auto n = count();
  return n == 0 ? 0.0 : static_cast<double>(sum_.load(std::memory_order_relaxed)) / static_cast<double>(n);
}

Nanos Histogram::percentile(double p) const {
  const auto n = count();
  if (n == 0) return 0;
  // The rank of the sample, 1-based: at least ceil(p * n) samples at or below it.
  auto rank = static_cast<std::uint64_t>(p * static_cast<double>(n));
  if (static_cast<double>(rank) < p * static_cast<double>(n)) ++rank;
  if (rank < 1) rank = 1;
  std::uint64_t seen = 0;
  for (int b = 0; b < kBuckets; ++b) {
    seen += buckets_[static_cast<std::size_t>(b)].load(std::memory_order_relaxed);
    if (seen >= rank) {
      const Nanos upper = bucket_upper(b);
      return upper < max() ? upper : max();
    }
  }
  return max();
}

void Histogram::merge(const Histogram& other) {
  for (int b = 0; b < kBuckets; ++b)
    bump(buckets_[static_cast<std::size_t>(b)], other.buckets_[static_cast<std::size_t>(b)].load(std::memory_order_relaxed));
  bump(count_, other.count());
  bump(sum_, other.sum_.load(std::memory_order_relaxed));
  if (other.count() > 0) {
    if (other.min() < min_.load(std::memory_order_relaxed)) min_.store(other.min(), std::memory_order_relaxed);
    if (other.max() > max_.load(std::memory_order_relaxed)) max_.store(other.max(), std::memory_order_relaxed);
  }
}

}  // namespace markcell::control
