#include "markcell/tools/panel_type_report.hpp"

#include <cstdio>
#include <iostream>

namespace markcell::host {

void print_panel_type(const vision::PanelTypeModel& model, const std::vector<Eigen::Vector2d>& given, const std::string& out) {
  std::cout << "panel type '" << model.name << "': " << model.count() << " macro-features\n";
  for (int i = 0; i < model.count(); ++i) {
    const auto& mf = model.mfs[static_cast<std::size_t>(i)];
    const Eigen::Vector2d& p = mf.reference_px;
    std::printf("  MF %2d %-6s at (%.2f, %.2f) px", i + 1, std::string(vision::to_string(mf.kind)).c_str(), p.x(), p.y());
    if (mf.kind == vision::MfKind::kHole) std::printf(", radius %.2f px", mf.hole_radius_px);
    // How far each MF moved from the position given (snapped, then refined).
    if (static_cast<std::size_t>(i) < given.size())
      std::printf(", %.2f px from (%.2f, %.2f)", (p - given[static_cast<std::size_t>(i)]).norm(),
                  given[static_cast<std::size_t>(i)].x(), given[static_cast<std::size_t>(i)].y());
    std::printf("\n");
  }
  std::cout << "wrote " << out << "\n";
}

}  // namespace markcell::host
