// libFuzzer target: a recording's frame index (frames.csv) on arbitrary bytes, behind a
// valid manifest, opened and every frame read. Every input must end in a recording (its
// bad lines listed as index problems, its bad frames dropped with a reason) or a
// RecordingError, never a crash, a hang, an overflow (UBSan) or a file outside the folder.
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include <unistd.h>

#include "markcell/vision/recording.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  namespace fs = std::filesystem;
  static const fs::path dir = [] {
    const fs::path d = fs::temp_directory_path() / ("markcell-fuzz-index-" + std::to_string(::getpid()));
    fs::create_directories(d / "left");
    std::ofstream(d / "recording.yaml") << "format: markcell-recording\nversion: 1\nstation: marking\npanel_type: door\n"
                                           "frame_rate_hz: 30\nimage_width: 8\nimage_height: 8\ncalibration: stereo.yaml\n";
    std::ofstream(d / "left" / "a.png") << "not a png";
    return d;
  }();
  std::ofstream(dir / "frames.csv", std::ios::binary | std::ios::trunc).write(reinterpret_cast<const char*>(data),
                                                                               static_cast<std::streamsize>(size));
  try {
    const markcell::vision::Recording r = markcell::vision::Recording::open(dir.string());
    for (std::size_t i = 0; i < r.size() && i < 64; ++i) {
      const markcell::vision::ReplayFrame f = r.read(i);
      if (!f.dropped) std::abort();  // no frame here has a readable image
      if (f.problem.empty()) std::abort();
    }
  } catch (const markcell::vision::RecordingError&) {
  }
  return 0;
}
