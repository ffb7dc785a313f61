#pragma once
// The inspection station's record of one panel, as it reaches the cell (a YAML file in
// the drop folder; format in vision/RECORDING.md, "inspection.yaml"), validated field by
// field into the fixed-size job the marking sequence takes. A bad record is rejected
// whole, with the file, line and field of the first problem; it is never half-used.
#include <stdexcept>
#include <string>
#include <vector>

#include "markcell/control/marking.hpp"
#include "markcell/host/config.hpp"

namespace markcell::host {

class RecordInvalid : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

control::PanelJob read_inspection_record(const std::string& path, const std::vector<PanelTypeConfig>& panel_types);
control::PanelJob parse_inspection_record(const std::string& text, const std::string& path,
                                          const std::vector<PanelTypeConfig>& panel_types);

}  // namespace markcell::host
