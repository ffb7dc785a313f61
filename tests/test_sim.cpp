// The rig end to end, as a user runs it: markcell sim generates a short scenario and
// replays it through the cell in simulated time; markcell replay of the same recording
// gives the same command log and report byte for byte; a bad inspection record is
// rejected with its line and field; a record whose MFs do not match the panel stops the
// panel with the PLC told and nothing sprayed. Figures are asserted from report.json.
#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <array>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <vector>
#include <string>

#include "markcell/host/config.hpp"
#include "markcell/host/cell.hpp"
#include "markcell/host/inspection_record.hpp"
#include "markcell/host/record_folder.hpp"
#include "markcell/host/results_file.hpp"
#include "alloc_guard.hpp"
#include "markcell/vision/frame_source.hpp"
#include "markcell/vision/recording.hpp"
#include "test_files.hpp"

using namespace markcell;
using markcell::test::read_file;
using markcell::test::run_command;
using markcell::test::source_path;

namespace {
const std::string kMarkcell = MARKCELL_BINARY;

// A number after "key": in the first occurrence of `section` (simple, for our own JSON).
double json_number(const std::string& json, const std::string& section, const std::string& key) {
  const auto s = json.find("\"" + section + "\"");
  REQUIRE(s != std::string::npos);
  const auto k = json.find("\"" + key + "\": ", s);
  REQUIRE(k != std::string::npos);
  return std::stod(json.substr(k + key.size() + 4));
}


// One short scenario for the whole file: 3 s of the paper's door at 10 frames a second,
// generated once per build of markcell (CTest runs each case in its own process: they
// share it under a file lock, and a newer markcell regenerates it).
const std::string& sim_dir() {
  static const std::string out = (std::filesystem::path(kMarkcell).parent_path() / "test-sim-paper-door").string();
  static bool done = false;
  if (done) return out;
  const int lock = ::open((out + ".lock").c_str(), O_CREAT | O_RDWR, 0644);
  REQUIRE(lock >= 0);
  REQUIRE(::flock(lock, LOCK_EX) == 0);
  const std::filesystem::path report = std::filesystem::path(out) / "report.json";
  if (!std::filesystem::exists(report) ||
      std::filesystem::last_write_time(report) < std::filesystem::last_write_time(kMarkcell)) {
    const auto r = run_command("cd " + source_path("") + " && " + kMarkcell +
                               " sim paper-door --seconds 3 --fps 10 --one-predictor -q --out " + out);
    INFO(r.output);
    ::flock(lock, LOCK_UN);
    ::close(lock);
    REQUIRE(r.exit_code == 0);
  } else {
    ::flock(lock, LOCK_UN);
    ::close(lock);
  }
  done = true;
  return out;
}
}  // namespace

TEST_CASE("markcell sim paper-door: all three dings marked within the radius, no false spray, Table I below the paper's") {
  const std::string json = read_file(sim_dir() + "/report.json");
  INFO(json);
  CHECK(json.find("\"scenario\": \"paper-door\"") != std::string::npos);
  CHECK(json.find("\"predictor\": \"kalman\"") != std::string::npos);
  CHECK(json_number(json, "defects", "planned") == 3);
  CHECK(json_number(json, "defects", "marked") == 3);
  CHECK(json_number(json, "defects", "skipped") == 0);
  CHECK(json_number(json, "false_sprays", "false_sprays") == 0);
  CHECK(json_number(json, "marking_error_mm", "max") < 5.0);
  // Inter-calibration max |error| per axis, cm: the paper's means were 1.63 / 0.89 / 2.01.
  const auto ic = json.find("\"intercalibration_cm\": {\"max_abs\": [");
  REQUIRE(ic != std::string::npos);
  std::istringstream in(json.substr(json.find('[', ic) + 1));
  double x = 0, y = 0, z = 0;
  char comma = 0;
  in >> x >> comma >> y >> comma >> z;
  CHECK(x < 1.63);
  CHECK(y < 0.89);
  CHECK(z < 2.01);
  CHECK(json_number(json, "deadline_misses", "deadline_misses") == 0);
  // The plan made once the door's motion was known: all three feasible, as the run found.
  CHECK(json_number(json, "plan", "feasible") == 3);
  CHECK(json.find("\"matches_run\": true") != std::string::npos);
  for (const char* f : {"prediction.png", "mf_epipolar.png", "mf_area.png", "sprays.png", "commands.log"})
    CHECK(std::filesystem::exists(sim_dir() + "/" + f));
  // Three valve pulses in the command log, each opened and closed.
  const std::string log = read_file(sim_dir() + "/commands.log");
  std::size_t opens = 0, closes = 0;
  for (auto p = log.find("valve open"); p != std::string::npos; p = log.find("valve open", p + 1)) ++opens;
  for (auto p = log.find("valve close"); p != std::string::npos; p = log.find("valve close", p + 1)) ++closes;
  CHECK(opens == 3);
  CHECK(closes == 3);
}

