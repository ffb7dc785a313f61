// The cell as the service runs it, through the rig's short door recording: inspection
// records read and refused with their file, line and field; the record drop folder, also
// against hostile input; a panel without a record and a record without a panel; each
// result on disk before the PLC hears it; `markcell run` on the simulated clock with a
// scripted PLC, killed mid-panel and restarted, and ending with exit 1 on a fault of the
// cell itself.
#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <cmath>
#include <sys/stat.h>
#include <algorithm>
#include <array>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <vector>
#include <string>

#include "markcell/host/config.hpp"
#include "markcell/host/cell.hpp"
#include "markcell/host/inspection_record.hpp"
#include "markcell/host/pose_log.hpp"
#include "markcell/host/record_folder.hpp"
#include "markcell/common/file_history.hpp"
#include "markcell/host/results_file.hpp"
#include "markcell/rig/scoring.hpp"
#include "markcell/control/tool_pose.hpp"
#include "alloc_guard.hpp"
#include "markcell/vision/frame_source.hpp"
#include "markcell/vision/recording.hpp"
#include "markcell/rig/render.hpp"
#include "sim_helpers.hpp"
#include "test_files.hpp"

using namespace markcell;
using namespace markcell::test;  // the helpers, the files, the example configuration

TEST_CASE("inspection records: every bad field is rejected with its file, line and what is wrong") {
  const auto cfg = host::load_config(source_path("config/cell.example.yaml"), host::task_catalog());
  const std::string good = read_file(sim_dir() + "/recording/inspection.yaml");
  const auto job = host::parse_inspection_record(good, "inspection.yaml", cfg.panel_types);
  CHECK(job.mfs_SL.size() == 10);
  CHECK(job.defects.ssize() == 3);
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
  // A defect map without its points (found by fuzz_record: a missing key of a read-only
  // yaml-cpp node is invalid, and asking its type threw past the record's own errors).
  const std::string no_points = bad("  - id: 2\n    points:", "  - id: 2\n    pints:");
  CHECK(no_points.find("unknown key (known: id, points)") != std::string::npos);
  const std::string missing = bad("  - id: 2\n    points:", "  - {id: 2}\n  - id: 9\n    points:");
  CHECK(missing.find("rec.yaml:") == 0);
  CHECK(missing.find("defects[1].points: expected a non-empty list of [x, y, z]") != std::string::npos);
  const auto first_mf = good.find("  - [", good.find("macro_features:"));
  const std::string mf_line = good.substr(first_mf, good.find('\n', first_mf) - first_mf);
  const std::string nan = bad(mf_line, "  - [.nan, 0.1, 2.0]");
  CHECK(nan.find("rec.yaml:7:") == 0);  // (line 6: the comment above macro_features)
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

TEST_CASE("a panel's result is written and synced before the PLC hears done, without it fault, and a late line says so") {
  const auto rec = vision::Recording::open(sim_dir() + "/recording");
  const auto pairs = [&] { return decoded_pairs(rec); };
  test::TempDir dir;
  auto cfg = in_process_config();
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
      file.append(host::ResultsFile::to_json(r, cfg.name, host::UtcClock{true}));
      CHECK(cell.marking()->acknowledge_result(r.serial));  // in time
      CHECK(cell.marking()->acknowledge_result(r.serial));  // (said twice: the same answer)
      clock.run_until(t + millis(10));
      lines();
      CHECK(done);
      CHECK_FALSE(fault);
      const std::string text = read_file(cfg.results_file);
      CHECK(text.back() == '\n');
      const auto line = parse_json(text);
      CHECK(line["panel_id"] == "paper-door-1");
      CHECK(line["fault"] == false);
      REQUIRE(line["defects"].size() == 3);
      CHECK(line["defects"][2]["id"] == 3);
      CHECK(line["defects"][2]["sprayed"] == true);
    } else {
      clock.run_until(t + seconds(3));  // past the 2 s the sequence waits for the result
      lines();
      CHECK_FALSE(done);
      CHECK(fault);
      CHECK(cell.marking()->current().reason.view() == "results file not written in time");
      // The line reaching the disk after that: the acknowledgement says it is too late, and
      // the writer's late line makes the file's last word on the panel the PLC's fault.
      host::ResultsFile file(cfg.results_file);
      file.append(host::ResultsFile::to_json(r, cfg.name, host::UtcClock{true}));
      CHECK_FALSE(cell.marking()->acknowledge_result(r.serial));
      file.append(host::ResultsFile::late_json(cfg.name, "1970-01-01T00:00:04.000Z", r.serial, std::string(r.panel_id.view())));
      clock.run_until(t + seconds(4));
      lines();
      CHECK_FALSE(done);  // the PLC's answer stands
      CHECK(fault);
      const auto written = lines_of(read_file(cfg.results_file));
      REQUIRE(written.size() >= 2);  // the result, then the late line last
      CHECK(parse_json(written[written.size() - 2])["panel_id"] == "paper-door-1");
      const auto last = parse_json(written.back());
      CHECK(last["panel_id"] == "paper-door-1");
      CHECK(last["late"] == true);
      CHECK(last["fault"] == true);
    }
    cell.shutdown(control::FaultCode::kShutdown, "test", "done");
  }
}

