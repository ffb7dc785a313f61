#pragma once
// Wait-free single-producer / single-consumer queue of fixed capacity: how a lane hands
// every one of a stream of values (not only the newest, as TripleBuffer does) to a thread
// that is not a lane, e.g. the vision task's pose estimates to the pose log's writer. The
// producer never waits and never allocates: a full queue refuses the value and counts it,
// so a slow writer costs log lines, never a late frame.
#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <type_traits>

namespace markcell {

template <typename T, std::size_t Capacity>
class SpscRing {
  static_assert(Capacity >= 2 && (Capacity & (Capacity - 1)) == 0, "Capacity: a power of two");
  static_assert(std::is_trivially_destructible_v<T> && std::is_copy_assignable_v<T>,
                "T is copied on the real-time path and must not own heap memory");

 public:
  static constexpr std::size_t capacity() { return Capacity; }

  // Producer side. False (nothing written, dropped() counts it) when full.
  bool push(const T& value) noexcept {
    const std::uint64_t head = head_.load(std::memory_order_relaxed);
    if (head - tail_.load(std::memory_order_acquire) >= Capacity) {
      dropped_.fetch_add(1, std::memory_order_relaxed);
      return false;
    }
    slots_[head & (Capacity - 1)] = value;
    head_.store(head + 1, std::memory_order_release);
    return true;
  }

  // Consumer side. False when empty.
  bool pop(T& out) noexcept {
    const std::uint64_t tail = tail_.load(std::memory_order_relaxed);
    if (tail == head_.load(std::memory_order_acquire)) return false;
    out = slots_[tail & (Capacity - 1)];
    tail_.store(tail + 1, std::memory_order_release);
    return true;
  }

  // Values refused because the queue was full, since construction.
  std::uint64_t dropped() const { return dropped_.load(std::memory_order_relaxed); }

 private:
  std::array<T, Capacity> slots_{};
  alignas(64) std::atomic<std::uint64_t> head_{0};  // written by the producer only
  alignas(64) std::atomic<std::uint64_t> tail_{0};  // written by the consumer only
  std::atomic<std::uint64_t> dropped_{0};
};

}  // namespace markcell
