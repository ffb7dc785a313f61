// markcell-select-mfs: the select-mfs window as a program of its own, so the cell's
// package does not depend on highgui (and through it Qt and a display server's
// libraries); `markcell select-mfs` without --mf runs it. Packaged as markcell-select-mfs.
#include <exception>
#include <iostream>
#include <optional>
#include <vector>

#include <CLI/CLI.hpp>
#include <opencv2/imgcodecs.hpp>

#include "markcell/build_info.hpp"  // generated: firmware_host/cmake/build_info.cmake
#include "markcell/host/exit_codes.hpp"
#include "markcell/tools/panel_type_report.hpp"
#include "markcell/tools/select_mfs_window.hpp"

int main(int argc, char** argv) {
  using namespace markcell;
  CLI::App app{"Choose a panel type's macro-features on a reference image of the left camera, in a window "
               "(markcell select-mfs without --mf runs this)",
               "markcell-select-mfs"};
  app.set_version_flag("--version", "markcell-select-mfs " MARKCELL_VERSION "\ncommit " MARKCELL_GIT_COMMIT
                                    ", build type " MARKCELL_BUILD_TYPE ", " MARKCELL_COMPILER,
                       "Print the version, the git commit and the build type, and exit");
  std::string image, panel, out;
  int snap = 6, search_x = 160, search_y = 40;
  app.add_option("--image", image, "Reference image of the left camera")->required();
  app.add_option("--panel", panel, "Panel type name (as in the configuration's panel_types)")->required();
  app.add_option("--out", out, "Panel type file to write")->required();
  app.add_option("--snap", snap, "Snap each MF to the strongest Shi-Tomasi corner within this many pixels; an MF that "
                                 "would end farther from its click is refused")
      ->check(CLI::Range(0, 20));
  app.add_option("--search-x", search_x, "How far (px) a new panel may sit from the reference along x")->check(CLI::Range(0, 2000));
  app.add_option("--search-y", search_y, "... and along y")->check(CLI::Range(0, 2000));
  app.footer("In the window: left click adds an MF (a hole's centre inside a hole, else the nearest strong corner); "
             "drag moves one; d, x or Delete deletes the selected one; s saves (3 or more) and closes; q or Esc "
             "closes without saving.");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : host::kExitConfig;
  }
  const cv::Mat img = cv::imread(image, cv::IMREAD_GRAYSCALE);
  if (img.empty()) {
    std::cerr << "markcell select-mfs: --image " << image << ": cannot read it as an image\n";
    return host::kExitConfig;
  }
  std::optional<std::vector<vision::MfPick>> chosen;
  try {
    chosen = host::select_mfs_window(img, "markcell select-mfs: " + panel, snap, std::cout);
  } catch (const std::exception& e) {  // no display
    std::cerr << "markcell select-mfs: " << e.what() << "\n";
    return host::kExitRuntime;
  }
  if (!chosen) {
    std::cerr << "markcell select-mfs: closed without saving; " << out << " not written\n";
    return host::kExitRuntime;
  }
  vision::PanelTypeModel model;
  try {
    // Already snapped where the window showed them: made without a second snap.
    model = vision::make_panel_type(panel, img, *chosen, 0, search_x, search_y);
  } catch (const std::exception& e) {
    std::cerr << "markcell select-mfs: " << e.what() << "\n";
    return host::kExitConfig;
  }
  vision::save_panel_type(out, model);
  host::print_panel_type(model, {}, out);
  return host::kExitOk;
}
