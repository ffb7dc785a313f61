#include "markcell/host/install_paths.hpp"

#include <unistd.h>

#include <array>

namespace markcell::host {

bool running_installed() {
  std::array<char, 256> exe{};
  const ssize_t n = readlink("/proc/self/exe", exe.data(), exe.size() - 1);
  return n > 0 && std::string(exe.data(), static_cast<std::size_t>(n)) == MARKCELL_INSTALLED_BINARY;
}

std::string default_config_dir() { return running_installed() ? MARKCELL_INSTALLED_CONFIG_DIR : "config"; }

std::string default_calibration_dir() {
  return running_installed() ? std::string(MARKCELL_INSTALLED_STATE_DIR) + "/calibration" : "config/calibration";
}

std::string default_config_file() {
  return running_installed() ? std::string(MARKCELL_INSTALLED_CONFIG_DIR) + "/cell.yaml" : "config/cell.example.yaml";
}

}  // namespace markcell::host
