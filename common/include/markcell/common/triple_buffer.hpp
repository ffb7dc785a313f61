#pragma once
// Wait-free single-writer / single-reader triple buffer: how tasks pass data across
// lanes. The writer never waits for the reader and the reader never waits for the
// writer; neither takes a lock nor allocates. The reader always sees the latest
// complete value (or the previous one it already had), never a torn one.
#include <array>
#include <atomic>
#include <cstdint>
#include <type_traits>

namespace markcell {

template <typename T>
class TripleBuffer {
  // T is copied on the real-time path: no type that owns heap memory (std::string,
  // std::vector) may pass. Fixed-size Eigen types qualify though Eigen does not declare
  // their copies noexcept.
  static_assert(std::is_trivially_destructible_v<T> && std::is_copy_assignable_v<T>,
                "T is copied on the real-time path and must not own heap memory");

 public:
  TripleBuffer() = default;
  explicit TripleBuffer(const T& initial) { slots_.fill(initial); }

  // Writer side: fill the back slot in place, then publish it.
  T& write_slot() { return slots_[back_]; }
  void publish() {
    // Swap the back slot with the middle one and mark the middle as fresh.
    const std::uint8_t old = middle_.exchange(static_cast<std::uint8_t>(back_ | kFresh),
                                              std::memory_order_acq_rel);
    back_ = old & kIndexMask;
  }
  void write(const T& value) {
    write_slot() = value;
    publish();
  }

  // Reader side: take the newest published value if there is one. Returns true when the
  // value changed since the last read.
  bool update() {
    if ((middle_.load(std::memory_order_relaxed) & kFresh) == 0) return false;
    const std::uint8_t old = middle_.exchange(front_, std::memory_order_acq_rel);
    front_ = old & kIndexMask;
    return true;
  }
  const T& read() const { return slots_[front_]; }

 private:
  static constexpr std::uint8_t kFresh = 0x4;
  static constexpr std::uint8_t kIndexMask = 0x3;
  std::array<T, 3> slots_{};
  std::uint8_t back_ = 0;               // writer's own
  std::atomic<std::uint8_t> middle_{1}; // shared: index | fresh flag
  std::uint8_t front_ = 2;              // reader's own
};

}  // namespace markcell
