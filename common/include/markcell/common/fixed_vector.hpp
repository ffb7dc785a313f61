#pragma once
// A vector with its capacity fixed at compile time (PX4's containers/Array.hpp): the
// elements live inside the object, so filling it never allocates and its size is part
// of it, not an `int count` beside a std::array. Adding past the capacity does not
// write: push_back returns false and the overflow flag stays set until clear(), so a
// record that did not fit says so instead of losing its tail silently.
#include <algorithm>
#include <array>
#include <cassert>
#include <cstddef>


namespace markcell {

template <typename T, std::size_t Capacity>
class FixedVector {
 public:
  using value_type = T;
  using iterator = T*;
  using const_iterator = const T*;

  static constexpr std::size_t capacity() { return Capacity; }
  std::size_t size() const { return size_; }
  int ssize() const { return static_cast<int>(size_); }
  bool empty() const { return size_ == 0; }
  bool full() const { return size_ == Capacity; }
  // An element was refused for want of room since the last clear().
  bool overflowed() const { return overflowed_; }

  // False (and nothing written, overflowed() set) when full.
  bool push_back(const T& value) {
    if (size_ == Capacity) {
      overflowed_ = true;
      return false;
    }
    items_[size_++] = value;
    return true;
  }
  // The next element, value-initialised, or nullptr (overflowed() set) when full.
  T* emplace_back() {
    if (size_ == Capacity) {
      overflowed_ = true;
      return nullptr;
    }
    items_[size_] = T{};
    return &items_[size_++];
  }
  void clear() {
    size_ = 0;
    overflowed_ = false;
  }
  // Keeps the first n (n <= size()).
  void truncate(std::size_t n) { size_ = std::min(n, size_); }

  // Past size() is a logic error, asserted in the checked builds (the real-time path
  // cannot throw: a throw allocates).
  T& operator[](std::size_t i) {
    assert(i < size_);
    return items_[i];
  }
  const T& operator[](std::size_t i) const {
    assert(i < size_);
    return items_[i];
  }
  T& back() { return (*this)[size_ - 1]; }
  const T& back() const { return (*this)[size_ - 1]; }

  T* begin() { return items_.data(); }
  T* end() { return items_.data() + size_; }
  const T* begin() const { return items_.data(); }
  const T* end() const { return items_.data() + size_; }
  T* data() { return items_.data(); }
  const T* data() const { return items_.data(); }

 private:
  std::array<T, Capacity> items_{};
  std::size_t size_ = 0;
  bool overflowed_ = false;
};

}  // namespace markcell
