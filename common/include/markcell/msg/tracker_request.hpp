#pragma once
// The marking task's message to the vision lane: search anew, which panel type, the MFs'
// positions in P the tracker has not measured itself, and the panel's record for the
// vision lane's fits. A leaf, as msg/pose_estimate.hpp.
#include <array>
#include <cstdint>

#include <Eigen/Geometry>

#include "markcell/common/fixed_vector.hpp"
#include "markcell/msg/pose_estimate.hpp"

namespace markcell::msg {

struct TrackerRequest {
  std::uint32_t reset_serial = 0;      // a change asks for a new search
  int panel_type = 0;                  // of this panel type
  std::uint32_t reference_serial = 0;  // the tracker's P these positions belong to
  // Changes with every new set of positions: each refit of the inter-calibration places
  // the MFs the tracker has not measured itself again, more surely than the last (the
  // first fit levers its few MFs' noise out to the far ones by more than the tracker's
  // re-acquisition accepts).
  std::uint32_t placement_serial = 0;
  std::array<Eigen::Vector3d, kMaxMacroFeatures> reference_P{};
  std::array<bool, kMaxMacroFeatures> known{};
  // The panel's record as the vision lane needs it to fit each pose to it (PoseFits):
  // which job (0: none), and the record's MFs in the scanner's frame.
  std::uint32_t job_serial = 0;
  FixedVector<Eigen::Vector3d, kMaxMacroFeatures> mfs_SL;
};

}  // namespace markcell::msg
