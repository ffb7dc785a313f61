#pragma once
// A panel as the rig knows it: its surface (a mesh, panel_mesh.hpp) and where its
// macro-features truly are, read from the panel type's files. The panel frame: origin at
// the panel's centre, x along its width (the direction of travel), y along its height
// (up), z out of the surface towards the cameras.
//
// A panel-type file (config/panels/NAME.yaml, made by `markcell select-mfs`) names, for
// the rig, beside the tracker's reference MFs and templates:
//   mesh: door.ply                   the surface, relative to the file's folder, inside it
//   mesh_metres_per_unit: 1.         0.001 for a CAD export in millimetres
//   macro_features_panel: Nx3        each MF's true position in the panel frame, metres
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "markcell/host/config.hpp"
#include "markcell/rig/panel_mesh.hpp"

namespace markcell::rig {

struct Panel {
  std::string name;
  std::shared_ptr<const MeshSurface> surface;
  // The macro-features' true positions, panel frame; empty when the source gives none (a
  // recording's mesh alone).
  std::vector<Eigen::Vector3d> macro_features;
  // Where the surface was read from, and its unit (sim copies it into the recording).
  std::string mesh_file;
  double mesh_metres_per_unit = 1.0;

  // The front face at (x, y), seen from +z: the surface point there, its unit normal.
  // Throws std::invalid_argument naming the panel and (x, y) over a hole or off the panel.
  Eigen::Vector3d surface_point(double x, double y) const;
  Eigen::Vector3d normal(double x, double y) const;
  // True when (x, y) is panel material seen from the front.
  bool solid(double x, double y) const { return surface->from_front(x, y).hit(); }
};

// Where the ray o + t d (panel frame, t > 0) first meets the panel: the distance t in
// units of |d|, or a negative value.
inline double intersect_panel(const Panel& panel, const Eigen::Vector3d& o_Panel, const Eigen::Vector3d& d_Panel) {
  return panel.surface->intersect(o_Panel, d_Panel).t;
}

// The panel of a panel-type file (the keys above). Throws std::runtime_error naming the
// file and the key: a missing key, a mesh outside the file's folder or unreadable, an MF
// that is not on the mesh's surface (further than 1 mm from it).
Panel load_panel(const std::string& panel_type_file);

// A panel's surface alone (a recording's `panel_mesh`): no macro-features.
Panel load_panel_mesh(const std::string& name, const std::string& mesh_file, double metres_per_unit);

// The configured panel type `type` (config `panel_types`), read with load_panel. Throws
// std::runtime_error naming the type and the configured ones when it is not configured.
Panel configured_panel(const std::vector<host::PanelTypeConfig>& panel_types, const std::string& type);

}  // namespace markcell::rig
