// Panel meshes: read with assimp in the formats CAD exports, ray-cast with Embree, checked
// against closed-form surfaces (the sheets of sheet_mesh.hpp) and hand-written files.
#include <catch2/catch.hpp>
#include <cmath>
#include <algorithm>
#include <cstring>
#include <fstream>
#include <map>

#include "markcell/common/splitmix.hpp"
#include "markcell/rig/panel_mesh.hpp"
#include "sheet_mesh.hpp"
#include "test_files.hpp"

using namespace markcell;

namespace {

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const std::exception& e) {
    return e.what();
  }
  return "no error";
}

// Edges used by one triangle only: the mesh's boundary. A T-junction shows up here too (its
// long edge has no partner), so the boundary's length is checked against the shape's.
double boundary_length(const rig::TriangleMesh& mesh) {
  std::map<std::pair<std::uint32_t, std::uint32_t>, int> uses;
  for (const auto& t : mesh.triangles)
    for (int k = 0; k < 3; ++k) {
      const auto a = t[static_cast<std::size_t>(k)], b = t[static_cast<std::size_t>((k + 1) % 3)];
      ++uses[{std::min(a, b), std::max(a, b)}];
    }
  double length = 0;
  for (const auto& [edge, n] : uses) {
    REQUIRE(n <= 2);
    if (n == 1) length += (mesh.vertices[edge.first] - mesh.vertices[edge.second]).norm();
  }
  return length;
}

}  // namespace

TEST_CASE("a sheet's mesh: every vertex on the surface, facing +z, its boundary the outline, cut-outs and holes") {
  test::SheetSpec s = test::door_sheet();
  s.bend_x = 0;  // flat: the boundary's length has a closed form
  const rig::TriangleMesh mesh = test::sheet_mesh(s);
  for (const auto& v : mesh.vertices) CHECK(std::abs(v.z() - s.z(v.x(), v.y())) < 1e-12);
  double area = 0;
  for (const auto& t : mesh.triangles) {
    const Eigen::Vector3d n = (mesh.vertices[t[1]] - mesh.vertices[t[0]]).cross(mesh.vertices[t[2]] - mesh.vertices[t[0]]);
    CHECK(n.z() > 0);
    area += n.norm() / 2;
  }
  double expected_area = s.width * s.height;
  double expected_boundary = 2 * (s.width + s.height);
  for (const auto& r : s.cutouts) {
    expected_area -= (r.x1 - r.x0) * (r.y1 - r.y0);
    expected_boundary += 2 * ((r.x1 - r.x0) + (r.y1 - r.y0));
  }
  for (const auto& h : s.holes) {
    expected_area -= M_PI * h.radius * h.radius;
    expected_boundary += 2 * M_PI * h.radius;
  }
  // The holes are polygons of at least 64 points on the rim: within 0.2 % of a circle's
  // area and perimeter (1 - cos(pi/64), 1 - sin(pi/64)/(pi/64)).
  CHECK(area == Approx(expected_area).margin(0.002 * M_PI * 0.015 * 0.015 * 2));
  CHECK(boundary_length(mesh) == Approx(expected_boundary).margin(0.0005 * 2 * M_PI * 0.027));
}

