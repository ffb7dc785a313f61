// The rig end to end, as a user runs it: markcell sim generates a short scenario and
// replays it through the cell in simulated time; markcell replay of the same recording
// gives the same command log and report byte for byte; a record whose MFs do not match
// the panel stops the panel with the PLC told and nothing sprayed; scripted PLC events
// mid-panel; no heap use once started. Figures are asserted from report.json. (The cell
// as the service runs it, records and the results file: test_service_run.cpp.)
#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <sys/stat.h>
#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <map>
#include <fstream>
#include <sstream>
#include <vector>
#include <string>

#include "markcell/host/config.hpp"
#include "markcell/host/cell.hpp"
#include "markcell/host/inspection_record.hpp"
#include "markcell/host/pose_log.hpp"
#include "markcell/host/record_folder.hpp"
#include "markcell/host/results_file.hpp"
#include "markcell/rig/panel.hpp"
#include "markcell/rig/scoring.hpp"
#include "markcell/control/tool_pose.hpp"
#include "markcell/drivers/can_protocol.hpp"
#include "alloc_guard.hpp"
#include "markcell/vision/frame_source.hpp"
#include "markcell/vision/calibration_io.hpp"
#include "markcell/vision/recording.hpp"
#include "markcell/rig/render.hpp"
#include "sim_helpers.hpp"
#include "test_files.hpp"

using namespace markcell;
using namespace markcell::test;  // the helpers, the files, the example configuration

namespace {
std::string joined(const std::vector<std::string>& v) {
  std::string out;
  for (const auto& s : v) out += (out.empty() ? "" : ", ") + s;
  return out;
}

// line-fast shortened: the door at 15 cm/s through the view, 11 s at 10 frames a second.
// Rendered by the optimised markcell when there is one (`./toolchain/run test` builds it:
// rendering 110 pairs under the sanitizers takes four minutes); the tests replay it with
// the markcell under test.
const std::string& line_fast_dir() {
  static const std::string out = generated_scenario(
      "test-sim-line-fast", "line-fast --seconds 11 --fps 10",
      std::filesystem::exists(MARKCELL_RELEASE_BINARY) ? std::string(MARKCELL_RELEASE_BINARY) : kMarkcell);
  return out;
}
}  // namespace

TEST_CASE("markcell sim paper-door: all three dings marked within the radius, no false spray, Table I below the paper's") {
  const std::string json = read_file(sim_dir() + "/report.json");
  INFO(json);
  CHECK(json.find("\"scenario\": \"paper-door\"") != std::string::npos);
  CHECK(json.find("\"predictor\": \"kalman\"") != std::string::npos);
  CHECK(parse_json(json)["scored_on"] == "surface");  // the rig's own door
  CHECK(json_number(json, "defects", "planned") == 3);
  CHECK(json_number(json, "defects", "marked") == 3);
  CHECK(json_number(json, "defects", "skipped") == 0);
  CHECK(json_number(json, "false_sprays", "false_sprays") == 0);
  CHECK(json_number(json, "marking_error_mm", "max") < 5.0);
  // Inter-calibration max |error| per axis, cm: the paper's means were 1.63 / 0.89 / 2.01.
  const Eigen::Vector3d ic = json_max_abs(json, "intercalibration_cm");
  CHECK(ic.x() < 1.63);
  CHECK(ic.y() < 0.89);
  CHECK(ic.z() < 2.01);
  // The vision issue's figure: the panel pose error (the tracked motion at the defect being
  // marked) within 3 mm, and the control issue's: the prediction at each spray within 3 mm
  // per axis (the paper: 9.67 mm in depth), the arm in the view.
  CHECK(json_number(json, "pose_error_mm", "max") < 3.0);
  const Eigen::Vector3d pe = json_max_abs(json, "prediction_error_mm");
  CHECK(pe.x() < 3.0);
  CHECK(pe.y() < 3.0);
  CHECK(pe.z() < 3.0);
  CHECK(json_number(json, "deadline_misses", "deadline_misses") == 0);
  // The simulated arm was drawn into every pair in closed loop and, spraying, hid some of
  // the door's MFs from the cameras: the marks above were made in spite of it.
  CHECK(json_number(json, "vision", "arm_drawn") == json_number(json, "vision", "frames"));
  CHECK(json_number(json, "vision", "arm_hid_pairs") > 0);
  CHECK(json_number(json, "vision", "arm_hidden_mfs") >= json_number(json, "vision", "arm_hid_pairs"));
  // The plan made once the door's motion was known: all three feasible, as the run found.
  CHECK(json_number(json, "plan", "feasible") == 3);
  CHECK(json.find("\"matches_run\": true") != std::string::npos);
  for (const char* f : {"prediction.png", "mf_epipolar.png", "mf_area.png", "sprays.png", "can.log", "valve.log"})
    CHECK(std::filesystem::exists(sim_dir() + "/" + f));
  CHECK_FALSE(std::filesystem::exists(sim_dir() + "/serial.log"));  // a CAN arm
  // Three valve pulses in the valve's log, each opened and closed.
  const std::string log = read_file(sim_dir() + "/valve.log");
  std::size_t opens = 0, closes = 0;
  for (auto p = log.find("valve open"); p != std::string::npos; p = log.find("valve open", p + 1)) ++opens;
  for (auto p = log.find("valve close"); p != std::string::npos; p = log.find("valve close", p + 1)) ++closes;
  CHECK(opens == 3);
  CHECK(closes == 3);
  // Each spray as the simulated world saw it: the nozzle at the configured stand-off from
  // the true surface, along its axis (within the settle tolerance and the prediction's
  // error), and the valve open for the configured pulse (to the 1 ms tick).
  const host::CellConfig config = host::load_config(source_path("config/cell.example.yaml"), host::task_catalog());
  const auto report = parse_json(json);
  REQUIRE(report["sprays"].size() == 3);
  for (const auto& spray : report["sprays"]) {
    INFO(spray.dump());
    CHECK(std::abs(spray["standoff_mm"].get<double>() - config.marking.standoff * 1000) < 4.0);
    CHECK(std::abs(spray["open_ms"].get<double>() - static_cast<double>(config.spray.pulse) / 1e6) <= 1.0);
  }
}

TEST_CASE("a panel type's recipe: the door sprayed at its own stand-off and pulse, by the rig's truth") {
  // The example configuration with a recipe for the door (the rest as shipped).
  TempDir dir;
  const auto config_dir = dir.path() / "config";
  std::filesystem::copy(source_path("config"), config_dir, std::filesystem::copy_options::recursive);
  const std::string config = (config_dir / "cell.example.yaml").string();
  std::string text = read_file(config);
  const std::string door = "  door:   {macro_features: 10, file: panels/door.yaml}";
  REQUIRE(text.find(door) != std::string::npos);
  text.replace(text.find(door), door.size(),
               "  door:   {macro_features: 10, file: panels/door.yaml, recipe: {standoff_m: 0.16, pulse_ms: 50}}");
  std::ofstream(config) << text;
  const std::string out = (dir.path() / "run").string();
  const auto r = run_command("cd " + source_path("") + " && " + kMarkcell + " sim paper-door --seconds 3 --fps 10 -c " + config +
                             " --one-predictor -q --out " + out);
  INFO(r.output);
  REQUIRE(r.exit_code == 0);
  const std::string json = read_file(out + "/report.json");
  INFO(json);
  CHECK(json_number(json, "defects", "marked") == 3);
  const auto report = parse_json(json);
  REQUIRE(report["sprays"].size() == 3);
  for (const auto& spray : report["sprays"]) {
    INFO(spray.dump());
    CHECK(std::abs(spray["standoff_mm"].get<double>() - 160.0) < 4.0);
    CHECK(std::abs(spray["open_ms"].get<double>() - 50.0) <= 1.0);
  }
}

