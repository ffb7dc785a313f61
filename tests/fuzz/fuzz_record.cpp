// libFuzzer target: the inspection-record parser on arbitrary text. Every input must end
// in a valid job or a RecordInvalid naming the file, never a crash, a hang or another
// exception; a job it accepts must be within the fixed storage it fills.
#include <cstdint>
#include <cstdlib>
#include <string>

#include "markcell/host/inspection_record.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const std::vector<markcell::host::PanelTypeConfig> types = [] {
    std::vector<markcell::host::PanelTypeConfig> t(2);
    t[0].name = "door";
    t[0].macro_features = 10;
    t[1].name = "fender";
    t[1].macro_features = 4;
    return t;
  }();
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    const markcell::control::PanelJob job = markcell::host::parse_inspection_record(text, "fuzz.yaml", types);
    if (job.defects.overflowed() || job.defects.ssize() > markcell::control::kMaxDefects) std::abort();
    if (job.mfs_SL.ssize() != types[static_cast<std::size_t>(job.panel_type_index)].macro_features) std::abort();
    if (!markcell::host::panel_id_problem(job.panel_id.view()).empty()) std::abort();
  } catch (const markcell::host::RecordInvalid& e) {
    if (std::string(e.what()).rfind("fuzz.yaml", 0) != 0) std::abort();  // every error names the file
  }
  return 0;
}
