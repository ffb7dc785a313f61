#pragma once
// A fixed-capacity string for records made on the real-time path (fault reasons, log
// lines): copying into it never allocates and silently truncates at capacity.
#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdio>
#include <string_view>

namespace markcell {

template <std::size_t Capacity>
class FixedString {
 public:
  FixedString() = default;
  FixedString(std::string_view s) { assign(s); }  // NOLINT: implicit by design

  void assign(std::string_view s) {
    size_ = std::min(s.size(), Capacity);
    std::copy_n(s.data(), size_, data_.data());
    data_[size_] = '\0';
  }
  // printf-style formatting into the fixed storage (vsnprintf does not allocate).
  template <typename... Args>
  void format(const char* fmt, Args... args) {
    const int n = std::snprintf(data_.data(), Capacity + 1, fmt, args...);
    size_ = n < 0 ? 0 : std::min(static_cast<std::size_t>(n), Capacity);
  }
  std::string_view view() const { return {data_.data(), size_}; }
  const char* c_str() const { return data_.data(); }
  std::size_t size() const { return size_; }
  bool empty() const { return size_ == 0; }
  static constexpr std::size_t capacity() { return Capacity; }

 private:
  std::array<char, Capacity + 1> data_{};
  std::size_t size_ = 0;
};

}  // namespace markcell