TEST_CASE("the record drop folder: records taken in name order, bad ones and duplicates rejected with the reason and kept") {
  const auto cfg = host::load_config(source_path("config/cell.example.yaml"), host::task_catalog());
  test::TempDir dir;
  const std::string good = read_file(sim_dir() + "/recording/inspection.yaml");
  REQUIRE(good.size() > 4);
  REQUIRE(good.substr(good.size() - 4) == "...\n");  // the rig's records end with YAML's end marker
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
  Nanos now = 0;
  const auto poll = [&] { return folder.poll(offer, now += millis(50)); };
  CHECK(poll().empty());  // empty

  std::ofstream((drop / "0002.yaml").string()) << good;
  std::ofstream((drop / "0001.yaml.part").string()) << good.substr(0, good.size() / 2);  // still being written
  busy = true;
  CHECK(poll().empty());  // new: read once unchanged at the next poll
  CHECK(poll().empty());  // the sequence holds a record: it waits, parsed
  CHECK(std::filesystem::exists(drop / "0002.yaml"));
  busy = false;
  auto ev = poll();
  REQUIRE(ev.size() == 1);
  CHECK(ev[0].kind == host::RecordEvent::Kind::kAccepted);
  CHECK(ev[0].file == (drop / "accepted" / "0002.yaml").string());
  REQUIRE(offered.size() == 1);
  CHECK(std::filesystem::exists(drop / "accepted" / "0002.yaml"));

  // The same panel again, and a record with a broken field: both rejected in one poll.
  std::ofstream((drop / "0003.yaml").string()) << good;
  std::string bad = good;
  const auto units = bad.find("units: m");
  REQUIRE(units != std::string::npos);
  bad.replace(units, 8, "units: mm");
  std::ofstream((drop / "0004.yaml").string()) << bad;
  CHECK(poll().empty());
  ev = poll();
  REQUIRE(ev.size() == 2);
  CHECK(ev[0].kind == host::RecordEvent::Kind::kRejected);
  CHECK(ev[0].reason.find("0003.yaml: panel_id: '" + offered[0] + "' was already received (a duplicate record)") != std::string::npos);
  CHECK(ev[0].panel_id == offered[0]);  // (the rejected line names the panel it repeats)
  CHECK(read_file((drop / "rejected" / "0003.yaml.reason").string()) == ev[0].reason + "\n");
  CHECK(ev[1].kind == host::RecordEvent::Kind::kRejected);
  INFO(ev[1].reason);
  CHECK(ev[1].reason.rfind((drop / "0004.yaml").string() + ":", 0) == 0);
  CHECK(ev[1].reason.find("units") != std::string::npos);
  CHECK(std::filesystem::exists(drop / "rejected" / "0004.yaml"));
  CHECK(offered.size() == 1);  // neither was offered
  CHECK(poll().empty());  // the .part file is not a record
}

