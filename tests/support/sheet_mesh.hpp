#pragma once
// Meshes of bent sheets with rectangular cut-outs and round holes, made in the tests (and
// once, for config/panels/, the door's and the fender's): surfaces with a closed form, so
// a test can check the mesh renderer and the scorer against exact intersections.
//
// The sheet: z = -bend_x x^2 - bend_y y^2 over [-w/2, w/2] x [-h/2, h/2] in the panel
// frame. The mesh: a grid of `spacing` with lines also on every cut-out's edges, the cells
// of the cut-outs left out; around each hole a square box of grid lines whose boundary is
// joined to a polygon of at least 64 points on the hole's rim. Every vertex lies on the
// surface, no vertex sits on another triangle's edge (no T-junctions), and triangles face +z.
#include <vector>

#include <Eigen/Core>

#include "markcell/rig/panel.hpp"
#include "markcell/rig/panel_mesh.hpp"

namespace markcell::test {

struct SheetSpec {
  struct Rect {
    double x0, y0, x1, y1;
  };
  struct Hole {
    double x, y, radius;
  };
  double width = 1.0, height = 0.7;
  double bend_x = 0.0, bend_y = 0.0;  // 1/m
  std::vector<Rect> cutouts;
  std::vector<Hole> holes;
  double spacing = 0.01;  // metres between grid lines

  double z(double x, double y) const { return -bend_x * x * x - bend_y * y * y; }
  Eigen::Vector3d point(double x, double y) const { return {x, y, z(x, y)}; }
  Eigen::Vector3d normal(double x, double y) const { return Eigen::Vector3d(2 * bend_x * x, 2 * bend_y * y, 1).normalized(); }
  // Panel material at (x, y): inside the outline, outside every cut-out and hole.
  bool solid(double x, double y) const;
  // The closed form: where o + t d first meets the sheet's surface (t > 0) on material,
  // or -1. The quadratic in t of o + t d on z = -bx x^2 - by y^2.
  double intersect(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const;
};

rig::TriangleMesh sheet_mesh(const SheetSpec& spec);

// The shapes the shipped config/panels/door.ply and fender.ply were made from (the rig's
// parametric panels until meshes replaced them), and their macro-features' corners.
SheetSpec door_sheet();
SheetSpec fender_sheet();
std::vector<Eigen::Vector3d> door_sheet_corners();
std::vector<Eigen::Vector3d> fender_sheet_corners();

// A panel of a sheet made here (its mesh in memory), with `macro_features` as given.
rig::Panel sheet_panel(const std::string& name, const SheetSpec& spec, std::vector<Eigen::Vector3d> macro_features);
// The shipped panel type `name`: config/panels/NAME.yaml and its mesh.
rig::Panel shipped_panel(const std::string& name);

}  // namespace markcell::test
