// libFuzzer target: the PLY reader (rig/panel_mesh.hpp parse_ply) on arbitrary bytes. A
// panel's mesh comes from outside the project (a CAD export): every input must end in a
// mesh whose triangles name vertices it has, all finite, within the limits, or in an
// error naming the file; never a crash, a hang or another exception.
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <stdexcept>
#include <string>

#include "markcell/rig/panel_mesh.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  try {
    const markcell::rig::TriangleMesh mesh = markcell::rig::parse_ply("fuzz.ply", bytes, 0.001);
    if (mesh.triangles.empty() || mesh.triangles.size() > markcell::rig::kMaxMeshTriangles) std::abort();
    for (const auto& v : mesh.vertices)
      if (!v.allFinite()) std::abort();
    for (const auto& t : mesh.triangles)
      for (const auto i : t)
        if (i >= mesh.vertices.size()) std::abort();
  } catch (const std::runtime_error& e) {
    if (std::string(e.what()).rfind("fuzz.ply: ", 0) != 0) std::abort();  // every error names the file
  }
  return 0;
}