TEST_CASE("the record drop folder against hostile input: links, FIFOs, folders, huge or unfinished files, junk ahead of a record") {
  const auto cfg = host::load_config(source_path("config/cell.example.yaml"), host::task_catalog());
  test::TempDir dir;
  const std::string good = read_file(sim_dir() + "/recording/inspection.yaml");
  const auto drop = dir.path() / "drop";
  std::filesystem::create_directories(drop);
  host::RecordFolder folder(drop.string(), cfg.panel_types, seconds(1));
  std::vector<std::string> offered;
  const auto offer = [&](const control::PanelJob& job) {
    offered.emplace_back(job.panel_id.view());
    return true;
  };
  Nanos now = 0;
  const auto poll = [&] { return folder.poll(offer, now += millis(50)); };
  const auto reason_of = [&](const std::vector<host::RecordEvent>& events, const std::string& name) {
    for (const auto& e : events)
      if (e.file.find("/rejected/" + name) != std::string::npos) return e.reason;
    return std::string("(not rejected)");
  };
  std::filesystem::create_symlink("/etc/passwd", drop / "0001.yaml");
  REQUIRE(::mkfifo((drop / "0002.yaml").c_str(), 0600) == 0);
  std::filesystem::create_directories(drop / "0003.yaml");
  std::filesystem::create_symlink(drop / "missing", drop / "0004.yaml");  // dangling
  std::ofstream((drop / "0005.yaml").string()) << std::string(host::RecordFolder::kMaxRecordBytes + 1, '#');
  std::string extra = good;
  extra.insert(0, "junk: [1, 2, 3]\n");
  std::ofstream((drop / "0006.yaml").string()) << extra;
  std::ofstream((drop / "0007.yaml").string()) << std::string(5000, '[') << "\n...\n";
  std::string bad_id = good;
  bad_id.replace(bad_id.find("panel_id: ") + 10, 0, "p7\\n<6>markcell: panel=x result=done ");
  bad_id.replace(bad_id.find("panel_id: ") + 10, 0, "\"");
  bad_id.insert(bad_id.find('\n', bad_id.find("panel_id: ")), "\"");
  std::ofstream((drop / "0008.yaml").string()) << bad_id;
  std::ofstream((drop / "0009.yaml").string()) << good;
  auto ev = poll();  // the ones that are no regular file at once; the others once unchanged
  CHECK(reason_of(ev, "0001.yaml").find("0001.yaml: a symbolic link, not read") != std::string::npos);
  CHECK(reason_of(ev, "0002.yaml").find("0002.yaml: a FIFO, not read") != std::string::npos);
  CHECK(reason_of(ev, "0003.yaml").find("0003.yaml: a directory, not read") != std::string::npos);
  CHECK(reason_of(ev, "0004.yaml").find("0004.yaml: a symbolic link, not read") != std::string::npos);
  CHECK(reason_of(ev, "0005.yaml").find("0005.yaml: 1048577 bytes, more than the 1048576 allowed for an inspection record") !=
        std::string::npos);
  CHECK(std::filesystem::exists("/etc/passwd"));
  ev = poll();
  CHECK(reason_of(ev, "0006.yaml").find("0006.yaml:1:1: junk: unknown key (known: panel_id, panel_type, frame, units, "
                                        "macro_features, macro_feature_quality, defects)") != std::string::npos);
  CHECK(reason_of(ev, "0007.yaml").find("0007.yaml:1: nested deeper than an inspection record is") != std::string::npos);
  CHECK(reason_of(ev, "0008.yaml").find("panel_id: character 3 (0x0a, a control character) is not allowed") != std::string::npos);
  // ... and the valid record behind them all is taken in the same poll.
  REQUIRE(offered.size() == 1);
  CHECK(std::filesystem::exists(drop / "accepted" / "0009.yaml"));

  // A record written in place, its writer pausing after the first defect: it waits (no
  // end marker), then is rejected, never half-used.
  std::string next = good;
  next.replace(next.find("panel_id: ") + 10, next.find('\n', next.find("panel_id: ")) - next.find("panel_id: ") - 10, "door-2");
  std::ofstream((drop / "0010.yaml").string()) << next.substr(0, next.find("points:") + 8);
  for (int i = 0; i < 10; ++i) CHECK(poll().empty());  // 0.5 s: waiting for the rest
  // Finished in time, it is taken whole.
  std::ofstream((drop / "0010.yaml").string()) << next;
  CHECK(poll().empty());
  ev = poll();
  REQUIRE(ev.size() == 1);
  CHECK(ev[0].kind == host::RecordEvent::Kind::kAccepted);
  // The station's counter restarts: the same file name again does not overwrite accepted/0010.yaml.
  next.replace(next.find("door-2"), 6, "door-3");
  std::ofstream((drop / "0010.yaml").string()) << next.substr(0, next.size() - 4);  // no end marker, for good
  for (int i = 0; i < 22 && ev.size() != 0; ++i) ev = poll();
  for (int i = 0; i < 22 && ev.empty(); ++i) ev = poll();
  REQUIRE(ev.size() == 1);
  CHECK(ev[0].reason.find("0010.yaml: incomplete: its last line is not YAML's end-of-document marker '...'") != std::string::npos);
  CHECK(ev[0].file == (drop / "rejected" / "0010.yaml").string());
  next.replace(next.find("door-3"), 6, "door-4");
  std::ofstream((drop / "0010.yaml").string()) << next;
  // rejected/ removed while running does not stick the queue either.
  std::filesystem::remove_all(drop / "rejected");
  std::ofstream((drop / "0009.yaml").string()) << "not: a record\n...\n";
  poll();
  ev = poll();
  REQUIRE(ev.size() == 2);
  CHECK(ev[0].kind == host::RecordEvent::Kind::kRejected);
  CHECK(ev[1].kind == host::RecordEvent::Kind::kAccepted);
  CHECK(ev[1].file == (drop / "accepted" / "0010.1.yaml").string());
  CHECK(std::filesystem::exists(drop / "accepted" / "0010.yaml"));

  // 200 junk files ahead of a record: cleared within a few polls, the record taken then.
  for (int i = 0; i < 200; ++i) {
    char name[32];
    std::snprintf(name, sizeof name, "1%03d.yaml", i);
    std::ofstream((drop / name).string()) << "junk\n...\n";
  }
  next.replace(next.find("door-4"), 6, "door-5");
  std::ofstream((drop / "2000.yaml").string()) << next;
  int polls = 0;
  const std::size_t before = offered.size();
  while (offered.size() == before && polls < 20) {
    poll();
    ++polls;
  }
  CHECK(offered.size() == before + 1);
  CHECK(polls <= 5);  // 250 ms at the service's 50 ms poll
}

