// libFuzzer target: the defects-file reader (CSV and ASCII PLY) on arbitrary text. Every
// input must end in clusters within their limits or a DefectsInvalid naming the file,
// never a crash, a hang or another exception.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "markcell/control/marking.hpp"
#include "markcell/host/defects_file.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  markcell::host::ScannerVolume v;
  v.fx = v.fy = 2000;
  v.cx = 696;
  v.cy = 520;
  v.width = 1392;
  v.height = 1040;
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    const auto clusters = markcell::host::parse_defects(text, "fuzz.csv", v, 1);
    if (clusters.size() > static_cast<std::size_t>(markcell::control::kMaxDefects)) std::abort();
    int last = 0;
    for (const auto& c : clusters) {
      if (c.id <= last || c.points_SL.empty() ||
          c.points_SL.size() > static_cast<std::size_t>(markcell::control::kMaxDefectPoints))
        std::abort();
      last = c.id;
      for (const auto& p : c.points_SL)
        if (!p.allFinite() || p.z() < v.z_min_m || p.z() > v.z_max_m) std::abort();
    }
  } catch (const markcell::host::DefectsInvalid& e) {
    if (std::string(e.what()).rfind("fuzz.csv", 0) != 0) std::abort();  // every error names the file
  }
  return 0;
}
