#include "sheet_mesh.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <numbers>
#include <stdexcept>
#include <string>
#include <utility>

namespace markcell::test {

bool SheetSpec::solid(double x, double y) const {
  if (x < -width / 2 || x > width / 2 || y < -height / 2 || y > height / 2) return false;
  for (const auto& r : cutouts)
    if (x > r.x0 && x < r.x1 && y > r.y0 && y < r.y1) return false;
  for (const auto& h : holes)
    if ((x - h.x) * (x - h.x) + (y - h.y) * (y - h.y) < h.radius * h.radius) return false;
  return true;
}

double SheetSpec::intersect(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const {
  const double A = bend_x * d.x() * d.x() + bend_y * d.y() * d.y();
  const double B = 2 * bend_x * o.x() * d.x() + 2 * bend_y * o.y() * d.y() + d.z();
  const double C = bend_x * o.x() * o.x() + bend_y * o.y() * o.y() + o.z();
  double roots[2] = {-1, -1};
  if (std::abs(A) < 1e-15) {
    if (std::abs(B) > 1e-15) roots[0] = -C / B;
  } else {
    const double disc = B * B - 4 * A * C;
    if (disc < 0) return -1;
    const double s = std::sqrt(disc);
    roots[0] = (-B - s) / (2 * A);
    roots[1] = (-B + s) / (2 * A);
    if (roots[0] > roots[1]) std::swap(roots[0], roots[1]);
  }
  for (const double t : roots)
    if (t > 0) {
      const Eigen::Vector3d p = o + t * d;
      if (solid(p.x(), p.y())) return t;
    }
  return -1;
}

namespace {

// Sorted grid lines from `lo` to `hi`: every `spacing`, and every feature line; a regular
// line closer than a fifth of the spacing to a feature line gives way to it (no slivers).
std::vector<double> grid_lines(double lo, double hi, double spacing, std::vector<double> features) {
  features.push_back(lo);
  features.push_back(hi);
  std::sort(features.begin(), features.end());
  std::vector<double> lines = features;
  const auto n = static_cast<int>(std::ceil((hi - lo) / spacing));
  for (int k = 1; k < n; ++k) {
    const double v = lo + (hi - lo) * k / n;
    bool near = false;
    for (const double f : features) near = near || std::abs(f - v) < spacing / 5;
    if (!near) lines.push_back(v);
  }
  std::sort(lines.begin(), lines.end());
  lines.erase(std::unique(lines.begin(), lines.end(), [](double a, double b) { return std::abs(a - b) < 1e-12; }), lines.end());
  return lines;
}

std::size_t index_of(const std::vector<double>& lines, double v) {
  for (std::size_t i = 0; i < lines.size(); ++i)
    if (std::abs(lines[i] - v) < 1e-12) return i;
  throw std::logic_error("a feature line is missing from the grid");
}

}  // namespace

rig::TriangleMesh sheet_mesh(const SheetSpec& s) {
  const double w = s.width / 2, h = s.height / 2;
  std::vector<double> fx, fy;
  for (const auto& r : s.cutouts) {
    fx.push_back(std::clamp(r.x0, -w, w));
    fx.push_back(std::clamp(r.x1, -w, w));
    fy.push_back(std::clamp(r.y0, -h, h));
    fy.push_back(std::clamp(r.y1, -h, h));
  }
  std::vector<double> box;  // each hole's half-size
  for (const auto& hole : s.holes) {
    const double b = hole.radius + s.spacing;
    box.push_back(b);
    if (hole.x - b <= -w || hole.x + b >= w || hole.y - b <= -h || hole.y + b >= h)
      throw std::invalid_argument("a hole's box must lie inside the outline");
    for (const auto& r : s.cutouts)
      if (hole.x + b > r.x0 && hole.x - b < r.x1 && hole.y + b > r.y0 && hole.y - b < r.y1)
        throw std::invalid_argument("a hole's box must not touch a cut-out");
    fx.push_back(hole.x - b);
    fx.push_back(hole.x + b);
    fy.push_back(hole.y - b);
    fy.push_back(hole.y + b);
  }
  const std::vector<double> xs = grid_lines(-w, w, s.spacing, fx), ys = grid_lines(-h, h, s.spacing, fy);

  rig::TriangleMesh mesh;
  std::map<std::pair<std::size_t, std::size_t>, std::uint32_t> grid_vertex;
  const auto vertex_at = [&](std::size_t i, std::size_t j) {
    const auto [it, added] = grid_vertex.try_emplace({i, j}, static_cast<std::uint32_t>(mesh.vertices.size()));
    if (added) mesh.vertices.push_back(s.point(xs[i], ys[j]));
    return it->second;
  };
  const auto add_vertex = [&](double x, double y) {
    mesh.vertices.push_back(s.point(x, y));
    return static_cast<std::uint32_t>(mesh.vertices.size() - 1);
  };
  // A triangle facing +z, whichever order its corners come in.
  const auto add_triangle = [&](std::uint32_t a, std::uint32_t b, std::uint32_t c) {
    const Eigen::Vector3d n = (mesh.vertices[b] - mesh.vertices[a]).cross(mesh.vertices[c] - mesh.vertices[a]);
    if (n.z() >= 0) mesh.triangles.push_back({a, b, c});
    else mesh.triangles.push_back({a, c, b});
  };

  for (std::size_t i = 0; i + 1 < xs.size(); ++i)
    for (std::size_t j = 0; j + 1 < ys.size(); ++j) {
      const double xc = (xs[i] + xs[i + 1]) / 2, yc = (ys[j] + ys[j + 1]) / 2;
      bool keep = true;
      for (const auto& r : s.cutouts) keep = keep && !(xc > r.x0 && xc < r.x1 && yc > r.y0 && yc < r.y1);
      for (std::size_t k = 0; k < s.holes.size(); ++k)
        keep = keep && !(std::abs(xc - s.holes[k].x) < box[k] && std::abs(yc - s.holes[k].y) < box[k]);
      if (!keep) continue;
      const auto v00 = vertex_at(i, j), v10 = vertex_at(i + 1, j), v11 = vertex_at(i + 1, j + 1), v01 = vertex_at(i, j + 1);
      add_triangle(v00, v10, v11);
      add_triangle(v00, v11, v01);
    }

  for (std::size_t k = 0; k < s.holes.size(); ++k) {
    const auto& hole = s.holes[k];
    const std::size_t i0 = index_of(xs, hole.x - box[k]), i1 = index_of(xs, hole.x + box[k]);
    const std::size_t j0 = index_of(ys, hole.y - box[k]), j1 = index_of(ys, hole.y + box[k]);
    // The box's boundary, counter-clockwise seen from +z, from its lower left corner.
    std::vector<std::pair<std::size_t, std::size_t>> ring;
    for (std::size_t i = i0; i < i1; ++i) ring.emplace_back(i, j0);
    for (std::size_t j = j0; j < j1; ++j) ring.emplace_back(i1, j);
    for (std::size_t i = i1; i > i0; --i) ring.emplace_back(i, j1);
    for (std::size_t j = j1; j > j0; --j) ring.emplace_back(i0, j);
    const auto angle = [&](std::size_t r) { return std::atan2(ys[ring[r].second] - hole.y, xs[ring[r].first] - hole.x); };
    // The rim: each boundary vertex's own angle, and between two of them enough points
    // that no rim segment spans more than 1/64 of a turn.
    constexpr double kStep = 2 * std::numbers::pi / 64;
    std::vector<std::uint32_t> rim_start(ring.size());
    std::vector<std::uint32_t> rim;
    for (std::size_t r = 0; r < ring.size(); ++r) {
      const double a0 = angle(r);
      double a1 = angle((r + 1) % ring.size());
      while (a1 <= a0) a1 += 2 * std::numbers::pi;
      const int m = std::max(1, static_cast<int>(std::ceil((a1 - a0) / kStep)));
      rim_start[r] = static_cast<std::uint32_t>(rim.size());
      for (int q = 0; q < m; ++q) {
        const double a = a0 + (a1 - a0) * q / m;
        rim.push_back(add_vertex(hole.x + hole.radius * std::cos(a), hole.y + hole.radius * std::sin(a)));
      }
    }
    for (std::size_t r = 0; r < ring.size(); ++r) {
      const std::size_t next = (r + 1) % ring.size();
      const auto b0 = vertex_at(ring[r].first, ring[r].second), b1 = vertex_at(ring[next].first, ring[next].second);
      const std::uint32_t end = next == 0 ? static_cast<std::uint32_t>(rim.size()) : rim_start[next];
      for (std::uint32_t q = rim_start[r]; q < end; ++q) add_triangle(b0, rim[q], rim[(q + 1) % rim.size()]);
      add_triangle(b0, rim[end % rim.size()], b1);
    }
  }
  return mesh;
}

SheetSpec door_sheet() {
  SheetSpec p;
  p.width = 1.10;
  p.height = 0.80;
  p.bend_x = 0.12;
  p.cutouts = {{-0.42, 0.10, 0.30, 0.34},   // window opening
               {0.36, -0.02, 0.46, 0.03}};  // handle recess
  p.holes = {{-0.30, -0.22, 0.015}, {0.05, -0.28, 0.012}};
  return p;
}

SheetSpec fender_sheet() {
  SheetSpec p;
  p.width = 0.95;
  p.height = 0.60;
  p.bend_x = 0.25;
  p.cutouts = {{-0.475, -0.30, -0.15, -0.05},  // wheel-arch notch at the lower left
               {0.10, 0.08, 0.28, 0.18}};      // indicator opening
  p.holes = {{0.35, -0.20, 0.012}, {-0.30, 0.20, 0.012}};
  return p;
}

std::vector<Eigen::Vector3d> door_sheet_corners() {
  const SheetSpec p = door_sheet();
  const double w = p.width / 2, h = p.height / 2;
  const std::vector<std::pair<double, double>> corners = {
      {-w, -h}, {w, -h}, {w, h}, {-w, h},                        // outer corners
      {-0.42, 0.10}, {0.30, 0.10}, {0.30, 0.34}, {-0.42, 0.34},  // window opening
      {0.36, -0.02}, {0.46, 0.03}};                              // handle recess
  std::vector<Eigen::Vector3d> out;
  for (const auto& [x, y] : corners) out.push_back(p.point(x, y));
  return out;
}

std::vector<Eigen::Vector3d> fender_sheet_corners() {
  const SheetSpec p = fender_sheet();
  const double w = p.width / 2, h = p.height / 2;
  const std::vector<std::pair<double, double>> corners = {
      {-w, h}, {w, h}, {w, -h}, {-0.15, -h},                    // outer corners (the notch cuts one)
      {-w, -0.05}, {-0.15, -0.05},                              // the notch's inner corners
      {0.10, 0.08}, {0.28, 0.08}, {0.28, 0.18}, {0.10, 0.18}};  // indicator opening
  std::vector<Eigen::Vector3d> out;
  for (const auto& [x, y] : corners) out.push_back(p.point(x, y));
  return out;
}

rig::Panel sheet_panel(const std::string& name, const SheetSpec& spec, std::vector<Eigen::Vector3d> macro_features) {
  rig::Panel p;
  p.name = name;
  p.surface = std::make_shared<const rig::MeshSurface>(sheet_mesh(spec));
  p.macro_features = std::move(macro_features);
  return p;
}

rig::Panel shipped_panel(const std::string& name) {
  return rig::load_panel(std::string(MARKCELL_SOURCE_DIR) + "/config/panels/" + name + ".yaml");
}

}  // namespace markcell::test
