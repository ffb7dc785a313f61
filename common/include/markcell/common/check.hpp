#pragma once
// Start-up checks in the spirit of Drake's DRAKE_THROW_UNLESS: the message names the
// condition that failed and where, plus any values the caller adds. These throw, so they
// belong to configuration and start-up; the real-time path reports enums instead.
#include <sstream>
#include <stdexcept>
#include <string>

namespace markcell {

class CheckFailed : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

namespace detail {
[[noreturn]] inline void throw_check(const char* condition, const char* file, int line,
                                     const std::string& detail) {
  std::ostringstream os;
  os << file << ":" << line << ": check failed: " << condition;
  if (!detail.empty()) os << " (" << detail << ")";
  throw CheckFailed(os.str());
}
}  // namespace detail

}  // namespace markcell

// MARKCELL_THROW_UNLESS(cond) or MARKCELL_THROW_UNLESS(cond, "x=" << x << " y=" << y)
#define MARKCELL_THROW_UNLESS(cond, ...)                                              \
  do {                                                                                \
    if (!(cond)) {                                                                    \
      std::ostringstream markcell_check_os_;                                          \
      markcell_check_os_ << "" __VA_OPT__(<< __VA_ARGS__);                            \
      ::markcell::detail::throw_check(#cond, __FILE__, __LINE__, markcell_check_os_.str()); \
    }                                                                                 \
  } while (false)
