#pragma once
// A value for one journal line: control characters (a newline would forge a line of its
// own), backslashes and double quotes escaped as \n, \t, \\, \" or \xHH; bytes of 0x80
// and above are kept (UTF-8 names stay readable). Off the real-time path: allocates.
#include <string>
#include <string_view>

namespace markcell {

inline std::string escape_log(std::string_view text) {
  static constexpr char kHex[] = "0123456789abcdef";
  std::string out;
  out.reserve(text.size());
  for (const char c : text) {
    const auto u = static_cast<unsigned char>(c);
    if (c == '\\' || c == '"') {
      out += '\\';
      out += c;
    } else if (c == '\n') {
      out += "\\n";
    } else if (c == '\t') {
      out += "\\t";
    } else if (c == '\r') {
      out += "\\r";
    } else if (u < 0x20 || u == 0x7f) {
      out += "\\x";
      out += kHex[u >> 4];
      out += kHex[u & 15];
    } else {
      out += c;
    }
  }
  return out;
}

}  // namespace markcell