TEST_CASE("replaying the same recording gives the same command log and report, byte for byte") {
  test::TempDir dir;
  const std::string out = (dir.path() / "again").string();
  const auto r = run_command("cd " + source_path("") + " && " + kMarkcell + " replay " + sim_dir() +
                             "/recording --one-predictor -q --out " + out);
  INFO(r.output);
  REQUIRE(r.exit_code == 0);
  CHECK(read_file(out + "/commands.log") == read_file(sim_dir() + "/commands.log"));
  CHECK(read_file(out + "/report.json") == read_file(sim_dir() + "/report.json"));
}

TEST_CASE("inspection records: every bad field is rejected with its file, line and what is wrong") {
  const auto cfg = host::load_config(source_path("config/cell.example.yaml"), host::task_catalog());
  const std::string good = read_file(sim_dir() + "/recording/inspection.yaml");
  const auto job = host::parse_inspection_record(good, "inspection.yaml", cfg.panel_types);
  CHECK(job.mf_count == 10);
  CHECK(job.defect_count == 3);
  CHECK(job.panel_type_index == 0);
  auto bad = [&](const std::string& from, const std::string& to) {
    std::string text = good;
    const auto p = text.find(from);
    REQUIRE(p != std::string::npos);
    text.replace(p, from.size(), to);
    try {
      host::parse_inspection_record(text, "rec.yaml", cfg.panel_types);
    } catch (const host::RecordInvalid& e) {
      return std::string(e.what());
    }
    return std::string("accepted");
  };
  CHECK(bad("panel_type: door", "panel_type: hood") == "rec.yaml:2:13: panel_type: 'hood' is not configured in panel_types");
  CHECK(bad("units: m", "units: mm") == "rec.yaml:4:8: units: must be m");
  CHECK(bad("  - id: 2", "  - id: 1").find("duplicate defect id 1") != std::string::npos);
  const auto first_mf = good.find("  - [", good.find("macro_features:"));
  const std::string mf_line = good.substr(first_mf, good.find('\n', first_mf) - first_mf);
  const std::string nan = bad(mf_line, "  - [.nan, 0.1, 2.0]");
  CHECK(nan.find("rec.yaml:6:") == 0);
  CHECK(nan.find("macro_features[0]: not a finite number") != std::string::npos);
  const std::string units = bad(mf_line, "  - [150.0, 100.0, 2000.0]");
  CHECK(units.find("units must be metres") != std::string::npos);
  const auto last_mf = good.find("defects:");
  std::string nine = good;
  nine.erase(good.rfind("  - [", last_mf), last_mf - good.rfind("  - [", last_mf));
  try {
    host::parse_inspection_record(nine, "rec.yaml", cfg.panel_types);
    FAIL("a record with 9 MFs of 10 was accepted");
  } catch (const host::RecordInvalid& e) {
    CHECK(std::string(e.what()).find("macro_features: 9 given, panel type 'door' has 10") != std::string::npos);
  }
}

