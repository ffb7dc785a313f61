#include "markcell/rig/panel.hpp"

#include <cmath>
#include <filesystem>
#include <stdexcept>

#include <opencv2/core.hpp>

#include "markcell/common/confined_path.hpp"
#include "markcell/vision/calibration_io.hpp"

namespace markcell::rig {

Eigen::Vector3d Panel::surface_point(double x, double y) const {
  const MeshHit h = surface->from_front(x, y);
  if (!h.hit())
    throw std::invalid_argument("panel '" + name + "': no surface at (" + std::to_string(x) + ", " + std::to_string(y) +
                                ") m: a hole, a cut-out or off the panel");
  return h.p;
}

Eigen::Vector3d Panel::normal(double x, double y) const {
  const MeshHit h = surface->from_front(x, y);
  if (!h.hit())
    throw std::invalid_argument("panel '" + name + "': no surface at (" + std::to_string(x) + ", " + std::to_string(y) + ") m");
  return h.normal;
}

Panel load_panel_mesh(const std::string& name, const std::string& mesh_file, double metres_per_unit) {
  Panel p;
  p.name = name;
  p.mesh_file = mesh_file;
  p.mesh_metres_per_unit = metres_per_unit;
  p.surface = std::make_shared<const MeshSurface>(load_mesh(mesh_file, metres_per_unit));
  return p;
}

Panel load_panel(const std::string& path) {
  // The same bound as the tracker's reader of this file (vision/panel_tracker.cpp).
  cv::FileStorage fs = vision::open_yaml_storage(path, 4 << 20, "a panel-type file");
  const auto need = [&](const char* key, const char* what) {
    const cv::FileNode n = fs[key];
    if (n.empty()) throw std::runtime_error(path + ": missing key '" + key + "' (" + what + ")");
    return n;
  };
  const std::string name = static_cast<std::string>(need("panel_type", "the panel type's name"));
  const std::string mesh = static_cast<std::string>(need("mesh", "the rig's surface of the panel: a mesh file beside it"));
  const double unit = static_cast<double>(need("mesh_metres_per_unit", "the mesh's unit in metres"));
  if (!(unit > 0) || !std::isfinite(unit) || unit > 1000)
    throw std::runtime_error(path + ": mesh_metres_per_unit must be in (0, 1000], not " + std::to_string(unit));
  const std::filesystem::path folder = std::filesystem::path(path).parent_path();
  if (const std::string why = confined_problem(folder.empty() ? "." : folder, mesh, "the panel-type file's folder",
                                               "a mesh is named relative to the panel-type file");
      !why.empty())
    throw std::runtime_error(path + ": mesh: '" + mesh + "' " + why);
  Panel p = load_panel_mesh(name, (folder / mesh).string(), unit);
  cv::Mat mfs;
  need("macro_features_panel", "each macro-feature's position on the panel, metres") >> mfs;
  if (mfs.cols != 3 || mfs.rows < 3 || mfs.type() != CV_64F)
    throw std::runtime_error(path + ": macro_features_panel must be an Nx3 double matrix (metres), N >= 3");
  // A hole MF (the tracker's `kinds`) is the centre of a hole: no material there, its rim
  // around it (a hole the tracker can follow is at most about 16 mm in radius).
  const cv::FileNode kinds = fs["kinds"];
  const auto is_hole = [&](int i) {
    return kinds.isSeq() && i < static_cast<int>(kinds.size()) && kinds[i].isString() && static_cast<std::string>(kinds[i]) == "hole";
  };
  constexpr double kHoleRimMax = 0.03;
  for (int i = 0; i < mfs.rows; ++i) {
    const Eigen::Vector3d m(mfs.at<double>(i, 0), mfs.at<double>(i, 1), mfs.at<double>(i, 2));
    // An MF is a point of the surface: on a corner or a rim the vertical ray may just miss,
    // so the nearest vertex is the reference.
    double nearest = 1e9;
    for (const auto& v : p.surface->mesh().vertices) nearest = std::min(nearest, (v - m).norm());
    if (is_hole(i)) {
      if (!m.allFinite() || p.solid(m.x(), m.y()) || nearest > kHoleRimMax)
        throw std::runtime_error(path + ": macro_features_panel row " + std::to_string(i + 1) + " (" + std::to_string(m.x()) +
                                 ", " + std::to_string(m.y()) + ", " + std::to_string(m.z()) + ") is a hole's centre (kinds) but " +
                                 (p.solid(m.x(), m.y()) ? std::string("the mesh has material there")
                                                        : "its nearest vertex is " + std::to_string(nearest * 1000) +
                                                              " mm away: no hole's rim around it"));
      p.macro_features.push_back(m);
      continue;
    }
    if (!m.allFinite() || nearest > 1e-3)
      throw std::runtime_error(path + ": macro_features_panel row " + std::to_string(i + 1) + " (" + std::to_string(m.x()) + ", " +
                               std::to_string(m.y()) + ", " + std::to_string(m.z()) + ") is " + std::to_string(nearest * 1000) +
                               " mm from the mesh's nearest vertex: not on the panel (units must be metres)");
    p.macro_features.push_back(m);
  }
  return p;
}

Panel configured_panel(const std::vector<host::PanelTypeConfig>& panel_types, const std::string& type) {
  std::string known;
  for (const auto& t : panel_types) {
    if (t.name == type) return load_panel(t.file);
    known += (known.empty() ? "" : ", ") + t.name;
  }
  throw std::runtime_error("panel type '" + type + "' is not configured in panel_types (configured: " + known + ")");
}

}  // namespace markcell::rig