// can.log is real candump -L (docs/rig.md, "The command logs"): can-utils' log2asc converts
// it with one header, python-can's CanutilsLogReader reads every frame at its time, and
// python3-canmatrix decodes each with config/markcell_arm.dbc to the values markcell's own
// codec decodes from the same line.
TEST_CASE("can.log is candump -L: log2asc, python-can and canmatrix read it as markcell's codec does") {
  namespace co = drivers::canopen;
  const std::string log = sim_dir() + "/can.log";
  // markcell's reading: "(SECONDS.MICROS) IFACE ID#DATA" (ID##FDATA for CAN FD).
  struct Line {
    std::string time, iface;
    drivers::CanFrame frame;
  };
  std::vector<Line> lines;
  {
    std::istringstream in(read_file(log));
    std::string text;
    while (std::getline(in, text)) {
      INFO(text);
      REQUIRE(text.size() > 20);
      REQUIRE(text[0] == '(');
      Line l;
      const auto close = text.find(") ");
      l.time = text.substr(1, close - 1);
      const auto space = text.find(' ', close + 2);
      l.iface = text.substr(close + 2, space - close - 2);
      const auto hash = text.find('#', space);
      l.frame.id = static_cast<std::uint32_t>(std::stoul(text.substr(space + 1, hash - space - 1), nullptr, 16));
      std::size_t at = hash + 1;
      if (text[at] == '#') {
        l.frame.fd = true;
        at += 2;  // the flags nibble
      }
      for (; at + 1 < text.size(); at += 2)
        l.frame.data[l.frame.len++] = static_cast<std::uint8_t>(std::stoul(text.substr(at, 2), nullptr, 16));
      lines.push_back(l);
    }
  }
  REQUIRE(lines.size() > 100);
  CHECK(lines.front().time.rfind("946684800.", 0) == 0);  // simulated time 0 on the logs' epoch, 2000-01-01

  test::TempDir dir;
  // python-can and canmatrix (Debian's python3-can, python3-canmatrix; Debian's interpreter).
  const std::string tsv = (dir.path() / "read.tsv").string();
  const auto read = run_command("/usr/bin/python3 " + source_path("tests/support/can_log_read.py") + " " + log + " " +
                                source_path("config/markcell_arm.dbc") + " " + tsv);
  INFO(read.output);
  REQUIRE(read.exit_code == 0);
  std::vector<std::vector<std::string>> theirs;
  {
    std::istringstream in(read_file(tsv));
    std::string text;
    while (std::getline(in, text)) {
      std::vector<std::string> fields;
      std::istringstream row(text);
      std::string field;
      while (std::getline(row, field, '\t')) fields.push_back(field);
      while (fields.size() < 6) fields.emplace_back();
      theirs.push_back(fields);
    }
  }
  REQUIRE(theirs.size() == lines.size());
  int decoded = 0;
  for (std::size_t i = 0; i < lines.size(); ++i) {
    const Line& l = lines[i];
    const auto& t = theirs[i];
    INFO("frame " << i << ": " << l.time << " " << l.iface << " " << std::hex << l.frame.id << std::dec << "; python: " << t[0]
                  << " " << t[2] << " " << t[4] << " " << t[5]);
    CHECK(t[0] == l.time);
    CHECK(t[1] == "can0");  // the example configuration's devices.arm.can.interface
    CHECK(std::stoul(t[2], nullptr, 16) == l.frame.id);
    CHECK((t[3] == "1") == l.frame.fd);
    co::Message m;
    REQUIRE(co::decode(l.frame, m) == co::DecodeError::kOk);
    // The codec's values by the DBC's signal names.
    std::map<std::string, double> ours;
    const auto xyz = [&ours](const std::string& prefix, const std::array<double, 3>& v) {
      ours[prefix + "x"] = v[0], ours[prefix + "y"] = v[1], ours[prefix + "z"] = v[2];
    };
    switch (m.kind) {
      case co::Kind::kNmt:
        ours["nmt_command"] = static_cast<double>(m.nmt_command), ours["nmt_node"] = m.node;
        break;
      case co::Kind::kSync: break;
      case co::Kind::kHeartbeat: ours["nmt_state"] = static_cast<double>(m.nmt_state); break;
      case co::Kind::kTargetPosition:
        xyz("target_", m.vector), ours["mode"] = m.mode_or_status, ours["seq"] = m.seq;
        break;
      case co::Kind::kTargetRotation:
        xyz("target_r", m.vector), ours["seq"] = m.seq;
        break;
      case co::Kind::kTargetTime: ours["time_us"] = m.time_us, ours["seq"] = m.seq; break;
      case co::Kind::kToolPosition:
        xyz("tool_", m.vector), ours["status"] = m.mode_or_status, ours["seq"] = m.seq;
        break;
      case co::Kind::kToolRotation:
        xyz("tool_r", m.vector), ours["fault_code"] = m.fault_code, ours["seq"] = m.seq;
        break;
      case co::Kind::kTargetFd:
        xyz("fd_target_", m.vector), xyz("fd_target_r", m.vector2);
        ours["mode"] = m.mode_or_status, ours["seq"] = m.seq, ours["time_us"] = m.time_us;
        break;
      case co::Kind::kToolFd:
        xyz("fd_tool_", m.vector), xyz("fd_tool_r", m.vector2);
        ours["status"] = m.mode_or_status, ours["seq"] = m.seq, ours["fault_code"] = m.fault_code;
        break;
    }
    std::map<std::string, double> canmatrix;
    std::istringstream signals(t[5]);
    std::string pair;
    while (signals >> pair) canmatrix[pair.substr(0, pair.find('='))] = std::stod(pair.substr(pair.find('=') + 1));
    REQUIRE(canmatrix.size() == ours.size());
    for (const auto& [name, value] : ours) {
      INFO(name);
      REQUIRE(canmatrix.count(name) == 1);
      CHECK(canmatrix[name] == Approx(value).margin(1e-9));
    }
    ++decoded;
  }
  CHECK(decoded == static_cast<int>(lines.size()));

  // can-utils' log2asc: one header, every frame, times from the first frame's.
  const std::string asc = (dir.path() / "can.asc").string();
  const auto converted = run_command("log2asc -I " + log + " -O " + asc + " can0");
  INFO(converted.output);
  REQUIRE(converted.exit_code == 0);
  std::istringstream in(read_file(asc));
  std::string text;
  int headers = 0, frames = 0;
  double last = -1;
  while (std::getline(in, text)) {
    if (text.rfind("date ", 0) == 0) ++headers;
    std::istringstream row(text);
    double time = 0;
    if (text.size() > 3 && text[0] == ' ' && (row >> time)) ++frames, last = time;
  }
  CHECK(headers == 1);
  CHECK(frames == static_cast<int>(lines.size()));
  CHECK(last == Approx(log_seconds(lines.back().time) - log_seconds(lines.front().time)).margin(1e-6));
}