TEST_CASE("a record that does not match the panel: inter-calibration rejected, nothing sprayed, PLC fault, reason recorded") {
  test::TempDir dir;
  const auto rec = dir.path() / "recording";
  std::filesystem::copy(sim_dir() + "/recording", rec, std::filesystem::copy_options::recursive);
  // Another panel type's record: the same layout 10 % larger (a wrong door).
  std::istringstream lines(read_file((rec / "inspection.yaml").string()));
  std::vector<std::string> out_lines;
  std::vector<std::array<double, 3>> mfs;
  std::string line;
  bool in_mfs = false;
  while (std::getline(lines, line)) {
    if (line == "macro_features:") in_mfs = true;
    else if (line == "defects:") in_mfs = false;
    else if (in_mfs) {
      std::array<double, 3> p{};
      char c = 0;
      std::istringstream(line.substr(line.find('[') + 1)) >> p[0] >> c >> p[1] >> c >> p[2];
      mfs.push_back(p);
      line = "@MF" + std::to_string(mfs.size() - 1);
    }
    out_lines.push_back(line);
  }
  REQUIRE(mfs.size() == 10);
  std::array<double, 3> mean{};
  for (const auto& p : mfs)
    for (int k = 0; k < 3; ++k) mean[static_cast<std::size_t>(k)] += p[static_cast<std::size_t>(k)] / 10;
  std::string text;
  for (const auto& l : out_lines) {
    if (l.rfind("@MF", 0) == 0) {
      const auto& p = mfs[std::stoul(l.substr(3))];
      text += "  - [";
      for (int k = 0; k < 3; ++k) {
        const auto u = static_cast<std::size_t>(k);
        text += std::to_string(mean[u] + 1.1 * (p[u] - mean[u])) + (k < 2 ? ", " : "]\n");
      }
    } else {
      text += l + "\n";
    }
  }
  std::ofstream((rec / "inspection.yaml").string()) << text;
  const std::string out = (dir.path() / "out").string();
  const auto r = run_command("cd " + source_path("") + " && " + kMarkcell + " replay " + rec.string() +
                             " --one-predictor -q --out " + out);
  INFO(r.output);
  REQUIRE(r.exit_code == 0);
  const std::string json = read_file(out + "/report.json");
  INFO(json);
  CHECK(json.find("\"status\": \"macro-features of the record and of the panel disagree\"") != std::string::npos);
  CHECK(json.find("\"fault\": true") != std::string::npos);
  CHECK(json_number(json, "defects", "sprayed") == 0);
  CHECK(json_number(json, "defects", "skipped") == 3);
  CHECK(json.find("inter-calibration failed or above its limit") != std::string::npos);
  CHECK(read_file(out + "/commands.log").find("valve open") == std::string::npos);
}

TEST_CASE("the whole cell marking a panel (vision, marking, arm link, valve, PLC) allocates nothing once started") {
  // The short recording's frames decoded into memory first: the measured part must not
  // decode images (the recording's loader is a device twin that allocates).
  const auto rec = vision::Recording::open(sim_dir() + "/recording");
  std::vector<vision::MemoryFrameSource::Pair> pairs;
  for (std::size_t i = 0; i < rec.size(); ++i) {
    auto f = rec.read(i);
    REQUIRE_FALSE(f.dropped);
    pairs.push_back({f.seq, f.time - rec.entry(0).time, f.left, f.right});
  }
  auto cfg = host::load_config(source_path("config/cell.example.yaml"), host::task_catalog());
  cfg.watchdog.systemd = false;
  cfg.executive.lock_memory = false;
  for (auto& lane : cfg.executive.lanes) lane.priority = 0, lane.core = -1;
  host::Cell cell(cfg, host::ClockKind::kSimulated);
  cell.use_frame_source(std::make_unique<vision::MemoryFrameSource>(std::move(pairs), cfg.cameras.latency));
  const auto job = host::read_inspection_record(sim_dir() + "/recording/inspection.yaml", cfg.panel_types);
  cell.start();
  REQUIRE(cell.marking()->offer_job(job));
  cell.sim_gpio()->drive_physical(cell.gpio_line(host::LineRole::kPlcPanelPresent), true);
  // The search, the inter-calibration and the planning happen in the first frames.
  REQUIRE(cell.sim_clock()->run_until(millis(400)) == control::SimClock::RunResult::kReached);
  REQUIRE(cell.marking()->state() == control::MarkingState::kApproach);
  std::size_t allocations = 0;
  {
    test::AllocationGuard guard;
    REQUIRE(cell.sim_clock()->run_until(millis(3000)) == control::SimClock::RunResult::kReached);
    allocations = guard.allocations();
  }
  const auto& result = cell.marking()->current();
  int sprayed = 0;
  for (int i = 0; i < result.defect_count; ++i) sprayed += result.defects[static_cast<std::size_t>(i)].sprayed ? 1 : 0;
  CHECK(sprayed == 3);
  CHECK(cell.sim_spray_count() == 3);
  CHECK(allocations == 0);
  cell.shutdown(control::FaultCode::kShutdown, "test", "done");
}

