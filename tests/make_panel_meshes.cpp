// Writes config/panels/door.ply and fender.ply from the sheets in sheet_mesh.hpp: how the
// shipped meshes were made (once; test_panel_mesh checks they still match).
//
//   build/dev/tests/make_panel_meshes config/panels
#include <cstdio>
#include <string>

#include "sheet_mesh.hpp"

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: make_panel_meshes FOLDER\n");
    return 2;
  }
  const std::string folder = argv[1];
  markcell::rig::save_mesh_ply(folder + "/door.ply", markcell::test::sheet_mesh(markcell::test::door_sheet()));
  markcell::rig::save_mesh_ply(folder + "/fender.ply", markcell::test::sheet_mesh(markcell::test::fender_sheet()));
  return 0;
}
