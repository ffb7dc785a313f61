// `markcell bench vision`: the vision task's work per stereo pair (pyramids, tracking in
// both views, triangulation, the robust pose) against the floor of OpenCV building the
// same two pyramids with cv::buildOpticalFlowPyramid, in one run, single-threaded.
#include <algorithm>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <vector>

#include <opencv2/core/utility.hpp>
#include <opencv2/video/tracking.hpp>

#include "markcell/tools/bench.hpp"
#include "sample_percentile.hpp"
#include "markcell/rig/line_motion.hpp"
#include "markcell/rig/scenario.hpp"
#include "markcell/vision/panel_tracker.hpp"
#include "markcell/rig/panel.hpp"
#include "markcell/rig/render.hpp"

namespace markcell::host {

int bench_vision(const CellConfig& config, const VisionBenchOptions& options) {
  cv::setNumThreads(1);  // one core for both: OpenCV would otherwise spread over the machine
  const auto calibration = vision::load_stereo_calibration(config.calibration.stereo);
  const rig::Scenario scenario = rig::find_scenario(options.scenario, rig::scenario_folder(config.file), 1);
  const rig::Panel panel = rig::configured_panel(config.panel_types, scenario.panel_type);
  const rig::LineMotion motion(scenario.speed, scenario.path, scenario.duration);
  const rig::StereoRenderer renderer(calibration, rig::RenderSettings{});
  const vision::StereoRig rig(calibration);
  std::string type_file;
  for (const auto& p : config.panel_types)
    if (p.name == scenario.panel_type) type_file = p.file;
  if (type_file.empty()) {
    std::fprintf(stderr, "markcell bench vision: panel type '%s' has no file in %s\n", scenario.panel_type.c_str(), config.file.c_str());
    return 2;
  }
  const vision::PanelTypeModel model = vision::load_panel_type(type_file);
  const vision::TrackerParams& params = config.vision;
  vision::PanelTracker tracker(rig, model, params);

  // The frames are rendered ahead (not timed), in a ring the length of the run.
  std::fprintf(stderr, "markcell bench vision: rendering %d stereo pairs of %s ...\n", options.frames, options.scenario.c_str());
  std::vector<cv::Mat> left(static_cast<std::size_t>(options.frames)), right(static_cast<std::size_t>(options.frames));
  const double fps = 30.0;
  for (int i = 0; i < options.frames; ++i) {
    const Nanos t = static_cast<Nanos>(static_cast<double>(i) * 1e9 / fps) % scenario.duration;
    renderer.render(panel, motion.X_CamR_Panel(t), 1.0, 1000 + static_cast<std::uint64_t>(i), {}, left[static_cast<std::size_t>(i)],
                    right[static_cast<std::size_t>(i)]);
  }
  std::vector<double> ours, floor;
  int poses = 0, mfs = 0, reinits = 0;
  std::vector<cv::Mat> pyr_l, pyr_r;
  for (int i = 0; i < options.frames; ++i) {
    const auto k = static_cast<std::size_t>(i);
    const Nanos t0 = monotonic_now();
    const msg::PoseEstimate& e = tracker.process(k, static_cast<Nanos>(static_cast<double>(i) * 1e9 / fps), left[k], right[k]);
    const Nanos t1 = monotonic_now();
    cv::buildOpticalFlowPyramid(left[k], pyr_l, cv::Size(2 * params.lk.radius + 1, 2 * params.lk.radius + 1),
                                params.pyramid_levels - 1);
    cv::buildOpticalFlowPyramid(right[k], pyr_r, cv::Size(2 * params.lk.radius + 1, 2 * params.lk.radius + 1),
                                params.pyramid_levels - 1);
    const Nanos t2 = monotonic_now();
    // As in the cell, where the inter-calibration places the MFs the search did not find
    // (here from the rig's truth), so that they are picked up as they come into view.
    if (e.status == msg::TrackStatus::kReinitialised) {
      const Nanos t = static_cast<Nanos>(static_cast<double>(i) * 1e9 / fps) % scenario.duration;
      for (int m = 0; m < model.count(); ++m)
        if (!tracker.reference_known()[static_cast<std::size_t>(m)])
          tracker.set_reference(m, motion.X_CamR_Panel(t) * panel.macro_features[static_cast<std::size_t>(m)]);
      ++reinits;
    }
    if (i == 0) continue;  // the first pair searches for the panel (re-initialisation), timed apart
    ours.push_back(to_seconds(t1 - t0) * 1e3);
    floor.push_back(to_seconds(t2 - t1) * 1e3);
    poses += e.has_pose() ? 1 : 0;
    mfs += e.inliers;
  }
  const double m_ours = sample_percentile(ours, 0.5), p99_ours = sample_percentile(ours, 0.99), max_ours = sample_percentile(ours, 1.0);
  const double m_floor = sample_percentile(floor, 0.5), p99_floor = sample_percentile(floor, 0.99);
  std::printf("vision task per stereo pair, %dx%d, %d MFs (%s), %zu pairs, one thread:\n", rig.width(), rig.height(), model.count(),
              options.scenario.c_str(), ours.size());
  std::printf("  markcell (pyramids + tracking + triangulation + pose)  median %.3f ms  p99 %.3f ms  max %.3f ms\n", m_ours, p99_ours,
              max_ours);
  std::printf("  floor: cv::buildOpticalFlowPyramid x2               median %.3f ms  p99 %.3f ms\n", m_floor, p99_floor);
  std::printf("  ratio of medians %.2f (target <= 2); p99 %.3f ms (target < 5 ms); poses %d of %zu, mean MFs in the pose %.1f, "
              "searches %d\n",
              m_ours / m_floor, p99_ours, poses, ours.size(), static_cast<double>(mfs) / static_cast<double>(ours.size()), reinits);
  if (!options.json_path.empty()) {
    std::ofstream out(options.json_path);
    const nlohmann::ordered_json doc{{"pairs", ours.size()},
                                     {"width", rig.width()},
                                     {"height", rig.height()},
                                     {"macro_features", model.count()},
                                     {"scenario", options.scenario},
                                     {"markcell_ms", {{"median", m_ours}, {"p99", p99_ours}, {"max", max_ours}}},
                                     {"floor_ms", {{"median", m_floor}, {"p99", p99_floor}}},
                                     {"ratio", m_ours / m_floor},
                                     {"poses", poses},
                                     {"searches", reinits}};
    out << doc.dump(2, ' ', false, nlohmann::ordered_json::error_handler_t::replace) << "\n";
  }
  return 0;
}

}  // namespace markcell::host