TEST_CASE("rays on a bent sheet's mesh meet it where the closed form does, to the mesh's chord error") {
  const test::SheetSpec s = test::fender_sheet();  // z = -0.25 x^2
  const rig::MeshSurface surface(test::sheet_mesh(s));
  SplitMix rng{42};
  int hits = 0, misses = 0, near_edges = 0;
  double worst = 0;
  for (int i = 0; i < 20000; ++i) {
    // From a camera 2.5 m in front, towards a point anywhere over the sheet and beyond.
    // Braced: the draws in the order written, on every compiler (tests/support/draw.hpp).
    const Eigen::Vector3d o{0.3 * (rng.unit() - 0.5), 0.2 * (rng.unit() - 0.5), 2.5};
    const Eigen::Vector3d target{1.1 * (rng.unit() - 0.5), 0.7 * (rng.unit() - 0.5), -0.05};
    const Eigen::Vector3d d = target - o;
    const double t_exact = s.intersect(o, d);
    const rig::MeshHit hit = surface.intersect(o, d);
    if (t_exact > 0 && hit.hit()) {
      ++hits;
      // The chord error on z = -0.25 x^2: 0.25 L^2 / 4 over a triangle L wide in x, 6 um
      // for the 10 mm grid, 14 um for the 15 mm fans around the holes, more along an
      // oblique ray.
      const double gap = (hit.p - (o + t_exact * d)).norm();
      worst = std::max(worst, gap);
      CHECK(gap < 2e-5);
      CHECK(hit.normal.dot(s.normal(hit.p.x(), hit.p.y())) > std::cos(0.01));
    } else if (t_exact > 0 || hit.hit()) {
      // Disagreement only where the sheet's edge and the mesh's differ: within the hole
      // polygons' sagitta (0.02 mm) of a rim, or a hair of an edge.
      const Eigen::Vector3d p = hit.hit() ? hit.p : o + t_exact * d;
      bool near = false;
      for (const double dx : {-2e-5, 2e-5})
        for (const double dy : {-2e-5, 2e-5}) near = near || s.solid(p.x() + dx, p.y() + dy) != s.solid(p.x(), p.y());
      CHECK(near);
      ++near_edges;
    } else {
      ++misses;
    }
  }
  INFO("hits " << hits << ", misses " << misses << ", near edges " << near_edges << ", worst " << worst);
  CHECK(hits > 10000);
  CHECK(misses > 1000);
  CHECK(near_edges < 20);
  // Straight down onto the front face: the surface's height, and over a hole nothing.
  CHECK(surface.from_front(0.2, -0.1).p.z() == Approx(s.z(0.2, -0.1)).margin(1e-5));
  CHECK_FALSE(surface.from_front(0.35, -0.20).hit());  // a hole's centre
  CHECK_FALSE(surface.from_front(0.19, 0.13).hit());   // the indicator opening
  CHECK_FALSE(surface.from_front(0.6, 0.0).hit());     // beside the panel
}

TEST_CASE("a fan of rays traced as packets meets the mesh where the same rays traced one by one do") {
  const test::SheetSpec s = test::fender_sheet();
  const rig::MeshSurface surface(test::sheet_mesh(s));
  // A camera's fan: one origin, 1000 directions over the sheet and past its edges and
  // holes, not all of unit length, one of them zero (no hit, no crash).
  const Eigen::Vector3d o(0.05, -0.02, 2.5);
  std::vector<Eigen::Vector3d> d;
  for (int i = 0; i < 40; ++i)
    for (int j = 0; j < 25; ++j) d.push_back((Eigen::Vector3d(-0.6 + 0.03 * i, -0.4 + 0.032 * j, -0.05) - o) * (1 + i % 3) / 2.0);
  d[7] = Eigen::Vector3d::Zero();
  std::vector<rig::MeshHit> fan(d.size());
  surface.intersect(o, d.data(), d.size(), fan.data());
  int hits = 0;
  for (std::size_t i = 0; i < d.size(); ++i) {
    const rig::MeshHit one = surface.intersect(o, d[i]);
    CAPTURE(i);
    REQUIRE(fan[i].hit() == one.hit());
    if (!one.hit()) continue;
    ++hits;
    CHECK((fan[i].p - one.p).norm() < 1e-9);
    CHECK(fan[i].t == Approx(one.t).epsilon(1e-12));
  }
  CHECK_FALSE(fan[7].hit());
  CHECK(hits > 400);  // half the fan is on the sheet (500 rays)
  CHECK(hits < 990);
}