TEST_CASE("line-fast: the arm waits at home for refits to place every ding, then pose, prediction and pace meet the targets") {
  // The door enters the view leading edge first: the first inter-calibration rests on the
  // MFs of that edge and levers the inspection record's depth noise out to the dings
  // beyond. The sequence holds until refits with the MFs that come into view place every
  // ding within the placement limit (1 mm), then marks them one after the other.
  test::TempDir dir;
  const std::string json = replay_report(line_fast_dir() + "/recording", "", (dir.path() / "held").string());
  INFO(json);
  CHECK(json_number(json, "defects", "marked") == 3);
  CHECK(json_number(json, "false_sprays", "false_sprays") == 0);
  CHECK(json_number(json, "marking_error_mm", "max") < 5.0);
  const Eigen::Vector3d held = json_max_abs(json, "prediction_error_mm");
  CHECK(held.maxCoeff() < 3.0);
  // The pose error's worst frame is one where the arm hides MFs (missing_mfs_max): with
  // the Kalman predictor, full line-fast runs gave 1.8 to 3.7 mm over seeds 1 to 5
  // (`markcell sim line-fast --seed N`, release build); these 11 s at seed 1, 3.2 mm.
  CHECK(json_number(json, "pose_error_mm", "max") < 4.0);
  CHECK(json_number(json, "seconds_per_defect", "seconds_per_defect") < 1.5);
  // The same recording without the hold: the limit at 3 mm and the arm off at once. With
  // the inspection station's record (MFs measured in the scanner's views to about 0.3 mm)
  // the first fits already place the far ding within a millimetre: the hold is the
  // safeguard for a record that is not as good (with the earlier noise model's record,
  // 0.25 px at the scanner, this ding was sprayed several millimetres off in depth). A
  // 1 mm limit without the hold keeps the arm waiting on the ding instead, and the pace
  // drops. (Each figure from its own report: the replay is deterministic.)
  const std::string at_once = replay_report(
      line_fast_dir() + "/recording",
      " --config " + example_config_with(dir, {{"  placement_limit_mm: 1.0 ", "  placement_limit_mm: 3.0 "},
                                               {"  placement_hold_s: 6 ", "  placement_hold_s: 0 "}}),
      (dir.path() / "at-once").string());
  INFO(at_once);
  CHECK(json_number(at_once, "defects", "marked") == 3);
  CHECK(json_number(at_once, "false_sprays", "false_sprays") == 0);
  CHECK(json_max_abs(at_once, "prediction_error_mm").z() < 3.0);
  test::TempDir dir2;
  const std::string waiting = replay_report(
      line_fast_dir() + "/recording",
      " --config " + example_config_with(dir2, {{"  placement_hold_s: 6 ", "  placement_hold_s: 0 "}}),
      (dir2.path() / "waiting").string());
  INFO(waiting);
  // Waiting on the ding costs time: the pace drops (4.8 s per defect at seed 1), and a
  // ding may be given up with its reason ("arm did not settle on the moving target in
  // time"), never sprayed off.
  CHECK(json_number(waiting, "defects", "marked") + json_number(waiting, "defects", "skipped") == 3);
  CHECK(json_number(waiting, "false_sprays", "false_sprays") == 0);
  CHECK(json_number(waiting, "seconds_per_defect", "seconds_per_defect") > 1.5);
}

TEST_CASE("replaying the same recording gives the same command log, pose log and report, byte for byte") {
  test::TempDir dir;
  const std::string out = (dir.path() / "again").string();
  const std::string json = replay_report(sim_dir() + "/recording", "", out);
  CHECK(read_file(out + "/can.log") == read_file(sim_dir() + "/can.log"));
  CHECK(read_file(out + "/valve.log") == read_file(sim_dir() + "/valve.log"));
  CHECK(read_file(out + "/poses.csv") == read_file(sim_dir() + "/poses.csv"));
  CHECK(read_file(out + "/mf_tracks.csv") == read_file(sim_dir() + "/mf_tracks.csv"));
  CHECK(json == read_file(sim_dir() + "/report.json"));
}

// Determinism across compilers (docs/determinism.md): the same scenario and seed from this
// markcell (GCC, Debug with the sanitizers) and the clang preset's (clang 14, a plain -O3
// Release; libc++'s distributions would differ, and clang contracts differently) give the
// same recording, inspection record, command log,
// pose log and report, byte for byte. `./toolchain/run test` builds both.
TEST_CASE("GCC's and clang's markcell make the same scenario byte for byte") {
  INFO("clang's markcell: " << MARKCELL_CLANG_BINARY << " (./toolchain/run build clang makes it)");
  REQUIRE(std::filesystem::exists(MARKCELL_CLANG_BINARY));
  const std::string args = "paper-door --seconds 2 --fps 10 --seed 3";
  const std::string gcc = generated_scenario("test-sim-same-bits-gcc", args);
  const std::string clang = generated_scenario("test-sim-same-bits-clang", args, MARKCELL_CLANG_BINARY);
  int compared = 0;
  std::vector<std::string> differ;
  for (const auto& e : std::filesystem::recursive_directory_iterator(gcc)) {
    if (!e.is_regular_file()) continue;
    const auto rel = std::filesystem::relative(e.path(), gcc);
    const auto other = std::filesystem::path(clang) / rel;
    ++compared;
    if (!std::filesystem::exists(other)) {
      differ.push_back(rel.string() + " (missing)");
      continue;
    }
    // report.json names its own folder (`recording`, `calibration`): the one difference allowed.
    std::string theirs = read_file(other.string());
    for (auto at = theirs.find(clang); at != std::string::npos; at = theirs.find(clang, at + gcc.size()))
      theirs.replace(at, clang.size(), gcc);
    if (read_file(e.path().string()) != theirs) differ.push_back(rel.string());
  }
  INFO("files that differ: " << joined(differ));
  CHECK(differ.empty());
  CHECK(compared > 20);  // the frames, truth.csv, inspection.yaml, can.log, poses.csv, report.json ...
  for (const char* name : {"recording/truth.csv", "recording/inspection.yaml", "can.log", "valve.log", "report.json", "poses.csv"})
    CHECK(std::filesystem::exists(std::filesystem::path(gcc) / name));
}

