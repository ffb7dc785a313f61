#pragma once
// A panel's surface as a triangle mesh in the panel frame, as CAD exports it (STL, OBJ,
// PLY, read with assimp), and ray casting against it with Embree (Intel's ray-tracing
// kernel, Debian's libembree-dev 3.13 on amd64 and arm64): a BVH built once, queries
// thread-safe. Cut-outs and holes are simply where the mesh has no triangles.
//
// Embree traces in single precision; it only says which triangle a ray meets first.
// Where on that triangle is recomputed here in double precision (Moeller-Trumbore), so a
// hit's point and distance do not depend on Embree's SIMD width or the CPU: scoring and
// the truth agree to the mesh, not to a float's 7 digits.
//
// The rig's side only (rendering, scoring): start-up and the renderer's threads; allocates.
#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Geometry>

namespace markcell::rig {

struct TriangleMesh {
  std::vector<Eigen::Vector3d> vertices;               // panel frame, metres
  std::vector<std::array<std::uint32_t, 3>> triangles;  // indices into vertices
};

// Limits on a mesh file: a panel's CAD export is megabytes; anything far larger is not a
// panel (or not meant for the rig) and is refused before it is parsed.
constexpr std::size_t kMaxMeshFileBytes = 256u << 20;
constexpr std::size_t kMaxMeshTriangles = 4'000'000;

// Reads a mesh file (STL ascii or binary, OBJ, PLY ascii or binary; the format from the
// file's contents and extension) with every node's transform applied, scaled by
// `metres_per_unit` (0.001 for a CAD export in millimetres). Throws std::runtime_error
// naming the file and what is wrong: not a regular file, too large, not a mesh, no
// triangles, a non-finite vertex.
TriangleMesh load_mesh(const std::string& path, double metres_per_unit);

// The PLY reader of load_mesh on bytes already read (`name` starts its messages): the
// project's own, not assimp's (panel_mesh.cpp says why); fuzzed (tests/fuzz/fuzz_mesh).
TriangleMesh parse_ply(const std::string& name, const std::string& bytes, double metres_per_unit);

// Writes a mesh as binary little-endian PLY (vertices as doubles): the shipped panels'
// format. Throws naming the file on an I/O error.
void save_mesh_ply(const std::string& path, const TriangleMesh& mesh);

struct MeshHit {
  double t = -1;                // along the ray, in units of |d|; negative: no hit
  Eigen::Vector3d p = Eigen::Vector3d::Zero();       // the hit point
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // the triangle's unit normal, facing the ray's origin
  std::uint32_t triangle = 0;
  bool hit() const { return t > 0; }
};

class MeshSurface {
 public:
  // Builds the BVH (Embree, high quality, robust: no cracks along shared edges). Throws
  // on an empty mesh or an index out of range.
  explicit MeshSurface(TriangleMesh mesh);
  ~MeshSurface();
  MeshSurface(const MeshSurface&) = delete;
  MeshSurface& operator=(const MeshSurface&) = delete;

  const TriangleMesh& mesh() const { return mesh_; }
  const Eigen::AlignedBox3d& bounds() const { return bounds_; }

  // Where the ray o + t d (t > 0; d need not be unit length) first meets the mesh.
  MeshHit intersect(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const;
  // The same for n rays from one origin (a camera's pixels), traced as coherent packets:
  // out[i] is what intersect(o, d[i]) gives (a ray through a shared edge may name the
  // other triangle of the edge: the same point, that facet's normal).
  void intersect(const Eigen::Vector3d& o, const Eigen::Vector3d* d, std::size_t n, MeshHit* out) const;
  // The front face seen from +z at (x, y) (the side the cameras see of a panel in its
  // frame): the first hit of the ray coming down along -z, or no hit over a hole.
  MeshHit from_front(double x, double y) const;

 private:
  struct Embree;
  MeshHit refine(std::uint32_t triangle, const Eigen::Vector3d& o, const Eigen::Vector3d& d) const;
  TriangleMesh mesh_;
  Eigen::AlignedBox3d bounds_;
  std::unique_ptr<Embree> embree_;
};

}  // namespace markcell::rig
