#pragma once
// What the rig's end-to-end tests share (test_sim.cpp, test_service_run.cpp): markcell
// run as a user runs it, the scenarios generated once per build, the example
// configuration edited, a cell in the test's process, a cell run as the service.
#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "markcell/host/cell.hpp"
#include "markcell/host/config.hpp"
#include "markcell/vision/frame_source.hpp"
#include "markcell/vision/recording.hpp"
#include "test_files.hpp"

namespace markcell::test {

inline const std::string kMarkcell = MARKCELL_BINARY;

// `markcell replay RECORDING --one-predictor -q ARGS --out OUT`, which must succeed; its
// report.json.
inline std::string replay_report(const std::string& recording, const std::string& args, const std::string& out) {
  const auto r = run_command("cd " + source_path("") + " && " + kMarkcell + " replay " + recording + " --one-predictor -q" + args +
                             " --out " + out);
  INFO(r.output);
  REQUIRE(r.exit_code == 0);
  return read_file(out + "/report.json");
}

// The example configuration with each `from` replaced by its `to`, written into `dir`
// with its calibration and panel files named by absolute paths.
inline std::string example_config_with(const test::TempDir& dir, const std::vector<std::pair<std::string, std::string>>& edits) {
  return dir.write("cell.yaml", test::example_config_text(edits));
}

// A command log's time "SECONDS.MICROS" (docs/rig.md, "The command logs") as seconds
// from the run's start: the logs' epoch, 946684800 s (2000-01-01 UTC), is the run's 0.
// Whole seconds and the fraction apart, so microseconds stay exact in a double.
inline double log_seconds(const std::string& stamp) {
  const auto dot = stamp.find('.');
  return static_cast<double>(std::stoll(stamp.substr(0, dot)) - 946684800) + std::stod("0" + stamp.substr(dot));
}

// `BINARY sim ARGS -q --one-predictor` into FOLDER next to markcell, generated once per
// build (CTest runs each case in its own process: they share it under a file lock, and a
// newer markcell or BINARY regenerates it).
inline std::string generated_scenario(const std::string& folder, const std::string& args, const std::string& binary = kMarkcell) {
  const std::string out = (std::filesystem::path(kMarkcell).parent_path() / folder).string();
  const int lock = ::open((out + ".lock").c_str(), O_CREAT | O_RDWR, 0644);
  REQUIRE(lock >= 0);
  REQUIRE(::flock(lock, LOCK_EX) == 0);
  const std::filesystem::path report = std::filesystem::path(out) / "report.json";
  if (!std::filesystem::exists(report) ||
      std::filesystem::last_write_time(report) < std::filesystem::last_write_time(kMarkcell) ||
      std::filesystem::last_write_time(report) < std::filesystem::last_write_time(binary)) {
    const auto r = run_command("cd " + source_path("") + " && " + binary + " sim " + args + " --one-predictor -q --out " + out);
    INFO(r.output);
    ::flock(lock, LOCK_UN);
    ::close(lock);
    REQUIRE(r.exit_code == 0);
  } else {
    ::flock(lock, LOCK_UN);
    ::close(lock);
  }
  return out;
}

// One short scenario for most of the file: 3 s of the paper's door at 10 frames a second.
inline const std::string& sim_dir() {
  static const std::string out = generated_scenario("test-sim-paper-door", "paper-door --seconds 3 --fps 10");
  return out;
}

// report.json's NAME.max_abs [x, y, z] (prediction_error_mm, ...) of the configured
// predictor's run (the top level).
inline Eigen::Vector3d json_max_abs(const std::string& json, const std::string& name) {
  const auto report = parse_json(json);
  INFO(name);
  REQUIRE(report.contains(name));
  const auto& v = report[name]["max_abs"];
  REQUIRE(v.is_array());
  REQUIRE(v.size() == 3);
  return {v[0].get<double>(), v[1].get<double>(), v[2].get<double>()};
}

// The example configuration for a cell inside the test process: no service manager, no
// memory locking, no real-time priorities (simulated time needs none).
inline host::CellConfig in_process_config() {
  auto cfg = host::load_config(source_path("config/cell.example.yaml"), host::task_catalog());
  cfg.watchdog.systemd = false;
  cfg.executive.lock_memory = false;
  for (auto& lane : cfg.executive.lanes) lane.priority = 0, lane.core = -1;
  return cfg;
}

// A recording's pairs decoded into memory, times from its first frame: for runs whose
// measured part must not decode images (the recording's loader allocates).
inline std::vector<vision::MemoryFrameSource::Pair> decoded_pairs(const vision::Recording& rec) {
  std::vector<vision::MemoryFrameSource::Pair> pairs;
  for (std::size_t i = 0; i < rec.size(); ++i) {
    auto f = rec.read(i);
    REQUIRE_FALSE(f.dropped);
    pairs.push_back({f.seq, f.time - rec.entry(0).time, f.left, f.right});
  }
  return pairs;
}

// A copy of the example configuration in `dir` running the cell as the service does, with
// a results file, a record drop folder and the short recording as its cameras.
struct ServiceCell {
  std::filesystem::path config, results, drop, script, poses;  // poses: the pose log's folder
};
inline ServiceCell service_cell(const test::TempDir& dir, const std::string& plc_script) {
  ServiceCell s;
  std::filesystem::copy(source_path("config"), dir.path() / "config", std::filesystem::copy_options::recursive);
  s.config = dir.path() / "config" / "cell.example.yaml";
  s.results = dir.path() / "results.jsonl";
  s.drop = dir.path() / "drop";
  s.script = dir.path() / "plc.txt";
  std::filesystem::create_directories(s.drop);
  std::string text = read_file(s.config.string());
  const auto replace = [&](const std::string& from, const std::string& to) {
    const auto at = text.find(from);
    REQUIRE(at != std::string::npos);
    text.replace(at, from.size(), to);
  };
  replace("  # results_file: /var/lib/markcell/results.jsonl", "  results_file: " + s.results.string());
  replace("  # record_folder: /var/lib/markcell/records", "  record_folder: " + s.drop.string());
  s.poses = dir.path() / "poses";
  std::filesystem::create_directories(s.poses);
  replace("  # pose_log_folder: /var/lib/markcell/poses", "  pose_log_folder: " + s.poses.string());
  replace("source: simulated ", "source: recording ");
  replace("    # recording: /path/to/recording", "    recording: " + sim_dir() + "/recording");
  std::ofstream(s.config.string()) << text;
  std::ofstream(s.script.string()) << plc_script;
  return s;
}

inline std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string l; std::getline(in, l);) out.push_back(l);
  return out;
}

}  // namespace markcell::test