TEST_CASE("a panel without an inspection record: PLC fault after the record timeout, the arm never moves, the result says so") {
  auto cfg = in_process_config();
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
  CHECK(r.defects.ssize() == 0);
  CHECK(cell.sim_arm()->model().tool().position == home);
  CHECK(cell.sim_nozzle()->kept() == 0);
  // The panel leaves: the PLC's fault line drops, ready for the next panel.
  cell.sim_gpio()->drive_physical(cell.gpio_line(host::LineRole::kPlcPanelPresent), false);
  clock.run_until(t += millis(100));
  cell.gpio().get(cell.gpio_line(host::LineRole::kPlcFault), fault);
  CHECK_FALSE(fault);
  CHECK(cell.marking()->state() == control::MarkingState::kIdle);
  cell.shutdown(control::FaultCode::kShutdown, "test", "done");
}

TEST_CASE("a record without a panel expires: its result a fault with the reason, the PLC's fault held until the next panel") {
  auto cfg = in_process_config();
  REQUIRE(cfg.marking.record_expiry == seconds(300));
  cfg.marking.record_expiry = seconds(20);
  host::Cell cell(cfg, host::ClockKind::kSimulated);
  cell.use_frame_source(std::make_unique<vision::MemoryFrameSource>(std::vector<vision::MemoryFrameSource::Pair>{}, cfg.cameras.latency));
  cell.start();
  auto job = host::read_inspection_record(sim_dir() + "/recording/inspection.yaml", cfg.panel_types);
  REQUIRE(cell.marking()->offer_job(job));
  control::SimClock& clock = *cell.sim_clock();
  const auto line = [&](host::LineRole role) {
    bool v = false;
    cell.gpio().get(cell.gpio_line(role), v);
    return v;
  };
  Nanos t = 0;
  clock.run_until(t += seconds(19));
  CHECK(cell.marking()->panels_completed() == 0);  // still waiting for its panel
  clock.run_until(t += seconds(2));
  REQUIRE(cell.marking()->panels_completed() == 1);
  cell.marking()->results().update();
  const control::PanelResult r = cell.marking()->results().read();
  CHECK(r.fault);
  CHECK(r.panel_id.view() == job.panel_id.view());
  CHECK(r.reason.view() == "inspection record expired: its panel never came");
  REQUIRE(r.defects.ssize() == 3);
  for (int i = 0; i < 3; ++i) CHECK(r.defects[static_cast<std::size_t>(i)].skipped == control::SkipReason::kNoPanel);
  CHECK(cell.sim_nozzle()->kept() == 0);
  clock.run_until(t += seconds(5));
  CHECK(line(host::LineRole::kPlcFault));  // no panel to release it: held
  CHECK_FALSE(line(host::LineRole::kPlcDone));
  CHECK(cell.marking()->can_offer());  // the mailbox is free for the next record
  // The next panel with its record: the fault drops as it starts.
  job.panel_id.assign("paper-door-2");
  REQUIRE(cell.marking()->offer_job(job));
  cell.sim_gpio()->drive_physical(cell.gpio_line(host::LineRole::kPlcPanelPresent), true);
  clock.run_until(t += millis(100));
  CHECK_FALSE(line(host::LineRole::kPlcFault));
  CHECK(line(host::LineRole::kPlcBusy));
  cell.shutdown(control::FaultCode::kShutdown, "test", "done");
}