TEST_CASE("mesh files: PLY round trip, STL and OBJ in millimetres, and each bad file named with what is wrong") {
  test::TempDir dir;
  const rig::TriangleMesh door = test::sheet_mesh(test::door_sheet());
  const std::string ply = (dir.path() / "door.ply").string();
  rig::save_mesh_ply(ply, door);
  const rig::TriangleMesh back = rig::load_mesh(ply, 1.0);
  REQUIRE(back.triangles.size() == door.triangles.size());
  REQUIRE(back.vertices.size() == door.vertices.size());
  for (std::size_t i = 0; i < door.vertices.size(); ++i) CHECK((back.vertices[i] - door.vertices[i]).norm() < 1e-6);
  for (std::size_t i = 0; i < door.triangles.size(); ++i) CHECK(back.triangles[i] == door.triangles[i]);

  // One square of 100 mm as CAD writes it: ASCII STL (two facets, six corners) and OBJ
  // (four vertices, one quad face that the importer splits in two).
  const std::string stl = dir.write("square.stl",
                                    "solid square\n"
                                    " facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n   vertex 100 0 0\n   vertex 100 100 0\n"
                                    "  endloop\n endfacet\n"
                                    " facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n   vertex 100 100 0\n   vertex 0 100 0\n"
                                    "  endloop\n endfacet\n"
                                    "endsolid square\n");
  const std::string obj = dir.write("square.obj", "# a square\nv 0 0 0\nv 100 0 0\nv 100 100 0\nv 0 100 0\nf 1 2 3 4\n");
  for (const std::string& file : {stl, obj}) {
    INFO(file);
    const rig::TriangleMesh m = rig::load_mesh(file, 0.001);
    REQUIRE(m.triangles.size() == 2);
    const rig::MeshSurface square(m);
    CHECK(square.bounds().max().isApprox(Eigen::Vector3d(0.1, 0.1, 0), 1e-9));
    const rig::MeshHit h = square.intersect(Eigen::Vector3d(0.03, 0.07, 1.0), Eigen::Vector3d(0, 0, -2));
    CHECK(h.t == Approx(0.5).epsilon(1e-12));
    CHECK(h.normal.isApprox(Eigen::Vector3d::UnitZ()));
    CHECK_FALSE(square.intersect(Eigen::Vector3d(0.13, 0.07, 1.0), Eigen::Vector3d(0, 0, -1)).hit());
  }

  CHECK(error_of([&] { rig::load_mesh(dir.path().string(), 1.0); }) ==
        dir.path().string() + ": a directory, not read (a panel mesh must be a regular file)");
  const std::string text = dir.write("notes.txt", "v 0 0 0\n");
  CHECK(error_of([&] { rig::load_mesh(text, 1.0); }) == text + ": a panel mesh must be .stl, .obj or .ply, not 'txt'");
  // PLY in every form: ascii with a quad (cut in two), big-endian binary with a double
  // vertex and an extra property and element the reader skips.
  const std::string ascii = dir.write("quad.ply",
                                      "ply\nformat ascii 1.0\ncomment by hand\nelement vertex 4\nproperty float x\n"
                                      "property float y\nproperty float z\nproperty uchar red\nelement face 1\n"
                                      "property list uchar int vertex_indices\nend_header\n"
                                      "0 0 0 1\n100 0 0 2\n100 100 0 3\n0 100 0 4\n4 0 1 2 3\n");
  const rig::TriangleMesh quad = rig::load_mesh(ascii, 0.001);
  REQUIRE(quad.triangles.size() == 2);
  CHECK(quad.vertices[2].isApprox(Eigen::Vector3d(0.1, 0.1, 0)));
  CHECK((quad.triangles[1] == std::array<std::uint32_t, 3>{0, 2, 3}));
  {
    std::string big = "ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
                      "property double z\nelement face 1\nproperty list uchar uint vertex_index\nproperty short flags\n"
                      "element edge 1\nproperty int a\nproperty int b\nend_header\n";
    const auto put = [&](auto value) {
      char raw[sizeof value];
      std::memcpy(raw, &value, sizeof value);
      std::reverse(raw, raw + sizeof value);
      big.append(raw, sizeof value);
    };
    for (const double v : {0.0, 0.0, 1.0, 2.0, 0.0, 1.0, 0.0, 2.0, 1.0}) put(v);
    put(std::uint8_t{3});
    for (const std::uint32_t i : {0u, 1u, 2u}) put(i);
    put(std::int16_t{7});
    put(std::int32_t{0});
    put(std::int32_t{1});
    const std::string file = dir.write("big.ply", big);
    const rig::TriangleMesh m = rig::load_mesh(file, 1.0);
    REQUIRE(m.triangles.size() == 1);
    CHECK(m.vertices[1].isApprox(Eigen::Vector3d(2, 0, 1)));
    const rig::MeshSurface tri(m);
    CHECK(tri.from_front(0.5, 0.5).p.z() == Approx(1.0));
  }
  const std::string garbage = dir.write("broken.ply", "ply\nformat binary_little_endian 1.0\nelement vertex 9\n");
  CHECK(error_of([&] { rig::load_mesh(garbage, 1.0); }) == garbage + ": PLY header without end_header");
  // Every cut of a real file is an error that names it (assimp's PLY reader hung on these),
  // and so is every cut of a binary STL.
  const std::string bytes = test::read_file(ply);
  const std::size_t body = bytes.find("end_header\n") + 11;
  for (std::size_t cut = 0; cut < bytes.size(); cut += cut < body + 64 ? 1 : 997) {
    const std::string file = dir.write("cut.ply", bytes.substr(0, cut));
    const std::string e = error_of([&] { rig::load_mesh(file, 1.0); });
    INFO(cut << ": " << e);
    CHECK(e.rfind(file + ": ", 0) == 0);
  }
  const std::string face_beyond = dir.write("beyond.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                                                          "property float y\nproperty float z\nelement face 1\n"
                                                          "property list uchar int vertex_indices\nend_header\n"
                                                          "0 0 0\n1 0 0\n1 1 0\n3 0 1 3\n");
  CHECK(error_of([&] { rig::load_mesh(face_beyond, 1.0); }) == face_beyond + ": face 0 names vertex 3.000000 of 3");
  // Counts that would loop without reading a byte (an element with no properties) or
  // wrap the header's sums are refused in the header; so is a vertex without z.
  const std::string endless = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                              "property float z\nelement edge 18446744073709551615\nend_header\n0 0 0\n1 0 0\n1 1 0\n";
  CHECK(error_of([&] { rig::parse_ply("endless.ply", endless, 1.0); }) ==
        "endless.ply: PLY header line 7: 18446744073709551615 edge entries, more than 12000000");
  const std::string flat = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                           "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0\n1 0\n1 1\n3 0 1 2\n";
  CHECK(error_of([&] { rig::parse_ply("flat.ply", flat, 1.0); }) == "flat.ply: PLY vertex element without a scalar property 'z'");
  {
    std::string stl_bin(80, ' ');
    const std::uint32_t n = 2;
    stl_bin.append(reinterpret_cast<const char*>(&n), 4);
    stl_bin.append(60, '\0');
    const std::string file = dir.write("cut.stl", stl_bin);
    CHECK(error_of([&] { rig::load_mesh(file, 1.0); }) == file + ": a binary STL of 2 triangles is 184 bytes, this one 144");
    const std::string cut_ascii = dir.write("cut_ascii.stl", test::read_file(stl).substr(0, 200));
    CHECK(error_of([&] { rig::load_mesh(cut_ascii, 1.0); }) == cut_ascii + ": an ASCII STL cut short: its last line is not endsolid");
  }
  const std::string lines_only = dir.write("lines.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nl 1 2\nl 2 3\n");
  CHECK(error_of([&] { rig::load_mesh(lines_only, 1.0); }).rfind(lines_only + ": ", 0) == 0);
  CHECK(error_of([&] { rig::load_mesh(obj, 0.0); }) == obj + ": metres per mesh unit must be a positive number, not 0.000000");
}

TEST_CASE("the shipped door and fender meshes are the sheets they were made from") {
  const std::pair<const char*, test::SheetSpec> shipped[] = {{"config/panels/door.ply", test::door_sheet()},
                                                             {"config/panels/fender.ply", test::fender_sheet()}};
  for (const auto& [file, spec] : shipped) {
    INFO(file);
    const rig::TriangleMesh made = test::sheet_mesh(spec);
    const rig::TriangleMesh loaded = rig::load_mesh(test::source_path(file), 1.0);
    REQUIRE(loaded.vertices.size() == made.vertices.size());
    REQUIRE(loaded.triangles.size() == made.triangles.size());
    double worst = 0;
    for (std::size_t i = 0; i < made.vertices.size(); ++i) worst = std::max(worst, (loaded.vertices[i] - made.vertices[i]).norm());
    CHECK(worst < 1e-6);  // float coordinates
    for (std::size_t i = 0; i < made.triangles.size(); ++i) CHECK(loaded.triangles[i] == made.triangles[i]);
  }
}
