#pragma once
// `markcell record`: live stereo pairs from the configured Aravis cameras written as a
// recording (vision/RECORDING.md), the same format the rig replays. Off the real-time
// path: a commissioning and regression tool.
#include <iosfwd>
#include <string>

#include "markcell/drivers/camera.hpp"
#include "markcell/host/config.hpp"

namespace markcell::host {

struct RecordOptions {
  std::string out;          // the recording folder (must not hold one already)
  std::string panel_type;   // written to the manifest
  int frames = 100;         // stereo pairs to keep
  std::string left_id, right_id;  // override the configuration's camera ids (empty: theirs)
};

struct RecordSummary {
  int pairs = 0;            // written
  int timeouts = 0;         // waits with no pair (each bounded)
  std::uint64_t unpaired = 0;  // frames dropped for want of a partner
};

// Throws std::runtime_error naming the camera or file when it cannot go on (a camera
// that cannot be opened or is lost, a folder that already holds a recording).
RecordSummary record_stereo(const CellConfig& config, const RecordOptions& options, std::ostream* progress);

}  // namespace markcell::host