TEST_CASE("a replay on real devices (--gpio-sim) refuses a configuration of simulated ones, naming the file and key") {
  // The real-device replay itself runs in the guest kernel (test_realkernel, [replay]).
  test::TempDir dir;
  const std::string example = source_path("config/cell.example.yaml");
  const auto gpio = run_command(kMarkcell + " replay " + sim_dir() + "/recording -q --one-predictor --config " + example +
                                " --gpio-sim " + dir.path().string() + " --out " + (dir.path() / "a").string());
  INFO(gpio.output);
  CHECK(gpio.exit_code != 0);
  CHECK(gpio.output.find(example + ": devices.gpio.simulated is true") != std::string::npos);
  const std::string real_gpio = example_config_with(dir, {{"    simulated: true ", "    simulated: false"}});
  const auto arm = run_command(kMarkcell + " replay " + sim_dir() + "/recording -q --one-predictor --config " + real_gpio +
                               " --gpio-sim " + dir.path().string() + " --out " + (dir.path() / "b").string());
  INFO(arm.output);
  CHECK(arm.exit_code != 0);
  CHECK(arm.output.find(real_gpio + ": devices.arm.transport must be can or serial") != std::string::npos);
  // An arm on a serial line needs the line's other end for the rig's arm, and only then.
  const std::string no_sim_world =
      "    sim_world:   {lane: control, period_us: 1000, phase_us: 0, budget_us: 300, on_overrun: log}";
  const std::string serial = example_config_with(dir, {{"    simulated: true ", "    simulated: false"},
                                                       {"    transport: simulated ", "    transport: serial "},
                                                       {no_sim_world, ""}});
  const auto no_peer = run_command(kMarkcell + " replay " + sim_dir() + "/recording -q --one-predictor --config " + serial +
                                   " --gpio-sim " + dir.path().string() + " --out " + (dir.path() / "c").string());
  INFO(no_peer.output);
  CHECK(no_peer.exit_code != 0);
  CHECK(no_peer.output.find(serial + ": devices.arm.transport is serial: a replay on real devices needs the serial line's "
                                     "other end for the rig's arm (--arm-serial-peer DEVICE)") != std::string::npos);
  const std::string can = example_config_with(dir, {{"    simulated: true ", "    simulated: false"},
                                                    {"    transport: simulated ", "    transport: can "},
                                                    {no_sim_world, ""}});
  const auto stray_peer = run_command(kMarkcell + " replay " + sim_dir() + "/recording -q --one-predictor --config " + can +
                                      " --gpio-sim " + dir.path().string() + " --arm-serial-peer " + dir.path().string() +
                                      " --out " + (dir.path() / "d").string());
  INFO(stray_peer.output);
  CHECK(stray_peer.exit_code != 0);
  CHECK(stray_peer.output.find(can + ": --arm-serial-peer is given but devices.arm.transport is not serial") !=
        std::string::npos);
  for (const char* out : {"a", "b", "c", "d"}) CHECK_FALSE(std::filesystem::exists(dir.path() / out / "report.json"));
}

TEST_CASE("defects the inter-calibration cannot place surely enough are followed, never sprayed, skipped with the reason") {
  // The door's fit places its dings to about half a millimetre; a limit below that holds
  // every spray back, and each defect times out (soon: the recording is 3 s) with the
  // placement as its reason.
  test::TempDir dir;
  const std::string config = example_config_with(
      dir, {{"  placement_limit_mm: 1.0 ", "  placement_limit_mm: 0.1 "},
            {"  defect_timeout_s: 6 ", "  defect_timeout_s: 0.8"},
            {"  placement_hold_s: 6 ", "  placement_hold_s: 0 "}});  // start at once: the spray gate is under test
  const std::string json = replay_report(sim_dir() + "/recording", " --config " + config, (dir.path() / "out").string());
  INFO(json);
  CHECK(json_number(json, "defects", "sprayed") == 0);
  CHECK(json_number(json, "defects", "skipped") == 3);
  const auto reasons = parse_json(json)["defects"]["skipped_reasons"];
  const auto count = [&](const std::string& what) {
    std::size_t n = 0;
    for (const auto& r : reasons) n += r["reason"].get<std::string>().find(what) != std::string::npos ? 1 : 0;
    return n;
  };
  // Each defect whose turn came waited for a surer placement until its timeout; the last
  // one's turn may not come before the 3 s panel leaves.
  const std::size_t placement = count("placed it too unsurely"), not_reached = count("stopped before the defect's turn");
  CHECK(placement >= 2);
  CHECK(placement + not_reached == 3);
  // The placement the sequence held them to, in the plan's verdicts: above 0.1 mm, below
  // the default limit.
  const double sigma = json_number(json, "verdicts", "placement_sigma_mm");
  CHECK(sigma > 0.1);
  CHECK(sigma < 1.0);
}

TEST_CASE("a record that does not match the panel: inter-calibration rejected (searched again with the arm home), nothing sprayed, PLC fault, reason recorded") {
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
    else if (line == "defects:" || line == "macro_feature_quality:") in_mfs = false;
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
  const std::string json = replay_report(rec.string(), "", out);
  INFO(json);
  CHECK(json.find("\"status\": \"macro-features of the record and of the panel disagree\"") != std::string::npos);
  CHECK(json.find("\"fault\": true") != std::string::npos);
  CHECK(json_number(json, "defects", "sprayed") == 0);
  CHECK(json_number(json, "defects", "skipped") == 3);
  CHECK(json.find("inter-calibration failed or above its limit") != std::string::npos);
  CHECK(read_file(out + "/valve.log").find("valve open") == std::string::npos);

  // Each failed search is made again with the arm at home; an arm that cannot say it is home
  // within home_timeout (here its confirmation must postdate a 150 ms command lead, with
  // 0.1 s allowed) ends the panel at once, naming the arm, not the search; the arm's
  // second miss, at the panel's end, comes after that reason.
  const std::string no_home = (dir.path() / "no-home").string();
  const std::string json2 = replay_report(
      rec.string(),
      " --config " + example_config_with(dir, {{"  command_lead_ms: 35 ", "  command_lead_ms: 150 "},
                                               {"  home_timeout_s: 10\n", "  home_timeout_s: 0.1\n"}}),
      no_home);
  INFO(json2);
  CHECK(json2.find("\"reason\": \"arm did not reach home in time to search again for the macro-features; then the "
                   "arm did not reach home in time\"") != std::string::npos);
  CHECK(json2.find("\"status\": \"macro-features of the record and of the panel disagree\"") != std::string::npos);
  CHECK(json_number(json2, "defects", "skipped") == 3);
  CHECK(json2.find("inter-calibration failed or above its limit") != std::string::npos);
  CHECK(read_file(no_home + "/valve.log").find("valve open") == std::string::npos);
}

TEST_CASE("the whole cell marking a panel (vision, marking, arm link, valve, PLC) allocates nothing once started") {
  // The short recording's frames decoded into memory first: the measured part must not
  // decode images (the recording's loader is a device twin that allocates).
  const auto rec = vision::Recording::open(sim_dir() + "/recording");
  std::vector<vision::MemoryFrameSource::Pair> pairs = decoded_pairs(rec);
  auto cfg = in_process_config();
  host::Cell cell(cfg, host::ClockKind::kSimulated);
  cell.use_frame_source(std::make_unique<vision::MemoryFrameSource>(std::move(pairs), cfg.cameras.latency));
  const auto job = host::read_inspection_record(sim_dir() + "/recording/inspection.yaml", cfg.panel_types);
  cell.enable_pose_queue();  // every estimate handed to the pose log's queue too
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
  CHECK(result.tally().sprayed == 3);
  CHECK(cell.sim_nozzle()->kept() == 3);
  CHECK(allocations == 0);
  msg::PoseEstimate e;
  std::size_t queued = 0;
  while (cell.pose_queue()->pop(e)) ++queued;
  CHECK(queued >= 29);  // the 3 s at 10 frames a second (the last may still be in flight)
  CHECK(cell.pose_queue()->dropped() == 0);
  cell.shutdown(control::FaultCode::kShutdown, "test", "done");
}