TEST_CASE("a panel's result is written and synced before the PLC hears done; without it the PLC gets fault") {
  const auto rec = vision::Recording::open(sim_dir() + "/recording");
  auto pairs = [&] {
    std::vector<vision::MemoryFrameSource::Pair> p;
    for (std::size_t i = 0; i < rec.size(); ++i) {
      auto f = rec.read(i);
      p.push_back({f.seq, f.time - rec.entry(0).time, f.left, f.right});
    }
    return p;
  };
  test::TempDir dir;
  auto cfg = host::load_config(source_path("config/cell.example.yaml"), host::task_catalog());
  cfg.watchdog.systemd = false;
  cfg.executive.lock_memory = false;
  for (auto& lane : cfg.executive.lanes) lane.priority = 0, lane.core = -1;
  cfg.results_file = (dir.path() / "results.jsonl").string();
  const auto job = host::read_inspection_record(sim_dir() + "/recording/inspection.yaml", cfg.panel_types);
  for (const bool write : {true, false}) {
    CAPTURE(write);
    host::Cell cell(cfg, host::ClockKind::kSimulated);
    cell.use_frame_source(std::make_unique<vision::MemoryFrameSource>(pairs(), cfg.cameras.latency));
    cell.start();
    REQUIRE(cell.marking()->offer_job(job));
    cell.sim_gpio()->drive_physical(cell.gpio_line(host::LineRole::kPlcPanelPresent), true);
    control::SimClock& clock = *cell.sim_clock();
    Nanos t = 0;
    while (cell.marking()->panels_completed() == 0 && t < seconds(10)) clock.run_until(t += millis(10));
    REQUIRE(cell.marking()->panels_completed() == 1);
    bool done = true, fault = true;
    auto lines = [&] {
      cell.gpio().get(cell.gpio_line(host::LineRole::kPlcDone), done);
      cell.gpio().get(cell.gpio_line(host::LineRole::kPlcFault), fault);
    };
    lines();
    CHECK(cell.marking()->state() == control::MarkingState::kReporting);
    CHECK_FALSE(done);  // nothing on disk yet: the PLC waits
    CHECK_FALSE(fault);
    cell.marking()->results().update();
    const control::PanelResult r = cell.marking()->results().read();
    if (write) {
      host::ResultsFile file(cfg.results_file);
      file.append(host::ResultsFile::to_json(r, cfg.name));
      cell.marking()->acknowledge_result(r.serial);
      clock.run_until(t + millis(10));
      lines();
      CHECK(done);
      CHECK_FALSE(fault);
      const std::string text = read_file(cfg.results_file);
      CHECK(text.find("\"panel_id\": \"paper-door-1\"") != std::string::npos);
      CHECK(text.find("\"fault\": false") != std::string::npos);
      CHECK(text.find("{\"id\": 3, \"sprayed\": true") != std::string::npos);
      CHECK(text.back() == '\n');
    } else {
      clock.run_until(t + seconds(3));  // past the 2 s the sequence waits for the result
      lines();
      CHECK_FALSE(done);
      CHECK(fault);
      CHECK(cell.marking()->current().reason.view() == "results file not written in time");
    }
    cell.shutdown(control::FaultCode::kShutdown, "test", "done");
  }
}

TEST_CASE("defects the arm cannot reach are planned out at once, reported with the reason, never attempted") {
  test::TempDir dir;
  std::filesystem::copy(source_path("config"), dir.path() / "config", std::filesystem::copy_options::recursive);
  const auto cfg = dir.path() / "config" / "cell.example.yaml";
  std::string text = read_file(cfg.string());
  const auto at = text.find("reach_m: 1.6");
  REQUIRE(at != std::string::npos);
  text.replace(at, 12, "reach_m: 0.9");  // the dings' spraying poses are 1.1 to 1.3 m from the base
  std::ofstream(cfg.string()) << text;
  const std::string out = (dir.path() / "out").string();
  const auto r = run_command("cd " + source_path("") + " && " + kMarkcell + " replay " + sim_dir() + "/recording --config " +
                             cfg.string() + " --one-predictor -q --out " + out);
  INFO(r.output);
  REQUIRE(r.exit_code == 0);
  const std::string json = read_file(out + "/report.json");
  INFO(json);
  CHECK(json_number(json, "plan", "feasible") == 0);
  CHECK(json_number(json, "plan", "infeasible") == 3);
  CHECK(json.find("\"verdict\": \"never within the arm's reach\"") != std::string::npos);
  CHECK(json.find("\"matches_run\": true") != std::string::npos);
  CHECK(json_number(json, "defects", "skipped") == 3);
  CHECK(json.find("planned out: not within the arm's reach in its turn (the plan's verdict says why)") != std::string::npos);
  CHECK(read_file(out + "/commands.log").find("valve open") == std::string::npos);
}