TEST_CASE("run as the service on the simulated clock: PLC script, drop-folder record, the panel marked and its result on disk") {
  test::TempDir dir;
  // The panel is present from the start and leaves with the recording's end (3 s).
  const ServiceCell s = service_cell(dir, "# t  line  level\n0.0 plc_panel_present 1\n3.2 plc_panel_present 0  # leaves\n");
  std::filesystem::copy_file(sim_dir() + "/recording/inspection.yaml", s.drop / "0001.yaml");
  const auto r = run_command(kMarkcell + " run --config " + s.config.string() + " --clock sim --seconds 6 --plc-script " +
                             s.script.string());
  INFO(r.output);
  REQUIRE(r.exit_code == 0);
  CHECK(r.output.find("<6>markcell: plc-script t=3.200 s plc_panel_present=0") != std::string::npos);
  CHECK(r.output.find("<6>markcell: record panel=paper-door-1 accepted") != std::string::npos);
  CHECK(r.output.find("<6>markcell: panel=paper-door-1 result=done sprayed=3 skipped=0") != std::string::npos);
  CHECK(std::filesystem::exists(s.drop / "accepted" / "0001.yaml"));
  const auto lines = lines_of(read_file(s.results.string()));
  REQUIRE(lines.size() == 2);
  // A simulated run's UTC is the simulated clock from the epoch (the same bytes each run).
  CHECK(parse_json(lines[0]) == nlohmann::ordered_json{{"cell", "marking-station-sim"},
                                                        {"utc", "1970-01-01T00:00:00.200Z"},  // the loop's 2nd step
                                                        {"record", (s.drop / "accepted" / "0001.yaml").string()},
                                                        {"panel_id", "paper-door-1"},
                                                        {"accepted", true}});
  const auto result = parse_json(lines[1]);
  CHECK(result["panel_id"] == "paper-door-1");
  CHECK(result["fault"] == false);
  const auto ms_of = [](double secs) { return static_cast<std::int64_t>(std::floor(secs * 1000 + 1e-6)); };
  CHECK(result["started_utc"] == markcell::utc_iso8601_ms(ms_of(result["started_s"].get<double>()) * 1'000'000));
  CHECK(result["finished_utc"] == markcell::utc_iso8601_ms(ms_of(result["finished_s"].get<double>()) * 1'000'000));
  REQUIRE(result["defects"].size() == 3);
  for (int id = 1; id <= 3; ++id) {
    CHECK(result["defects"][static_cast<std::size_t>(id - 1)]["id"] == id);
    CHECK(result["defects"][static_cast<std::size_t>(id - 1)]["sprayed"] == true);
  }
  // The pose log: one line per frame pair the vision task took (the recording's 3 s at 10
  // frames a second), each with its MFs.
  const auto poses = lines_of(read_file((s.poses / "poses.csv").string()));
  const auto tracks = lines_of(read_file((s.poses / "mf_tracks.csv").string()));
  REQUIRE(poses.size() > 20);
  CHECK(poses[0] + "\n" == host::PoseLog::kPosesHeader);
  CHECK(tracks[0] + "\n" == host::PoseLog::kTracksHeader);
  CHECK(tracks.size() - 1 == 10 * (poses.size() - 1));  // the door's 10 MFs per frame pair
  CHECK(std::count_if(poses.begin(), poses.end(), [](const std::string& l) { return l.find(",tracking,") != std::string::npos; }) > 20);

  // The next panel's e-stop mid-sequence: the fault logged as it happens, the panel's
  // result a fault with nothing sprayed after it, the valve closed.
  std::string second = read_file(sim_dir() + "/recording/inspection.yaml");
  second.replace(second.find("panel_id: paper-door-1"), 22, "panel_id: paper-door-2");
  std::ofstream((s.drop / "0002.yaml").string()) << second;
  std::ofstream(s.script.string()) << "0.0 plc_panel_present 1\n0.6 plc_estop 1\n";
  const auto stop = run_command(kMarkcell + " run --config " + s.config.string() + " --clock sim --seconds 3 --plc-script " +
                                s.script.string());
  INFO(stop.output);
  REQUIRE(stop.exit_code == 0);
  CHECK(stop.output.find("<3>markcell: fault t=0.60") != std::string::npos);
  CHECK(stop.output.find(" utc=1970-01-01T00:00:00.60") != std::string::npos);
  CHECK(stop.output.find("code=operator_stop source=plc_estop detail=\"e-stop input active\"") != std::string::npos);
  CHECK(stop.output.find("<3>markcell: panel=paper-door-2 result=fault sprayed=0 skipped=3 reason=\"safe stop during the marking sequence\"") !=
        std::string::npos);
  const auto after_stop = lines_of(read_file(s.results.string()));
  REQUIRE(after_stop.size() == 4);
  // The service's pose log is appended to across restarts, its header written once.
  const auto poses_after = lines_of(read_file((s.poses / "poses.csv").string()));
  CHECK(poses_after.size() > poses.size());
  CHECK(std::equal(poses.begin(), poses.end(), poses_after.begin()));
  CHECK(std::count(poses_after.begin(), poses_after.end(), poses[0]) == 1);
  const auto stopped = parse_json(after_stop[3]);
  CHECK(stopped["panel_id"] == "paper-door-2");
  CHECK(stopped["fault"] == true);
  for (const auto& d : stopped["defects"]) CHECK(d["sprayed"] == false);

  // A PLC script with a mistake is refused before anything starts, naming file and line.
  std::ofstream(s.script.string()) << "0.0 plc_panel_present 1\n0.5 plc_panel_presnt 0\n";
  const auto bad = run_command(kMarkcell + " run --config " + s.config.string() + " --clock sim --seconds 1 --plc-script " +
                               s.script.string());
  CHECK(bad.exit_code == 2);
  CHECK(bad.output.find(s.script.string() + ":2: line 'plc_panel_presnt' is not a PLC input") != std::string::npos);
  std::ofstream(s.script.string()) << "1.0 plc_panel_present 1\n0.5 plc_estop 1\n";
  const auto order = run_command(kMarkcell + " run --config " + s.config.string() + " --clock sim --seconds 1 --plc-script " +
                                 s.script.string());
  CHECK(order.exit_code == 2);
  CHECK(order.output.find(s.script.string() + ":2: time 0.5 s is before the previous event's") != std::string::npos);
  CHECK(lines_of(read_file(s.results.string())) == after_stop);  // nothing written by a refused start
}

