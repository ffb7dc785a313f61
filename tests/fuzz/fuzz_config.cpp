// libFuzzer target: the cell configuration loader on arbitrary text. Every input must
// end in a valid configuration or a list of errors, never a crash or another exception.
#include <cstdint>
#include <cstdlib>
#include <string>

#include "markcell/common/check.hpp"
#include "markcell/host/cell.hpp"
#include "markcell/host/config.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    const auto errors = markcell::host::check_config_text(text, "/nonexistent/fuzz.yaml", markcell::host::task_catalog());
    for (const auto& e : errors)
      if (e.message.empty()) std::abort();
  } catch (const markcell::CheckFailed&) {
    std::abort();  // the loader accepted what the executive then refused: they disagree
  }
  return 0;
}