TEST_CASE("pairing by the line's panel id: the announced panel is marked and the control lane allocates nothing") {
  const auto rec = vision::Recording::open(sim_dir() + "/recording");
  std::vector<vision::MemoryFrameSource::Pair> pairs = decoded_pairs(rec);
  auto cfg = in_process_config();
  cfg.line.panel_id_source = host::PanelIdSource::kModbus;  // (the cell takes the words; no PLC link here)
  cfg.line.modbus.server = "127.0.0.1:1502";
  host::Cell cell(cfg, host::ClockKind::kSimulated);
  cell.use_frame_source(std::make_unique<vision::MemoryFrameSource>(std::move(pairs), cfg.cameras.latency));
  const auto job = host::read_inspection_record(sim_dir() + "/recording/inspection.yaml", cfg.panel_types);
  // The line's word, as the PLC link writes it every poll: this panel comes next.
  TripleBuffer<msg::LineArrival>& arrivals = cell.line_arrivals();
  const auto announce = [&](std::uint32_t counter, std::string_view id) {
    msg::LineArrival& a = arrivals.write_slot();
    a.counter = counter;
    a.panel_id.assign(id);
    a.panel_type.assign(job.panel_type.view());
    a.heard = cell.sim_clock()->global_now();
    arrivals.publish();
  };
  cell.start();
  announce(1, job.panel_id.view());
  REQUIRE(cell.marking()->offer_job(job));
  cell.sim_gpio()->drive_physical(cell.gpio_line(host::LineRole::kPlcPanelPresent), true);
  Nanos t = 0;
  for (; t < millis(400); t += millis(100)) {
    REQUIRE(cell.sim_clock()->run_until(t + millis(100)) == control::SimClock::RunResult::kReached);
    announce(1, job.panel_id.view());
  }
  REQUIRE(cell.marking()->state() == control::MarkingState::kApproach);
  std::size_t allocations = 0;
  {
    test::AllocationGuard guard;
    for (; t < millis(3000); t += millis(100)) {
      REQUIRE(cell.sim_clock()->run_until(t + millis(100)) == control::SimClock::RunResult::kReached);
      announce(1, job.panel_id.view());
    }
    allocations = guard.allocations();
  }
  CHECK(cell.marking()->current().panel_id.view() == job.panel_id.view());
  CHECK(cell.marking()->current().tally().sprayed == 3);
  CHECK(cell.sim_nozzle()->kept() == 3);
  CHECK(allocations == 0);
  CHECK_FALSE(cell.safe_stop().active());
  // The PLC's status word's source: the lines as the tasks drove and read them, during
  // the panel and at its end.
  const auto level = [&](host::LineRole role) { return (cell.gpio_mirror().levels() >> static_cast<int>(role) & 1u) == 1u; };
  CHECK(level(host::LineRole::kPlcPanelPresent));
  CHECK(level(host::LineRole::kPlcBusy));
  CHECK_FALSE(level(host::LineRole::kSprayValve));
  for (; cell.marking()->panels_completed() == 0 && t < seconds(10); t += millis(100)) {
    REQUIRE(cell.sim_clock()->run_until(t + millis(100)) == control::SimClock::RunResult::kReached);
    announce(1, job.panel_id.view());
  }
  REQUIRE(cell.marking()->panels_completed() == 1);
  CHECK_FALSE(level(host::LineRole::kPlcBusy));
  CHECK(level(host::LineRole::kPlcDone) == !cell.marking()->current().fault);
  CHECK(level(host::LineRole::kPlcFault) == cell.marking()->current().fault);
  cell.shutdown(control::FaultCode::kShutdown, "test", "done");
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
  const std::string json = replay_report(sim_dir() + "/recording", " --config " + cfg.string(), out);
  INFO(json);
  CHECK(json_number(json, "plan", "feasible") == 0);
  CHECK(json_number(json, "plan", "infeasible") == 3);
  CHECK(json.find("\"verdict\": \"never within the arm's reach\"") != std::string::npos);
  CHECK(json.find("\"matches_run\": true") != std::string::npos);
  CHECK(json_number(json, "defects", "skipped") == 3);
  CHECK(json.find("planned out: not within the arm's reach in its turn (the plan's verdict says why)") != std::string::npos);
  CHECK(read_file(out + "/valve.log").find("valve open") == std::string::npos);
}

TEST_CASE("soak: 200 consecutive panels in simulated time, every defect marked, no false spray, no heap use") {
  // The short recording's frames in memory, replayed as panel after panel by one cell:
  // the PLC brings each panel in, its record arrives, the cell marks it, the panel leaves.
  const auto rec = vision::Recording::open(sim_dir() + "/recording");
  std::vector<vision::MemoryFrameSource::Pair> pairs = decoded_pairs(rec);
  const Nanos time_base = rec.entry(0).time;
  auto cfg = in_process_config();
  host::Cell cell(cfg, host::ClockKind::kSimulated);
  auto memory = std::make_unique<vision::MemoryFrameSource>(std::move(pairs), cfg.cameras.latency);
  vision::MemoryFrameSource& source = *memory;
  cell.use_frame_source(std::move(memory));
  auto job = host::read_inspection_record(sim_dir() + "/recording/inspection.yaml", cfg.panel_types);
  cell.start();
  control::SimClock& clock = *cell.sim_clock();
  control::MarkingSequence& marking = *cell.marking();
  const int present = cell.gpio_line(host::LineRole::kPlcPanelPresent);

  // The truth of the recording, by linear interpolation between its poses.
  const auto& truth = rec.truth();
  REQUIRE(truth.size() >= 2);
  const auto truth_at = [&](Nanos t_rec) {
    std::size_t i = 1;
    while (i + 1 < truth.size() && truth[i].time < t_rec) ++i;
    const auto& a = truth[i - 1];
    const auto& b = truth[i];
    const double f = std::clamp(static_cast<double>(t_rec - a.time) / static_cast<double>(b.time - a.time), 0.0, 1.0);
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() = Eigen::Quaterniond(a.X_CamR_Panel.linear()).slerp(f, Eigen::Quaterniond(b.X_CamR_Panel.linear())).toRotationMatrix();
    X.translation() = (1 - f) * a.X_CamR_Panel.translation() + f * b.X_CamR_Panel.translation();
    return X;
  };
  std::vector<rig::TrueDefect> defects;
  for (const auto& d : rec.defects()) defects.push_back({d.id, d.p_Panel});
  // Scored on the recording's own panel mesh.
  const rig::Panel shape = rig::load_panel_mesh(rec.manifest().panel_type, rec.folder() + "/" + rec.manifest().panel_mesh,
                                                rec.manifest().panel_mesh_metres_per_unit);
  const Eigen::Isometry3d X_CamR_Base = cell.X_Base_CamR().inverse();

  constexpr int kPanels = 200;
  int marked = 0, false_sprays = 0, faults = 0, unfinished = 0;
  std::string first_unfinished;  // (the first panel that did not finish: the state it hung in)
  std::size_t allocations = 0;
  for (int k = 0; k < kPanels; ++k) {
    const Nanos epoch = clock.global_now();
    const std::size_t sprays_before = cell.sim_nozzle()->total();
    job.panel_id.assign(("soak-" + std::to_string(k)).c_str());
    {
      test::AllocationGuard guard;
      source.rewind(epoch);
      const bool offered = marking.offer_job(job);
      cell.sim_gpio()->drive_physical(present, true);
      Nanos t = epoch;
      while (marking.panels_completed() < static_cast<std::uint64_t>(k + 1) && t < epoch + seconds(15))
        clock.run_until(t += millis(100));
      cell.sim_gpio()->drive_physical(present, false);  // the panel leaves the station
      clock.run_until(t + millis(200));
      if (k > 0) allocations += guard.allocations();  // the first panel warms up what is allocated once
      if ((!offered || marking.panels_completed() != static_cast<std::uint64_t>(k + 1)) && unfinished++ == 0)
        first_unfinished = "panel " + std::to_string(k) + ": offered " + std::to_string(offered) + ", state " +
                           std::string(control::to_string(marking.state())) + ", " +
                           std::to_string(marking.panels_completed()) + " completed";
    }
    const control::PanelResult& r = marking.current();
    faults += r.fault ? 1 : 0;
    std::vector<rig::Spray> sprays;
    for (std::size_t i = sprays_before; i < cell.sim_nozzle()->total(); ++i)
      sprays.push_back({cell.sim_nozzle()->spray(i).time, X_CamR_Base * control::to_isometry(cell.sim_nozzle()->spray(i).tool)});
    const auto score = rig::score_sprays(
        shape, [&](Nanos t) { return truth_at(t - epoch + time_base); }, defects, sprays, {}, 0.010);
    marked += score.marked;
    false_sprays += score.false_sprays;
  }
  cell.shutdown(control::FaultCode::kShutdown, "test", "soak done");
  INFO(first_unfinished);
  CHECK(unfinished == 0);
  CHECK(faults == 0);
  CHECK(marked == kPanels * static_cast<int>(defects.size()));
  CHECK(false_sprays == 0);
  CHECK(marking.panels_completed() == kPanels);
  CHECK(allocations == 0);
}