TEST_CASE("killed with SIGKILL mid-panel and restarted: earlier results intact, the panel recorded as interrupted, its id a duplicate") {
  test::TempDir dir;
  const ServiceCell s = service_cell(dir, "0.0 plc_panel_present 1\n");
  {
    // On the real clock, under the sanitizers, on a shared machine a task may overrun its
    // budget; this test is about the crash, not the timing: overruns are only logged.
    std::string text = read_file(s.config.string());
    for (auto at = text.find("on_overrun: safe_stop"); at != std::string::npos; at = text.find("on_overrun: safe_stop", at))
      text.replace(at, 21, "on_overrun: log");
    std::ofstream(s.config.string()) << text;
  }
  // An earlier result, and a line a power cut tore (no newline).
  const std::string earlier = "{\"cell\": \"marking-station-sim\", \"panel\": 1, \"panel_id\": \"door-0\", \"fault\": false}\n";
  std::ofstream(s.results.string()) << earlier << "{\"cell\": \"marking-station-sim\", \"panel\": 2, \"panel_id\": \"do";
  std::filesystem::copy_file(sim_dir() + "/recording/inspection.yaml", s.drop / "0001.yaml");
  const std::string log = (dir.path() / "log").string();
  // Real clock: the record is taken within 50 ms; the kill comes as soon as the log says
  // so, while the panel's macro-features are being found (the recording lasts 3 s).
  const auto killed = run_command("( " + kMarkcell + " run --config " + s.config.string() + " --plc-script " + s.script.string() +
                                  " > " + log + " 2>&1 & pid=$!; for i in $(seq 600); do grep -q 'record panel=paper-door-1 accepted' " +
                                  log + " && break; sleep 0.05; done; kill -KILL $pid; wait $pid; echo \"exit=$?\"; cat " + log + " )");
  INFO(killed.output);
  REQUIRE(killed.output.find("exit=137") != std::string::npos);
  REQUIRE(killed.output.find("result=done") == std::string::npos);  // killed before the panel's end
  std::string text = read_file(s.results.string());
  REQUIRE(text.rfind(earlier, 0) == 0);

  // The restart ends the torn line, answers the accepted record with an interrupted
  // fault, and knows the panel id: the same record again is a duplicate.
  std::filesystem::copy_file(sim_dir() + "/recording/inspection.yaml", s.drop / "0002.yaml");
  const auto again = run_command(kMarkcell + " run --config " + s.config.string() + " --clock sim --seconds 1");
  INFO(again.output);
  REQUIRE(again.exit_code == 0);
  CHECK(again.output.find("<3>markcell: panel=paper-door-1 result=fault reason=\"interrupted: markcell stopped after accepting its record and before its result\"") !=
        std::string::npos);
  CHECK(again.output.find("0002.yaml: panel_id: 'paper-door-1' was already received (a duplicate record)") != std::string::npos);
  text = read_file(s.results.string());
  CHECK(text.rfind(earlier, 0) == 0);  // untouched
  const auto lines = lines_of(text);
  REQUIRE(lines.size() == 5);
  CHECK(lines[1] == "{\"cell\": \"marking-station-sim\", \"panel\": 2, \"panel_id\": \"do");  // torn, ended, left as it was
  CHECK(parse_json(lines[2])["panel_id"] == "paper-door-1");
  CHECK(parse_json(lines[2])["accepted"] == true);
  CHECK(parse_json(lines[3]) == nlohmann::ordered_json{{"cell", "marking-station-sim"},
                                                       {"utc", "1970-01-01T00:00:00.000Z"},
                                                       {"panel_id", "paper-door-1"},
                                                       {"interrupted", true},
                                                       {"fault", true},
                                                       {"reason", "markcell stopped after accepting the panel's record and "
                                                                  "before its result"}});
  CHECK(parse_json(lines[4]).contains("rejected"));
  CHECK(std::filesystem::exists(s.drop / "rejected" / "0002.yaml"));

  // A third start finds nothing left to answer.
  const auto third = run_command(kMarkcell + " run --config " + s.config.string() + " --clock sim --seconds 1");
  CHECK(third.exit_code == 0);
  CHECK(lines_of(read_file(s.results.string())).size() == 5);
}

