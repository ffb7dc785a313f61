#pragma once
// The inspection station's record of one panel, as it reaches the cell (a YAML file in
// the drop folder; format in vision/RECORDING.md, "inspection.yaml"), validated field by
// field into the fixed-size job the marking sequence takes. A bad record is rejected
// whole, with the file, line and field of the first problem; it is never half-used.
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "markcell/control/marking.hpp"
#include "markcell/host/config.hpp"

namespace markcell::host {

class RecordInvalid : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// An inspection record is at most this large (checked before it is read or parsed).
inline constexpr std::size_t kMaxInspectionRecordBytes = 1 << 20;

// What is wrong with a panel id ("" when nothing): 1 to 63 of letters, digits and
// . _ - : / # + (no spaces, no control characters: an id goes into journal lines and
// file names as it is).
std::string panel_id_problem(std::string_view id);

// A record's last line is YAML's end-of-document marker `...`: its writer got to the end.
bool ends_with_end_marker(std::string_view text);

control::PanelJob read_inspection_record(const std::string& path, const std::vector<PanelTypeConfig>& panel_types);
control::PanelJob parse_inspection_record(const std::string& text, const std::string& path,
                                          const std::vector<PanelTypeConfig>& panel_types);

}  // namespace markcell::host