TEST_CASE("replay with a scripted PLC: an e-stop mid-panel ends it, nothing sprayed after, every defect skipped with the reason") {
  test::TempDir dir;
  const std::string script = dir.write("estop.txt", "# the operator hits the e-stop as the arm approaches\n0.8 plc_estop 1\n");
  const std::string out = (dir.path() / "estop").string();
  const std::string json = replay_report(sim_dir() + "/recording", " --plc-script " + script, out);
  INFO(json);
  // The first ding is sprayed at 0.70 s, before the stop; the other two never are.
  CHECK(json_number(json, "defects", "sprayed") == 1);
  CHECK(json_number(json, "defects", "skipped") == 2);
  CHECK(json_number(json, "false_sprays", "false_sprays") == 0);
  CHECK(json.find("stopped before the defect's turn (safe stop or panel left)") != std::string::npos);
  CHECK(json.find("t=0.801 s operator_stop plc_estop: e-stop input active") != std::string::npos);
  const std::string log = read_file(out + "/valve.log");
  const auto open = log.find("valve open");
  REQUIRE(open != std::string::npos);
  CHECK(log.find("valve open", open + 1) == std::string::npos);  // one pulse, the one before the stop
  // A script with a mistake is refused before the replay starts.
  const std::string bad = dir.write("bad.txt", "0.8 plc_estop on\n");
  const auto refused = run_command("cd " + source_path("") + " && " + kMarkcell + " replay " + sim_dir() +
                                   "/recording -q --plc-script " + bad + " --out " + out);
  INFO(refused.output);
  CHECK(refused.exit_code == 2);
  CHECK(refused.output.find(bad + ":1: level 'on' must be 0 or 1") != std::string::npos);
}

TEST_CASE("replay with a scripted PLC: panel present dropping mid-pulse closes the valve on the next tick, the defect cut short") {
  test::TempDir dir;
  // The first ding's pulse opens at about 0.70 s for 80 ms; the panel-present line drops at 0.72 s, within it.
  const std::string script = dir.write("drop.txt", "# the photo-eye loses the panel during the first spray\n0.72 plc_panel_present 0\n");
  const std::string out = (dir.path() / "drop").string();
  const std::string json = replay_report(sim_dir() + "/recording", " --plc-script " + script, out);
  INFO(json);
  const std::string log = read_file(out + "/valve.log");
  const auto open = log.find(") valve open");
  const auto close = log.find(") valve close");
  REQUIRE(open != std::string::npos);
  REQUIRE(close != std::string::npos);
  // The "(SECONDS.MICROS)" before the entry at `at`, from the run's start.
  const auto stamp = [&](std::size_t at) { return log_seconds(log.substr(log.rfind('(', at) + 1, at - log.rfind('(', at) - 1)); };
  REQUIRE(stamp(open) > 0.64);
  REQUIRE(stamp(open) < 0.72);
  CHECK(stamp(close) > 0.720);
  CHECK(stamp(close) <= 0.721 + 1e-9);  // one 1 ms control tick after the drop, not the pulse's 0.08 s
  CHECK(log.find("valve open", close) == std::string::npos);  // never again
  CHECK(json_number(json, "defects", "sprayed") == 0);
  CHECK(json.find("its spray was cut short (panel present dropped during the pulse)") != std::string::npos);
  CHECK(json.find("panel left during the marking sequence") != std::string::npos);
}

TEST_CASE("a replay runs the whole recording: each panel-present episode of the PLC script is a panel, each scored on its own sprays") {
  // 9 s of the paper's door; the PLC takes the panel away at 3.5 s (the first is done by
  // then) and brings it back at 4 s: two panels, the record offered for each. (The second
  // panel is the same door further down the line: brought back at 5 s, it was still held
  // for its placement when the recording ended, and ended "panel left before its marking
  // began".)
  const std::string recording =
      generated_scenario("test-sim-paper-door-9s", "paper-door --seconds 9 --fps 10",
                         std::filesystem::exists(MARKCELL_RELEASE_BINARY) ? std::string(MARKCELL_RELEASE_BINARY) : kMarkcell) +
      "/recording";
  test::TempDir dir;
  const std::string script = dir.write("two.plc", "# the first panel leaves, the next comes\n3.5 plc_panel_present 0\n4.0 plc_panel_present 1\n");
  const std::string json = replay_report(recording, " --plc-script " + script, (dir.path() / "out").string());
  INFO(json);
  const auto report = parse_json(json);
  CHECK(report["episodes"] == 2);
  REQUIRE(report["panels"].size() == 2);
  const auto& first = report["panels"][0];
  const auto& second = report["panels"][1];
  CHECK(first["id"] == "paper-door-1");
  CHECK(second["id"] == "paper-door-1#2");
  CHECK(first["fault"] == false);
  CHECK(second["fault"] == false);
  CHECK(first["finished_s"].get<double>() < 3.5);
  CHECK(second["started_s"].get<double>() >= 4.0);
  // Each panel marks all three dings on its own sprays, against the recording's truth.
  for (const auto& p : {first, second}) {
    CHECK(p["defects"]["marked"] == 3);
    CHECK(p["defects"]["planned"] == 3);
    CHECK(p["false_sprays"] == 0);
    CHECK(p["marking_error_mm"]["max"].get<double>() < 5.0);
  }
  // The top level counts both, and every spray once.
  CHECK(report["defects"]["marked"] == 6);
  CHECK(report["defects"]["sprayed"] == 6);
  CHECK(report["false_sprays"] == 0);
  CHECK(report["sprays"].size() == 6);
  std::size_t after = 0;
  for (const auto& s : report["sprays"]) after += s["t_s"].get<double>() >= 4.0 ? 1 : 0;
  CHECK(after == 3);
}