TEST_CASE("run as the service: a fault of the cell itself ends it with exit 1 (for systemd to restart), an e-stop does not") {
  test::TempDir dir;
  const ServiceCell s = service_cell(dir, "0.0 plc_panel_present 0\n");
  // The vision task over a budget it cannot keep, with on_overrun: safe_stop.
  std::string text = read_file(s.config.string());
  const std::string vision = "vision:      {lane: vision,  period_us: 33000, phase_us: 0, budget_us: 30000, on_overrun: log}";
  REQUIRE(text.find(vision) != std::string::npos);
  std::ofstream(s.config.string()) << std::string(text).replace(
      text.find(vision), vision.size(), "vision:      {lane: vision,  period_us: 33000, phase_us: 0, budget_us: 50, on_overrun: safe_stop}");
  const auto r = run_command(kMarkcell + " run --config " + s.config.string() + " --clock real --seconds 20");
  INFO(r.output);
  CHECK(r.exit_code == 1);
  CHECK(r.output.find("<4>markcell: safe stop (task_overrun, vision: ran ") != std::string::npos);
  CHECK(r.output.find("): exiting for a restart") != std::string::npos);
  CHECK(r.output.find("<6>markcell: stopped (a fault of the cell)") != std::string::npos);

  // An e-stop, released and reset by the PLC: the cell runs on, and says so.
  std::ofstream(s.config.string()) << text;
  std::ofstream(s.script.string()) << "0.5 plc_estop 1\n1.0 plc_estop 0\n1.5 plc_cycle_enable 0\n1.6 plc_cycle_enable 1\n";
  const auto e = run_command(kMarkcell + " run --config " + s.config.string() + " --clock sim --seconds 4 --plc-script " +
                             s.script.string());
  INFO(e.output);
  CHECK(e.exit_code == 0);
  CHECK(e.output.find("<4>markcell: safe stop (operator_stop, plc_estop: e-stop input active): waiting for the e-stop's release, "
                      "then a cycle-enable edge") != std::string::npos);
  CHECK(e.output.find("code=rearm source=safe_stop detail=\"e-stop released, reset by cycle enable, arm at home\"") !=
        std::string::npos);
  CHECK(e.output.find("<6>markcell: running: marking idle, 0 panel(s)") != std::string::npos);
  CHECK(e.output.find("<6>markcell: stopped (duration elapsed)") != std::string::npos);
}

