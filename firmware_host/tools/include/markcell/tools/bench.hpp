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

// `markcell bench broker`: one mosquitto, `lines` lines of one inspection station and
// `marking_per_line` marking stations, each a process; `records` records in all; the
// latency from publish to the accepted line synced, and lost and duplicated deliveries.
struct BrokerBenchOptions {
  int records = 10'000;
  int lines = 3;
  int marking_per_line = 2;
  double rate_per_station = 100;  // records a second from each inspection station
  int drain_seconds = 60;         // after the last publish, the marking stations' time to take the rest
  std::string json_path;
  std::string work;               // the bench's folder (default: a fresh one under /tmp, removed after)
  bool keep = false;
  std::string config_file;        // passed on to the stations
  // The hidden station mode (the bench runs itself once per station).
  std::string station_role;       // marking | inspection
  int station_line = 0;
  std::string station_name;
  int port = 0;
  int station_count = 0;          // records this station publishes or expects
};
int bench_broker(const CellConfig& config, const BrokerBenchOptions& options);

}  // namespace markcell::host