TEST_CASE("a replay shows the frame index lines it refused, in its output and in report.json") {
  test::TempDir dir;
  const auto rec = dir.path() / "recording";
  std::filesystem::copy(sim_dir() + "/recording", rec, std::filesystem::copy_options::recursive);
  std::ofstream(rec / "frames.csv", std::ios::app) << "99,notatime,left/x.png,right/x.png\n999,1,/etc/passwd,right/x.png\n";
  const std::string out = (dir.path() / "out").string();
  const auto r = run_command("cd " + source_path("") + " && " + kMarkcell + " replay " + rec.string() + " --one-predictor --out " + out);
  INFO(r.output);
  REQUIRE(r.exit_code == 0);
  CHECK(r.output.find("frames.csv: 2 line(s) refused, not replayed:") != std::string::npos);
  CHECK(r.output.find("seq and time_ns must be integers and both image paths present") != std::string::npos);
  CHECK(r.output.find("image path '/etc/passwd' is an absolute path") != std::string::npos);
  const auto report = parse_json(read_file(out + "/report.json"));
  REQUIRE(report["index_problems"].size() == 2);
  for (const auto& p : report["index_problems"]) CHECK(p.get<std::string>().rfind("frames.csv:", 0) == 0);
}

namespace {
std::vector<std::string> csv_fields(const std::string& line) {
  std::vector<std::string> out;
  std::string field;
  std::istringstream in(line);
  while (std::getline(in, field, ',')) out.push_back(field);
  if (!line.empty() && line.back() == ',') out.emplace_back();
  return out;
}
Eigen::Isometry3d pose_of(const std::vector<std::string>& f, std::size_t at) {  // x y z qw qx qy qz from column `at`
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(std::stod(f[at]), std::stod(f[at + 1]), std::stod(f[at + 2]));
  X.linear() = Eigen::Quaterniond(std::stod(f[at + 3]), std::stod(f[at + 4]), std::stod(f[at + 5]), std::stod(f[at + 6]))
                   .normalized()
                   .toRotationMatrix();
  return X;
}
}  // namespace

TEST_CASE("the pose log read back against the recording's truth: the panel's motion within the report's pose error") {
  // Independent of the rig's scorer: the recording's truth.csv and defects.csv, joined on
  // seq, as a user with their own truth would.
  const std::string json = read_file(sim_dir() + "/report.json");
  const auto poses = lines_of(read_file(sim_dir() + "/poses.csv"));
  const auto truth_lines = lines_of(read_file(sim_dir() + "/recording/truth.csv"));
  const auto defect_lines = lines_of(read_file(sim_dir() + "/recording/defects.csv"));
  REQUIRE(poses.size() > 20);
  REQUIRE(poses[0] + "\n" == host::PoseLog::kPosesHeader);
  std::map<std::string, Eigen::Isometry3d> truth;  // by seq: X_CamR_Panel
  for (std::size_t i = 1; i < truth_lines.size(); ++i) {
    const auto f = csv_fields(truth_lines[i]);
    truth[f[0]] = pose_of(f, 2);
  }
  std::vector<Eigen::Vector3d> defects_Panel;
  for (std::size_t i = 1; i < defect_lines.size(); ++i) {
    const auto f = csv_fields(defect_lines[i]);
    defects_Panel.emplace_back(std::stod(f[1]), std::stod(f[2]), std::stod(f[3]));
  }
  REQUIRE(defects_Panel.size() == 3);
  std::map<std::string, std::string> seq_at_time;  // time_ns -> seq, to find each P's set-up frame
  for (std::size_t i = 1; i < poses.size(); ++i) {
    const auto f = csv_fields(poses[i]);
    seq_at_time[f[1]] = f[0];
  }
  double max_error = 0, sum_sq = 0;
  int tracked = 0;
  for (std::size_t i = 1; i < poses.size(); ++i) {
    const auto f = csv_fields(poses[i]);
    REQUIRE(f.size() == 15);
    if (f[2] != "tracking") continue;
    REQUIRE(seq_at_time.count(f[3]) == 1);
    const Eigen::Isometry3d X_CamR_Panel = truth.at(f[0]), X_CamR_Panel_ref = truth.at(seq_at_time.at(f[3]));
    const Eigen::Isometry3d X_CamR_P = pose_of(f, 4);
    for (const auto& c : defects_Panel) {
      // P is the right camera's frame at the set-up frame: the defect there is X_CamR_Panel_ref * c.
      const double e = (X_CamR_P * (X_CamR_Panel_ref * c) - X_CamR_Panel * c).norm();
      max_error = std::max(max_error, e);
      sum_sq += e * e;
    }
    ++tracked;
  }
  REQUIRE(tracked > 20);
  const double rms = std::sqrt(sum_sq / (3.0 * tracked));
  INFO("pose log: " << tracked << " tracked frames, motion error at the dings max " << max_error * 1000 << " mm, rms "
                    << rms * 1000 << " mm");
  INFO(json);
  // The report's figure is the same motion error, taken only at the frames the marking
  // sequence used and at the ding being marked ("setup_frame_max": P taken as the set-up
  // frame, as here).
  const double report_max = json_number(json, "pose_error_mm", "setup_frame_max") / 1000;
  CHECK(rms <= report_max);
  CHECK(max_error < 3e-3);  // the vision issue's target for the panel pose
}