// Under systemd, stderr is journald's stream (JOURNAL_STREAM names it): each line goes as
// one journal entry with fields, through the native protocol, read here by an independent
// receiver (tests/support/journal_listener.py) on journald's socket in a mount namespace
// of the test's own. Nothing is written twice to stderr.
TEST_CASE("under journald, the service's lines are journal entries with their panel and fault fields") {
  test::TempDir dir;
  const ServiceCell s =
      service_cell(dir, "0.0 plc_panel_present 1\n3.2 plc_panel_present 0\n4.0 plc_estop 1  # after the panel\n");
  std::filesystem::copy_file(sim_dir() + "/recording/inspection.yaml", s.drop / "0001.yaml");
  const std::string entries = (dir.path() / "entries.jsonl").string(), err = (dir.path() / "stderr.txt").string();
  const std::string script =
      "mount -t tmpfs tmpfs /run || exit 90\n"
      "python3 " + source_path("tests/support/journal_listener.py") + " " + entries + " 60 & listener=$!\n"
      "for i in $(seq 200); do [ -e " + entries + ".ready ] && break; sleep 0.05; done\n"
      ": > " + err + "\n"
      "JOURNAL_STREAM=$(stat -c %d:%i " + err + ") " + kMarkcell + " run --config " + s.config.string() +
      " --clock sim --seconds 5 --plc-script " + s.script.string() + " 2>> " + err + "\n"
      "code=$?\nsleep 0.5\nkill $listener\nexit $code\n";
  const std::string script_file = dir.write("journal.sh", script);
  const auto r = run_command("unshare --mount sh " + script_file);
  INFO(r.output << read_file(err));
  REQUIRE(r.exit_code == 0);
  std::vector<nlohmann::ordered_json> got;
  for (const auto& line : lines_of(read_file(entries))) got.push_back(parse_json(line));
  const auto find = [&](const std::string& key, const std::string& value) -> const nlohmann::ordered_json* {
    for (const auto& e : got)
      if (e.contains(key) && e[key] == value) return &e;
    return nullptr;
  };
  const auto* panel = find("PANEL_RESULT", "done");
  REQUIRE(panel != nullptr);
  CHECK((*panel)["PANEL_ID"] == "paper-door-1");
  CHECK((*panel)["SPRAYED"] == "3");
  CHECK((*panel)["SKIPPED"] == "0");
  CHECK((*panel)["PRIORITY"] == "6");
  CHECK((*panel)["SYSLOG_IDENTIFIER"] == "markcell");
  CHECK((*panel)["MESSAGE"].get<std::string>().rfind("markcell: panel=paper-door-1 result=done sprayed=3 skipped=0", 0) == 0);
  const auto* accepted = find("RECORD_FILE", (s.drop / "accepted" / "0001.yaml").string());
  REQUIRE(accepted != nullptr);
  CHECK((*accepted)["PANEL_ID"] == "paper-door-1");
  const auto* fault = find("FAULT_CODE", "operator_stop");
  REQUIRE(fault != nullptr);
  CHECK((*fault)["FAULT_SOURCE"] == "plc_estop");
  CHECK((*fault)["PRIORITY"] == "3");
  // The same lines are not on stderr too (journald would show each twice).
  CHECK(read_file(err).find("markcell: panel=") == std::string::npos);
}
