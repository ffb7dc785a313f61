// `markcell bench render`: the rig's renderer per 640x480 stereo pair (or whatever the
// configured calibration's size), on one core, for the shipped door's mesh and for the
// same door subdivided to over 200k triangles (a CAD export's density), along the
// paper-door scenario's travel. The two meshes describe the same surface, so their images
// must agree (the largest grey difference is printed): the cost of the triangle count
// alone is what the two medians differ by.
#include <algorithm>
#include <cstdio>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <vector>

#include <opencv2/core/utility.hpp>

#include "markcell/rig/line_motion.hpp"
#include "markcell/rig/panel.hpp"
#include "markcell/rig/render.hpp"
#include "markcell/rig/scenario.hpp"
#include "markcell/tools/bench.hpp"
#include "sample_percentile.hpp"

namespace markcell::host {

namespace {

// Each triangle into four through its edges' midpoints (shared midpoints shared): the
// same surface, four times the triangles.
rig::TriangleMesh subdivide(const rig::TriangleMesh& in) {
  rig::TriangleMesh out;
  out.vertices = in.vertices;
  std::map<std::pair<std::uint32_t, std::uint32_t>, std::uint32_t> midpoint;
  const auto mid = [&](std::uint32_t a, std::uint32_t b) {
    const auto key = std::minmax(a, b);
    const auto [it, added] = midpoint.emplace(std::pair{key.first, key.second}, static_cast<std::uint32_t>(out.vertices.size()));
    if (added) out.vertices.push_back(0.5 * (in.vertices[a] + in.vertices[b]));
    return it->second;
  };
  for (const auto& t : in.triangles) {
    const std::uint32_t ab = mid(t[0], t[1]), bc = mid(t[1], t[2]), ca = mid(t[2], t[0]);
    out.triangles.push_back({t[0], ab, ca});
    out.triangles.push_back({ab, t[1], bc});
    out.triangles.push_back({ca, bc, t[2]});
    out.triangles.push_back({ab, bc, ca});
  }
  return out;
}

struct Timing {
  double median = 0, p99 = 0;
};
}  // namespace

int bench_render(const CellConfig& config, const RenderBenchOptions& options) {
  cv::setNumThreads(1);
  const auto calibration = vision::load_stereo_calibration(config.calibration.stereo);
  const rig::Scenario scenario = rig::find_scenario("paper-door", rig::scenario_folder(config.file), 1);
  const rig::Panel shipped = rig::configured_panel(config.panel_types, scenario.panel_type);
  rig::Panel fine = shipped;
  rig::TriangleMesh mesh = shipped.surface->mesh();
  while (mesh.triangles.size() < 200'000) mesh = subdivide(mesh);
  fine.surface = std::make_shared<const rig::MeshSurface>(std::move(mesh));
  const rig::LineMotion motion(scenario.speed, scenario.path, scenario.duration);
  rig::RenderSettings settings;
  settings.threads = 1;
  const rig::StereoRenderer renderer(calibration, settings);

  // Poses spread over the part of the travel where the panel is in view.
  std::vector<Eigen::Isometry3d> poses;
  for (int i = 0; i < options.pairs; ++i)
    poses.push_back(motion.X_CamR_Panel(scenario.duration / 4 + scenario.duration / 2 * i / std::max(1, options.pairs - 1)));
  const auto time = [&](const rig::Panel& panel, std::vector<cv::Mat>& lefts) {
    std::vector<double> ms;
    cv::Mat right;
    for (std::size_t i = 0; i < poses.size(); ++i) {
      const Nanos t0 = monotonic_now();
      renderer.render(panel, poses[i], 1.0, 1000 + i, {}, lefts[i], right);
      ms.push_back(to_seconds(monotonic_now() - t0) * 1e3);
    }
    return Timing{sample_percentile(ms, 0.5), sample_percentile(ms, 0.99)};
  };
  std::vector<cv::Mat> shipped_left(poses.size()), fine_left(poses.size());
  const Timing a = time(shipped, shipped_left);
  const Timing b = time(fine, fine_left);
  double worst = 0;
  for (std::size_t i = 0; i < poses.size(); ++i) worst = std::max(worst, cv::norm(shipped_left[i], fine_left[i], cv::NORM_INF));
  std::printf("renderer per stereo pair, %dx%d, %zu pairs of paper-door's travel, one core:\n", calibration.left.width,
              calibration.left.height, poses.size());
  std::printf("  shipped door mesh, %7zu triangles  median %.2f ms  p99 %.2f ms\n", shipped.surface->mesh().triangles.size(),
              a.median, a.p99);
  std::printf("  door subdivided,   %7zu triangles  median %.2f ms  p99 %.2f ms  (ratio of medians %.2f)\n",
              fine.surface->mesh().triangles.size(), b.median, b.p99, b.median / a.median);
  std::printf("  largest grey difference between the two meshes' left images: %.0f\n", worst);
  if (!options.json_path.empty()) {
    std::ofstream out(options.json_path);
    const nlohmann::ordered_json doc{
        {"pairs", poses.size()},
        {"width", calibration.left.width},
        {"height", calibration.left.height},
        {"shipped", {{"triangles", shipped.surface->mesh().triangles.size()}, {"median_ms", a.median}, {"p99_ms", a.p99}}},
        {"subdivided", {{"triangles", fine.surface->mesh().triangles.size()}, {"median_ms", b.median}, {"p99_ms", b.p99}}},
        {"largest_grey_difference", worst}};
    out << doc.dump(2) << "\n";
  }
  return 0;
}

}  // namespace markcell::host