TEST_CASE("the record drop folder: records taken in name order, bad ones and duplicates rejected with the reason and kept") {
  const auto cfg = host::load_config(source_path("config/cell.example.yaml"), host::task_catalog());
  test::TempDir dir;
  const std::string good = read_file(sim_dir() + "/recording/inspection.yaml");
  const auto drop = dir.path() / "drop";
  std::filesystem::create_directories(drop);
  host::RecordFolder folder(drop.string(), cfg.panel_types);
  std::vector<std::string> offered;
  bool busy = false;
  const auto offer = [&](const control::PanelJob& job) {
    if (busy) return false;
    offered.emplace_back(job.panel_id.view());
    return true;
  };
  CHECK_FALSE(folder.poll(offer).has_value());  // empty

  std::ofstream((drop / "0002.yaml").string()) << good;
  std::ofstream((drop / "0001.yaml.part").string()) << good.substr(0, good.size() / 2);  // still being written
  busy = true;
  CHECK_FALSE(folder.poll(offer).has_value());  // the sequence holds a record: it waits
  CHECK(std::filesystem::exists(drop / "0002.yaml"));
  busy = false;
  auto ev = folder.poll(offer);
  REQUIRE(ev.has_value());
  CHECK(ev->kind == host::RecordEvent::Kind::kAccepted);
  CHECK(ev->file == (drop / "accepted" / "0002.yaml").string());
  REQUIRE(offered.size() == 1);
  CHECK(std::filesystem::exists(drop / "accepted" / "0002.yaml"));

  // The same panel again, and a record with a broken field.
  std::ofstream((drop / "0003.yaml").string()) << good;
  std::string bad = good;
  const auto units = bad.find("units: m");
  REQUIRE(units != std::string::npos);
  bad.replace(units, 8, "units: mm");
  std::ofstream((drop / "0004.yaml").string()) << bad;
  ev = folder.poll(offer);
  REQUIRE(ev.has_value());
  CHECK(ev->kind == host::RecordEvent::Kind::kRejected);
  CHECK(ev->reason.find("0003.yaml: panel_id: '" + offered[0] + "' was already received (a duplicate record)") != std::string::npos);
  CHECK(read_file((drop / "rejected" / "0003.yaml.reason").string()) == ev->reason + "\n");
  ev = folder.poll(offer);
  REQUIRE(ev.has_value());
  CHECK(ev->kind == host::RecordEvent::Kind::kRejected);
  INFO(ev->reason);
  CHECK(ev->reason.rfind((drop / "0004.yaml").string() + ":", 0) == 0);
  CHECK(ev->reason.find("units") != std::string::npos);
  CHECK(std::filesystem::exists(drop / "rejected" / "0004.yaml"));
  CHECK(offered.size() == 1);  // neither was offered
  CHECK_FALSE(folder.poll(offer).has_value());  // the .part file is not a record
}

TEST_CASE("a panel without an inspection record: PLC fault after the record timeout, the arm never moves, the result says so") {
  auto cfg = host::load_config(source_path("config/cell.example.yaml"), host::task_catalog());
  cfg.watchdog.systemd = false;
  cfg.executive.lock_memory = false;
  for (auto& lane : cfg.executive.lanes) lane.priority = 0, lane.core = -1;
  REQUIRE(cfg.marking.record_timeout == seconds(5));
  host::Cell cell(cfg, host::ClockKind::kSimulated);
  cell.use_frame_source(std::make_unique<vision::MemoryFrameSource>(std::vector<vision::MemoryFrameSource::Pair>{}, cfg.cameras.latency));
  cell.start();
  control::SimClock& clock = *cell.sim_clock();
  Nanos t = 0;
  clock.run_until(t += seconds(1));
  const auto home = cell.sim_arm()->model().tool().position;
  cell.sim_gpio()->drive_physical(cell.gpio_line(host::LineRole::kPlcPanelPresent), true);
  clock.run_until(t += seconds(4));
  CHECK(cell.marking()->panels_completed() == 0);  // still within the timeout
  clock.run_until(t += seconds(2));
  REQUIRE(cell.marking()->panels_completed() == 1);
  bool fault = false, done = true;
  cell.gpio().get(cell.gpio_line(host::LineRole::kPlcFault), fault);
  cell.gpio().get(cell.gpio_line(host::LineRole::kPlcDone), done);
  CHECK(fault);
  CHECK_FALSE(done);
  cell.marking()->results().update();
  const control::PanelResult r = cell.marking()->results().read();
  CHECK(r.fault);
  CHECK(r.reason.view() == "panel present without an inspection record");
  CHECK(r.panel_id.view() == "(no record)");
  CHECK(r.defect_count == 0);
  CHECK(cell.sim_arm()->model().tool().position == home);
  CHECK(cell.sim_spray_count() == 0);
  cell.shutdown(control::FaultCode::kShutdown, "test", "done");
}
