#pragma once
// `markcell bench loop`: the control lane's wake-up latency at 1 kHz next to cyclictest's
// at the same period and priority, measured in one run on the same machine.
#include <string>

#include "markcell/host/config.hpp"

namespace markcell::host {

struct LoopBenchOptions {
  double seconds = 10.0;
  std::string lane = "control";
  std::string json_path;        // empty: no file
  std::string cyclictest = "cyclictest";
};

// Returns the process exit code; prints the comparison on stdout.
int bench_loop(const CellConfig& config, const LoopBenchOptions& options);

// `markcell bench vision`: the vision task per stereo pair vs cv::buildOpticalFlowPyramid
// on the same two images (the floor), one thread, over rendered frames.
struct VisionBenchOptions {
  int frames = 1000;
  std::string scenario = "paper-door";
  std::string json_path;
};
int bench_vision(const CellConfig& config, const VisionBenchOptions& options);

// `markcell bench render`: the rig's renderer per stereo pair on one core, the shipped
// door's mesh next to the same door subdivided past 200k triangles.
struct RenderBenchOptions {
  int pairs = 40;
  std::string json_path;
};
int bench_render(const CellConfig& config, const RenderBenchOptions& options);

}  // namespace markcell::host