TEST_CASE("a recording made with another calibration than the configuration's is refused with both files, unless --calibration says which") {
  test::TempDir dir;
  const auto rec = dir.path() / "recording";
  std::filesystem::copy(sim_dir() + "/recording", rec, std::filesystem::copy_options::recursive);
  // Another tool's recording (no `generator: markcell sim`), replayed with a configuration
  // whose cameras are 2 mm further apart than the ones that took it.
  std::string manifest = read_file((rec / "recording.yaml").string());
  const auto at = manifest.find("generator: markcell sim\n");
  REQUIRE(at != std::string::npos);
  manifest.erase(at, std::string("generator: markcell sim\n").size());
  // ... and without the panel's mesh: nothing to score the sprays on but the aim.
  const auto mesh_at = manifest.find("panel_mesh: panel.ply\n");
  REQUIRE(mesh_at != std::string::npos);
  manifest.erase(mesh_at, std::string("panel_mesh: panel.ply\n").size());
  std::ofstream((rec / "recording.yaml").string()) << manifest;
  const auto manifest_calibration = vision::Recording::open(rec.string()).manifest().calibration;
  const std::string recorded = (rec / manifest_calibration).string();
  vision::StereoCalibration cal = vision::load_stereo_calibration(recorded);
  const double tx = cal.X_CamR_CamL.translation().x();
  cal.X_CamR_CamL.translation().x() = tx + (tx < 0 ? -0.002 : 0.002);
  const std::string configured = (dir.path() / "wider_stereo.yaml").string();
  vision::save_stereo_calibration(configured, cal);
  std::string config_text = test::example_config_text({});
  const std::string example_stereo = source_path("config/calibration/marking_stereo.yaml");
  const auto stereo_at = config_text.find("  stereo: " + example_stereo + " ");
  REQUIRE(stereo_at != std::string::npos);
  config_text.replace(stereo_at, example_stereo.size() + 10, "  stereo: " + configured);
  const std::string config = " --config " + dir.write("cell.yaml", config_text);

  const std::string out = (dir.path() / "out").string();
  const auto refused = run_command("cd " + source_path("") + " && " + kMarkcell + " replay " + rec.string() + config +
                                   " --one-predictor -q --out " + out);
  INFO(refused.output);
  CHECK(refused.exit_code != 0);
  CHECK(refused.output.find("the recording's calibration " + recorded + " and the configuration's calibration.stereo " +
                            configured + " differ (largest difference: T[0] (X_CamR_CamL, m)") != std::string::npos);
  CHECK(refused.output.find("--calibration FILE") != std::string::npos);
  CHECK_FALSE(std::filesystem::exists(out + "/report.json"));

  // Told to use the recording's: replayed with it, and (not markcell sim's) without the
  // simulated arm painted in.
  const auto told = run_command("cd " + source_path("") + " && " + kMarkcell + " replay " + rec.string() + config +
                                " --one-predictor -q --calibration " + recorded + " --out " + out);
  INFO(told.output);
  REQUIRE(told.exit_code == 0);
  const std::string json = read_file(out + "/report.json");
  CHECK(parse_json(json)["calibration"] == recorded);
  CHECK(json_number(json, "vision", "arm_drawn") == 0);
  // No mesh in the recording: scored on the aim, never on the configuration's door.
  CHECK(parse_json(json)["scored_on"] == "aim");
  CHECK(json_number(json, "defects", "marked") == 3);
  CHECK(json_number(json, "false_sprays", "false_sprays") == 0);
  CHECK(json_number(json, "vision", "frames") > 20);
  // --draw-arm paints it into any recording.
  const auto drawn = run_command("cd " + source_path("") + " && " + kMarkcell + " replay " + rec.string() + config +
                                 " --one-predictor -q --draw-arm --calibration " + recorded + " --out " + out);
  INFO(drawn.output);
  REQUIRE(drawn.exit_code == 0);
  const std::string with_arm = read_file(out + "/report.json");
  CHECK(json_number(with_arm, "vision", "arm_drawn") == json_number(with_arm, "vision", "frames"));
}

TEST_CASE("a recording's panel mesh that is cut short, or outside its folder, is refused before the replay runs") {
  test::TempDir dir;
  const auto rec = dir.path() / "recording";
  std::filesystem::copy(sim_dir() + "/recording", rec, std::filesystem::copy_options::recursive);
  const std::string mesh = (rec / "panel.ply").string();
  const std::string bytes = read_file(mesh);
  std::ofstream(mesh, std::ios::binary | std::ios::trunc) << bytes.substr(0, bytes.size() / 2);
  const std::string out = (dir.path() / "out").string();
  const auto cut = run_command("cd " + source_path("") + " && " + kMarkcell + " replay " + rec.string() +
                               " --one-predictor -q --out " + out);
  INFO(cut.output);
  CHECK(cut.exit_code != 0);
  CHECK(cut.output.find(mesh + ": the PLY body ends before its header's counts") != std::string::npos);
  CHECK_FALSE(std::filesystem::exists(out + "/can.log"));
  CHECK_FALSE(std::filesystem::exists(out + "/valve.log"));

  std::string manifest = read_file((rec / "recording.yaml").string());
  const auto at = manifest.find("panel_mesh: panel.ply\n");
  REQUIRE(at != std::string::npos);
  manifest.replace(at, std::string("panel_mesh: panel.ply\n").size(), "panel_mesh: ../../door.ply\n");
  std::ofstream((rec / "recording.yaml").string()) << manifest;
  const auto outside = run_command("cd " + source_path("") + " && " + kMarkcell + " replay " + rec.string() +
                                   " --one-predictor -q --out " + out);
  INFO(outside.output);
  CHECK(outside.exit_code != 0);
  CHECK(outside.output.find("recording.yaml: key 'panel_mesh': '../../door.ply' leaves the recording folder (..)") !=
        std::string::npos);
}

TEST_CASE("sim table-i: the paper's Table I through both stations, averaged over the panels as the paper's") {
  // Two panels (a door, a fender), 2 s each: the table's averages against the per-panel
  // rows, and each row against that panel's own report.json; the figures within the
  // inspection-station issue's targets (0.3 cm rms, 0.6 cm max per axis; every MF within
  // 1.5 mm of the truth).
  test::TempDir dir;
  const std::string out = (dir.path() / "table-i").string();
  const auto r = run_command("cd " + source_path("") + " && " + kMarkcell + " sim table-i --panels 2 --seconds 2 -q --out " + out);
  INFO(r.output);
  REQUIRE(r.exit_code == 0);
  CHECK(r.output.find("Table I through the real chain: 2 panels") != std::string::npos);
  const auto doc = parse_json(read_file(out + "/report.json"));
  REQUIRE(doc["table_i"]["panels"].get<int>() == 2);
  REQUIRE(doc["panels"].size() == 2);
  CHECK(doc["panels"][0]["panel_type"] == "door");
  CHECK(doc["panels"][1]["panel_type"] == "fender");
  for (const char* key : {"max_abs_cm", "rms_cm"})
    for (std::size_t axis = 0; axis < 3; ++axis) {
      const double a = doc["panels"][0][key][axis].get<double>(), b = doc["panels"][1][key][axis].get<double>();
      CHECK(doc["table_i"][key][axis].get<double>() == Approx((a + b) / 2).margin(1e-12));
      CHECK(doc["table_i"][key][axis].get<double>() < (std::string(key) == "rms_cm" ? 0.3 : 0.6));
      for (int p = 0; p < 2; ++p) {
        const auto own = parse_json(read_file(out + "/panel-0" + std::to_string(p + 1) + "/report.json"));
        const char* own_key = std::string(key) == "rms_cm" ? "rms" : "max_abs";
        CHECK(own["intercalibration_cm"][own_key][axis].get<double>() ==
              Approx(doc["panels"][p][key][axis].get<double>()).margin(0.0005));
      }
    }
  CHECK(doc["paper"]["max_abs_cm"][2].get<double>() == 2.01);
  CHECK(doc["inspection"]["macro_features"].get<int>() == 20);
  CHECK(doc["inspection"]["mf_error_mm"]["max"].get<double>() < 1.5);
}
