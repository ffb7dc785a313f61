#pragma once
// The few JSON helpers the report and the results file share: a quoted string (quotes
// and backslashes escaped, control characters dropped) and a number with fixed digits
// (the same value always prints the same bytes; not finite: null).
#include <cmath>
#include <cstdio>
#include <string>
#include <string_view>

namespace markcell::host {

inline std::string json_quote(std::string_view s) {
  std::string out = "\"";
  for (const char c : s) {
    if (c == '"' || c == '\\') out += '\\';
    if (static_cast<unsigned char>(c) >= 0x20) out += c;
  }
  return out + "\"";
}

inline std::string json_number(double v, int digits) {
  if (!std::isfinite(v)) return "null";
  char b[64];
  std::snprintf(b, sizeof b, "%.*f", digits, v);
  return b;
}

}  // namespace markcell::host
