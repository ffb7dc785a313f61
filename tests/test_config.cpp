// The cell configuration: the example loads, and every class of bad input is reported
// with file, line, column, key path and what was expected - all of them, not the first.
#include <catch2/catch.hpp>
#include <sys/stat.h>

#include <algorithm>
#include <filesystem>
#include <numbers>
#include <sstream>
#include <type_traits>
#include <string>

#include "markcell/host/cell.hpp"
#include "markcell/host/config.hpp"
#include "markcell/host/service_loop.hpp"
#include "test_files.hpp"

using namespace markcell;
using namespace markcell::host;

namespace {

// A small valid configuration; line numbers below refer to this text (line 1 = "cell:").
const std::string kValid = R"(cell:
  name: test-cell
executive:
  base_tick_us: 1000
  lane_stall_ms: 50
  supervisor_period_ms: 10
  lanes:
    control: {core: -1, priority: 0}
  tasks:
    plc_io: {lane: control, period_us: 1000, budget_us: 200, on_overrun: safe_stop}
    arm_link: {lane: control, period_us: 1000, budget_us: 200}
    spray_valve: {lane: control, period_us: 1000, budget_us: 100}
    sim_world: {lane: control, period_us: 1000, budget_us: 300}
watchdog:
  systemd: true
  device: {enabled: false, path: /dev/watchdog, timeout_s: 10}
safe_stop: {arm: hold, plc_fault_line: true}
devices:
  gpio:
    simulated: true
    chip: gpiochip0
    lines:
      spray_valve: {line: V}
      camera_trigger: {line: T}
      plc_panel_present: {line: P}
      plc_cycle_enable: {line: E}
      plc_estop: {line: S, active_low: true}
      plc_ready: {line: R}
      plc_busy: {line: B}
      plc_done: {line: D}
      plc_fault: {line: F}
  arm: {transport: simulated, limits: {reach_m: 1.6, max_tcp_speed_m_s: 1, max_tcp_accel_m_s2: 4, home_m: [0.3, 0, 0.6]}}
  cameras: {source: simulated, width: 640, height: 480, fps: 30, trigger: hardware}
calibration:
  stereo: stereo.yaml
  base: base.yaml
panel_types:
  door: {macro_features: 10}
spray: {pulse_ms: 80, min_pulse_ms: 5, max_pulse_ms: 500}
)";

struct Fixture {
  Fixture() {
    dir.write("stereo.yaml", test::read_file(test::source_path("config/calibration/marking_stereo.yaml")));
    dir.write("base.yaml", test::read_file(test::source_path("config/calibration/base.yaml")));
  }
  std::vector<ConfigError> check(const std::string& text) {
    return check_config(dir.write("cell.yaml", text), task_catalog());
  }
  std::string file() const { return (dir.path() / "cell.yaml").string(); }
  test::TempDir dir;
};

std::string replace(std::string s, const std::string& from, const std::string& to) {
  const auto at = s.find(from);
  REQUIRE(at != std::string::npos);
  return s.replace(at, from.size(), to);
}

// Every parameter a struct declares, as (key, stored value as text): to compare two
// instances key by key.
struct ParamValues {
  std::vector<std::pair<std::string, std::string>> values;
  template <typename T>
  void operator()(const Param& p, T& field) {
    std::ostringstream os;
    os.precision(17);
    if constexpr (std::is_same_v<T, Eigen::Vector3d>) os << field.transpose();
    else os << field;
    values.emplace_back(std::string(p.key), os.str());
  }
  template <typename E, std::size_t N>
  void operator()(const Param& p, Choice<E, N> c) {
    values.emplace_back(std::string(p.key), std::to_string(static_cast<int>(c.value)));
  }
};
template <class Params>
std::vector<std::pair<std::string, std::string>> param_values(Params params) {
  ParamValues v;
  params.Visit(v);
  return v.values;
}

// The keys written in one top-level section of a YAML text (its lines indented by two).
std::vector<std::string> section_keys(const std::string& text, const std::string& section) {
  std::vector<std::string> keys;
  std::istringstream in(text);
  bool inside = false;
  for (std::string line; std::getline(in, line);) {
    if (!line.empty() && line[0] != ' ' && line[0] != '#') inside = line.rfind(section + ":", 0) == 0;
    else if (inside && line.size() > 2 && line[2] != ' ' && line[2] != '#' && line.find(':') != std::string::npos)
      keys.push_back(line.substr(2, line.find(':') - 2));
  }
  return keys;
}

std::vector<std::string> messages(const std::vector<ConfigError>& errors) {
  std::vector<std::string> out;
  for (const auto& e : errors) out.push_back(e.to_string());
  return out;
}

}  // namespace

TEST_CASE("the example configuration loads") {
  const auto cfg = load_config(test::source_path("config/cell.example.yaml"), task_catalog());
  CHECK(cfg.name == "marking-station-sim");
  CHECK(cfg.executive.tick == millis(1));
  REQUIRE(cfg.executive.lanes.size() == 2);
  CHECK(cfg.executive.lanes[0].priority == 80);
  CHECK(cfg.executive.lanes[1].name == "vision");
  REQUIRE(cfg.executive.tasks.size() == 6);
  CHECK(cfg.executive.tasks[0].budget == micros(200));
  CHECK(cfg.executive.tasks[0].overrun == control::OverrunPolicy::kSafeStop);
  CHECK(cfg.gpio.lines[static_cast<std::size_t>(LineRole::kPlcEstop)].active_low);
  CHECK(std::filesystem::path(cfg.calibration.stereo).is_absolute());
  CHECK(std::filesystem::exists(cfg.calibration.base));
  REQUIRE(cfg.panel_types.size() == 2);
  CHECK(std::filesystem::exists(cfg.panel_types[0].file));
  CHECK(cfg.marking.predictor.kind == control::PredictorKind::kKalman);
  CHECK(cfg.vision.epipolar_px == 1.0);
}

// The example documents the defaults of its `vision:` and `marking:` sections ("all
// keys optional; these are the defaults"): they are declared once, in TrackerParams and
// MarkingParams; this holds the two together, key by key and in both directions.
TEST_CASE("the example's vision and marking sections are the declared defaults, every key written") {
  const std::string example = test::source_path("config/cell.example.yaml");
  const auto cfg = load_config(example, task_catalog());
  CHECK(param_values(cfg.vision) == param_values(vision::TrackerParams{}));
  CHECK(param_values(cfg.marking) == param_values(control::MarkingParams{}));
  const std::string text = test::read_file(example);
  const auto keys = [](auto params) {
    std::vector<std::string> k;
    for (const auto& [key, value] : param_values(params)) k.push_back(key);
    std::sort(k.begin(), k.end());
    return k;
  };
  auto written_vision = section_keys(text, "vision"), written_marking = section_keys(text, "marking");
  std::sort(written_vision.begin(), written_vision.end());
  std::sort(written_marking.begin(), written_marking.end());
  CHECK(written_vision == keys(vision::TrackerParams{}));
  CHECK(written_marking == keys(control::MarkingParams{}));
}

TEST_CASE_METHOD(Fixture, "parameters are converted once from the configuration's units to SI") {
  const auto cfg = load_config_text(kValid + R"(vision: {lk_window_px: 15, inlier_mm: 2.5, depth_max_m: 6}
marking: {settle_mm: 2, settle_deg: 30, plan_settle_ms: 250, defect_timeout_s: 1.5, predictor: two-frame,
          line_direction: [0, 1, 0], placement_limit_mm: 4}
)", dir.write("cell.yaml", ""), task_catalog());
  CHECK(cfg.vision.lk.radius == 7);  // a 15-pixel window
  CHECK(cfg.vision.inlier_m == 2.5 / 1000.0);
  CHECK(cfg.vision.depth_max == 6.0);
  CHECK(cfg.vision.depth_min == vision::TrackerParams{}.depth_min);  // not given: the default
  CHECK(cfg.marking.settle_position == 0.002);
  CHECK(cfg.marking.settle_angle == Approx(std::numbers::pi / 6));
  CHECK(cfg.marking.timing.settle == millis(250));
  CHECK(cfg.marking.timing.defect_timeout == millis(1500));
  CHECK(cfg.marking.predictor.kind == control::PredictorKind::kTwoFrame);
  CHECK(cfg.marking.line_direction_CamR == Eigen::Vector3d::UnitY());
  CHECK(cfg.marking.intercalibration.max_placement_sigma == 0.004);
  CHECK(cfg.marking.standoff == control::MarkingParams{}.standoff);
}

TEST_CASE_METHOD(Fixture, "declared parameters: range, parity and cross-field errors with their position") {
  const auto m = messages(check(kValid + R"(vision:
  lk_window_px: 20
  depth_min_m: 5
  depth_max_m: 4
marking:
  settle_deg: 45
  predictor: kalmann
  line_direction: [0.1, 0, 0]
  spray_ms: 3
)"));
  REQUIRE(m.size() == 6);
  CHECK(m[0] == file() + ":41:17: vision.lk_window_px: must be odd (a window centred on the point)");
  CHECK(m[1] == file() + ":43:16: vision.depth_max_m: must be greater than depth_min_m");
  CHECK(m[2].rfind(file() + ":48:3: marking.spray_ms: unknown key 'spray_ms' (expected one of: standoff_m, command_lead_ms,", 0) == 0);
  CHECK(m[3] == file() + ":45:15: marking.settle_deg: expected a number in [0.01, 30], got 45");
  CHECK(m[4] == file() + ":46:14: marking.predictor: expected one of: kalman, two-frame, got \"kalmann\"");
  CHECK(m[5] == file() + ":47:19: marking.line_direction: must be a unit vector (the line's travel in CamR)");
}

TEST_CASE_METHOD(Fixture, "a valid configuration has no error") { CHECK(check(kValid).empty()); }

TEST_CASE_METHOD(Fixture, "unknown keys are errors, with their position") {
  const auto e = check(replace(kValid, "  lane_stall_ms: 50\n", "  lane_stall_ms: 50\n  lane_stal_ms: 50\n"));
  REQUIRE(e.size() == 1);
  CHECK(e[0].to_string() == file() + ":6:3: executive.lane_stal_ms: unknown key 'lane_stal_ms' (expected one of: "
                                     "base_tick_us, lane_stall_ms, supervisor_period_ms, degrade_recovery_runs, "
                                     "lock_memory, lanes, tasks)");
}

TEST_CASE_METHOD(Fixture, "missing keys are errors at the map that lacks them") {
  const auto e = check(replace(kValid, "budget_us: 200, ", ""));
  REQUIRE(e.size() == 1);
  CHECK(e[0].to_string() == file() + ":10:13: executive.tasks.plc_io.budget_us: missing required key 'budget_us'");
}

TEST_CASE_METHOD(Fixture, "wrong types name what was expected and what was found") {
  const auto e = check(replace(replace(kValid, "base_tick_us: 1000", "base_tick_us: fast"), "systemd: true", "systemd: [1]"));
  REQUIRE(e.size() >= 2);
  CHECK(e[0].to_string() == file() + ":4:17: executive.base_tick_us: expected an integer in [50, 1000000], got \"fast\"");
  CHECK(e.back().to_string() == file() + ":15:12: watchdog.systemd: expected true or false, got a sequence");
}

TEST_CASE_METHOD(Fixture, "out-of-range values") {
  const auto e = check(replace(kValid, "{core: -1, priority: 0}", "{core: -1, priority: 120}"));
  REQUIRE(e.size() == 1);
  CHECK(e[0].to_string() == file() + ":8:35: executive.lanes.control.priority: expected an integer in [0, 99], got 120");
}

TEST_CASE_METHOD(Fixture, "a task period that is not a multiple of the tick") {
  const auto e = check(replace(kValid, "period_us: 1000,", "period_us: 2500,"));
  REQUIRE(e.size() == 1);
  CHECK(e[0].to_string() == file() + ":10:40: executive.tasks.plc_io.period_us: period_us 2500 is not a multiple of "
                                     "executive.base_tick_us 1000");
}

TEST_CASE_METHOD(Fixture, "a budget longer than the period") {
  const auto e = check(replace(kValid, "budget_us: 200", "budget_us: 1200"));
  REQUIRE(e.size() == 1);
  CHECK(e[0].to_string() == file() + ":10:57: executive.tasks.plc_io.budget_us: budget_us 1200 is longer than period_us 1000");
}

TEST_CASE_METHOD(Fixture, "references to undeclared lanes and unknown tasks") {
  const auto e = check(replace(kValid, "    plc_io: {lane: control,",
                               "    vision_track: {lane: vison, period_us: 1000, budget_us: 100}\n    plc_io: {lane: control,"));
  const auto m = messages(e);
  for (const auto& x : m) UNSCOPED_INFO(x);
  REQUIRE(m.size() == 2);
  CHECK(m[0] == file() + ":10:5: executive.tasks.vision_track: unknown task 'vision_track' (markcell provides: plc_io, spray_valve, arm_link, sim_world, vision, marking, camera_trigger)");
  CHECK(m[1] == file() + ":10:26: executive.tasks.vision_track.lane: lane 'vison' is not declared in executive.lanes "
                         "(declared: control)");
}

TEST_CASE_METHOD(Fixture, "inconsistent values across sections") {
  const auto text = replace(replace(kValid, "plc_done: {line: D}", "plc_done: {line: B}"), "lane_stall_ms: 50",
                            "lane_stall_ms: 15");
  const auto m = messages(check(text));
  REQUIRE(m.size() == 2);
  CHECK(m[0] == file() + ":6:25: executive.supervisor_period_ms: supervisor_period_ms 10 must be at most half of "
                         "lane_stall_ms 15, or a stall could go unseen for too long");
  CHECK(m[1] == file() + ":30:24: devices.gpio.lines.plc_done.line: line 'B' is already used by plc_busy (each role "
                         "needs its own line)");
}

TEST_CASE_METHOD(Fixture, "missing files and malformed calibration files") {
  dir.write("bad_stereo.yaml", "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\nK1: !!opencv-matrix\n   rows: 3\n"
                               "   cols: 4\n   dt: d\n   data: [1,0,0,0, 0,1,0,0, 0,0,1,0]\n");
  const auto text = replace(replace(kValid, "stereo: stereo.yaml", "stereo: bad_stereo.yaml"), "base: base.yaml",
                            "base: calib/nowhere.yaml");
  const auto m = messages(check(text));
  REQUIRE(m.size() == 2);
  CHECK(m[0] == file() + ":36:9: calibration.base: file 'calib/nowhere.yaml' not found (looked for " +
                    (dir.path() / "calib/nowhere.yaml").string() + ")");
  CHECK(m[1] == file() + ":35:11: calibration.stereo: " + (dir.path() / "bad_stereo.yaml").string() +
                    ": key 'K1': expected a 3x3 matrix, got 3x4");
}

TEST_CASE_METHOD(Fixture, "simulated devices and the tasks that run them go together") {
  auto m = messages(check(replace(kValid, "    sim_world: {lane: control, period_us: 1000, budget_us: 300}\n", "")));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == file() + ":10:5: executive.tasks: devices.arm.transport is simulated: the sim_world task must be in the table");
  m = messages(check(replace(kValid, "transport: simulated, limits", "transport: serial, serial: {device: /dev/ttyS1, baud: 115200, "
                                                                      "ack_timeout_ms: 20, retries: 3}, limits")));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == file() + ":13:16: executive.tasks.sim_world: no device is simulated: remove sim_world");
}

// The loader's task rules come from the cell's task table (Cell::task_entries): a task
// it declares required, the needs it declares with their reasons, heavy work off the
// control tasks' lane.
TEST_CASE_METHOD(Fixture, "the task table's declarations are the loader's rules, each error at its task") {
  auto m = messages(check(replace(kValid, "    spray_valve: {lane: control, period_us: 1000, budget_us: 100}\n", "")));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == file() + ":10:5: executive.tasks: the spray_valve task must be in the table (it opens and closes the valve on the tick)");
  m = messages(check(replace(kValid, "    plc_io: {lane: control, period_us: 1000, budget_us: 200, on_overrun: safe_stop}\n",
                             "    marking: {lane: control, period_us: 2000, budget_us: 200}\n")));
  REQUIRE(m.size() == 2);
  CHECK(m[0] == file() + ":10:14: executive.tasks.marking: the marking task needs the vision task in the table");
  CHECK(m[1] == file() + ":10:14: executive.tasks.marking: the marking task needs the plc_io task in the table "
                         "(panel present and the valve's interlock come from it)");
  dir.write("door.yaml", test::read_file(test::source_path("config/panels/door.yaml")));
  const std::string with_vision =
      replace(replace(kValid, "  door: {macro_features: 10}", "  door: {macro_features: 10, file: door.yaml}"),
              "    sim_world: {lane: control, period_us: 1000, budget_us: 300}\n",
              "    sim_world: {lane: control, period_us: 1000, budget_us: 300}\n"
              "    vision: {lane: control, period_us: 33000, budget_us: 30000}\n");
  m = messages(check(with_vision));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == file() + ":14:20: executive.tasks.vision.lane: the vision task does per-frame work: it needs a lane "
                         "without control tasks (plc_io is on this one)");
  // On a lane of its own it is accepted.
  CHECK(check(replace(replace(replace(with_vision, "    vision: {lane: control", "    vision: {lane: vision"),
                              "lane_stall_ms: 50", "lane_stall_ms: 100"),
                      "    control: {core: -1, priority: 0}\n",
                      "    control: {core: -1, priority: 0}\n    vision: {core: -1, priority: 0}\n"))
            .empty());
}

// docs/executive.md shows the task table as `markcell check-config --tasks` prints it.
TEST_CASE("docs/executive.md shows the task table the cell declares") {
  const std::string page = test::read_file(test::source_path("docs/executive.md"));
  const std::string table = task_table_markdown(task_catalog());
  CHECK(page.find(table) != std::string::npos);
  REQUIRE(task_catalog().size() == Cell::task_entries().size());
  for (std::size_t i = 0; i < task_catalog().size(); ++i)
    CHECK(task_catalog()[i].name == Cell::task_entries()[i].decl.name);
}

TEST_CASE_METHOD(Fixture, "a serial arm's STATE timeout: 150 ms unless given, read in milliseconds, checked") {
  const auto serial = [&](const std::string& extra) {
    return replace(replace(kValid, "    sim_world: {lane: control, period_us: 1000, budget_us: 300}\n", ""),
                   "transport: simulated, limits",
                   "transport: serial, serial: {device: /dev/ttyS1, baud: 115200, ack_timeout_ms: 20, retries: 3" + extra +
                       "}, limits");
  };
  REQUIRE(check(serial("")).empty());
  CHECK(load_config(file(), task_catalog()).arm.serial.state_timeout == millis(150));
  REQUIRE(check(serial(", state_timeout_ms: 400")).empty());
  CHECK(load_config(file(), task_catalog()).arm.serial.state_timeout == millis(400));
  const auto m = messages(check(serial(", state_timeout_ms: 0")));
  REQUIRE(m.size() == 1);
  CHECK(m[0].find("devices.arm.serial.state_timeout_ms: expected an integer in [1, 65535], got 0") != std::string::npos);
}

TEST_CASE_METHOD(Fixture, "spray pulse and arm limits are checked against each other") {
  auto m = messages(check(replace(replace(kValid, "pulse_ms: 80", "pulse_ms: 800"), "home_m: [0.3, 0, 0.6]", "home_m: [2, 0, 0.6]")));
  REQUIRE(m.size() == 2);
  CHECK(m[0] == file() + ":39:19: spray.pulse_ms: pulse_ms 800 is outside [min_pulse_ms, max_pulse_ms] = [5, 500]");
  CHECK(m[1] == file() + ":32:107: devices.arm.limits.home_m: home is beyond reach_m");
}

TEST_CASE_METHOD(Fixture, "sections of the wrong kind are errors, not crashes (found by the fuzzer)") {
  for (const char* executive : {"executive: 5\n", "executive: [a, b]\n", "executive: {tasks: 3}\n", "executive: {}\n"}) {
    const auto e = check(executive);
    REQUIRE_FALSE(e.empty());
    CHECK(e[0].path == "cell");  // the first missing section, at the document
  }
  const auto e = check("executive: 5\n");
  bool named = false;
  for (const auto& x : e) named |= x.to_string() == file() + ":1:12: executive: expected a map, got \"5\"";
  CHECK(named);
}

TEST_CASE_METHOD(Fixture, "YAML syntax errors carry their position") {
  const auto m = messages(check(replace(kValid, "  door: {macro_features: 10}", "  door: {macro_features: 10")));
  REQUIRE(m.size() == 1);
  CHECK(m[0].rfind(file() + ":", 0) == 0);
  CHECK(m[0].find("(document): YAML syntax: ") != std::string::npos);
}

TEST_CASE_METHOD(Fixture, "every error is reported, not only the first") {
  std::string text = replace(kValid, "base_tick_us: 1000", "base_tick_us: 0");
  text = replace(text, "fps: 30", "fps: -1");
  text = replace(text, "transport: simulated", "transport: ethercat");
  text = replace(text, "door: {macro_features: 10}", "door: {macro_features: 10, colour: red}");
  const auto e = check(text);
  const auto m = messages(e);
  for (const auto& x : m) UNSCOPED_INFO(x);
  REQUIRE(m.size() == 4);
  CHECK(e[0].path == "executive.base_tick_us");
  CHECK(e[1].path == "devices.arm.transport");
  CHECK(e[1].message == "expected one of: simulated, can, serial, got \"ethercat\"");
  CHECK(e[2].path == "devices.cameras.fps");
  CHECK(e[3].path == "panel_types.door.colour");
  REQUIRE_THROWS_AS(load_config(file(), task_catalog()), ConfigInvalid);
}

TEST_CASE_METHOD(Fixture, "cameras: the pair's trigger, each camera's own settings under left and right, refused with why") {
  const std::string pair = "cameras: {source: simulated, width: 640, height: 480, fps: 30, trigger: hardware}";
  const auto cfg = load_config_text(
      replace(kValid, pair,
              "cameras: {source: aravis, width: 640, height: 480, fps: 30, trigger: hardware, trigger_source: Line2, "
              "trigger_activation: falling_edge,\n"
              "    left: {id: cam-L, exposure_us: 3000, gain_db: 6, packet_size: 8192, packet_delay_ticks: 1200},\n"
              "    right: {id: cam-R, exposure_us: 5000}}"),
      file(), task_catalog());
  // What each camera is opened with: the pair's settings and its own (defaults where not written).
  const drivers::CameraSettings left = camera_settings(cfg.cameras, cfg.cameras.left);
  const drivers::CameraSettings right = camera_settings(cfg.cameras, cfg.cameras.right);
  CHECK(left.id == "cam-L");
  CHECK(left.exposure_us == 3000);
  CHECK(left.gain_db == 6);
  CHECK(left.packet_size == 8192);
  CHECK(left.packet_delay_ticks == 1200);
  CHECK(right.id == "cam-R");
  CHECK(right.exposure_us == 5000);
  CHECK(right.gain_db == 0);
  CHECK(right.packet_size == 0);
  CHECK(right.packet_delay_ticks == 0);
  for (const auto& s : {left, right}) {
    CHECK(s.width == 640);
    CHECK(s.trigger == drivers::TriggerMode::kHardware);
    CHECK(s.trigger_source == "Line2");
    CHECK(s.trigger_activation == drivers::TriggerActivation::kFallingEdge);
  }

  // Refused, each at its key: no left id with aravis, the same id twice, an exposure
  // longer than a frame, an activation GenICam does not have, a packet bigger than UDP's,
  // and the pair-level exposure of earlier configurations (each camera has its own).
  const auto e = check(replace(
      kValid, pair,
      "cameras: {source: aravis, width: 640, height: 480, fps: 30, trigger: hardware, trigger_activation: rising,\n"
      "    exposure_us: 4000, left: {packet_size: 70000}, right: {id: cam-R, exposure_us: 40000}}"));
  const auto m = messages(e);
  for (const auto& x : m) UNSCOPED_INFO(x);
  REQUIRE(e.size() == 5);
  CHECK(e[0].path == "devices.cameras.exposure_us");
  CHECK(e[1].path == "devices.cameras.trigger_activation");
  CHECK(e[1].message == "expected one of: rising_edge, falling_edge, any_edge, level_high, level_low, got \"rising\"");
  CHECK(e[2].path == "devices.cameras.left.packet_size");
  CHECK(e[3].path == "devices.cameras.left");
  CHECK(e[3].message == "missing required key 'left.id' (source: aravis): the left camera's Aravis device id");
  CHECK(e[4].path == "devices.cameras.right");
  CHECK(e[4].message == "exposure_us 40000 is longer than a frame at fps 30 (33333 us)");
  const auto same = check(replace(kValid, pair,
                                  "cameras: {source: aravis, width: 640, height: 480, fps: 30, trigger: hardware,\n"
                                  "    left: {id: cam-A}, right: {id: cam-A}}"));
  REQUIRE(same.size() == 1);
  CHECK(same[0].path == "devices.cameras.right");
  CHECK(same[0].message == "right.id must differ from left.id 'cam-A'");
}

TEST_CASE_METHOD(Fixture, "the results file: resolved against the config's folder, its folder must exist") {
  const auto ok = load_config_text(replace(kValid, "name: test-cell", "name: test-cell\n  results_file: results.jsonl"), file(),
                                   task_catalog());
  CHECK(ok.results_file == (dir.path() / "results.jsonl").string());
  const auto m = messages(check(replace(kValid, "name: test-cell", "name: test-cell\n  results_file: nowhere/results.jsonl")));
  REQUIRE(m.size() == 1);
  CHECK(m[0].find("cell.results_file: folder '" + (dir.path() / "nowhere").string() + "' does not exist") != std::string::npos);
}

TEST_CASE_METHOD(Fixture, "base_calibration: poses and the board's mounting as six numbers, each checked") {
  const std::string ok_poses =
      "base_calibration:\n  board: {cols: 7, rows: 5, square_m: 0.04}\n  poses:\n"
      "    - [0.2, 0.4, 1.0, 0, -90, 0]\n    - [0.1, 0.4, 1.0, 0, -90, 0]\n    - [0.2, 0.3, 1.0, 0, -90, 0]\n"
      "    - [0.2, 0.4, 0.9, 0, -90, 0]\n    - [0.3, 0.4, 1.0, 0, -90, 0]\n    - [0.2, 0.5, 1.0, 0, -90, 0]\n";
  const auto cfg = load_config_text(kValid + ok_poses, file(), task_catalog());
  CHECK(cfg.base_calibration.board.cols == 7);
  REQUIRE(cfg.base_calibration.poses.size() == 6);
  CHECK(cfg.base_calibration.poses[3][2] == 0.9);
  CHECK(cfg.base_calibration.poses[3][4] == -90.0);

  const auto lines = std::count(kValid.begin(), kValid.end(), '\n');
  const auto bad = messages(check(kValid + replace(ok_poses, "[0.2, 0.4, 0.9, 0, -90, 0]", "[0.2, 0.4, 0.9, 0, -90]")));
  REQUIRE(bad.size() == 1);
  CHECK(bad[0] == file() + ":" + std::to_string(lines + 7) +
                      ":7: base_calibration.poses[3]: expected [x, y, z, rx, ry, rz]: metres within 10, a rotation vector "
                      "in degrees within 360, got a sequence");
  const auto few = messages(check(kValid + "base_calibration:\n  poses: [[0, 0, 1, 0, 0, 0]]\n"));
  REQUIRE(few.size() == 1);
  CHECK(few[0] == file() + ":" + std::to_string(lines + 2) +
                      ":10: base_calibration.poses: expected a list of 6 to 200 poses, got a sequence of 1");
}

TEST_CASE_METHOD(Fixture, "the record folder: resolved against the config's folder, it must exist") {
  std::filesystem::create_directories(dir.path() / "records");
  const auto ok = load_config_text(replace(kValid, "name: test-cell", "name: test-cell\n  record_folder: records"), file(),
                                   task_catalog());
  CHECK(ok.record_folder == (dir.path() / "records").string());
  const auto m = messages(check(replace(kValid, "name: test-cell", "name: test-cell\n  record_folder: nowhere")));
  REQUIRE(m.size() == 1);
  CHECK(m[0].find("cell.record_folder: folder '" + (dir.path() / "nowhere").string() + "' does not exist") != std::string::npos);
}

TEST_CASE_METHOD(Fixture, "the operator page: off unless given, ADDRESS:PORT, each error at its key") {
  CHECK(load_config_text(kValid, file(), task_catalog()).operator_page.empty());
  const auto ok = load_config_text(replace(kValid, "name: test-cell", "name: test-cell\n  operator_page: 127.0.0.1:8089"), file(),
                                   task_catalog());
  CHECK(ok.operator_page == "127.0.0.1:8089");
  auto m = messages(check(replace(kValid, "name: test-cell", "name: test-cell\n  operator_page: localhost:8089")));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == file() + ":3:18: cell.operator_page: 'localhost' is not an IPv4 address (e.g. 127.0.0.1, or 0.0.0.0 for every interface)");
  m = messages(check(replace(kValid, "name: test-cell", "name: test-cell\n  operator_page: 0.0.0.0:80800")));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == file() + ":3:18: cell.operator_page: port '80800' is not a number from 1 to 65535");
  m = messages(check(replace(kValid, "name: test-cell", "name: test-cell\n  operator_page: [8089]")));
  REQUIRE(m.size() == 1);
  CHECK(m[0].rfind(file() + ":3:18: cell.operator_page: expected ", 0) == 0);
}

TEST_CASE_METHOD(Fixture, "the line: records in order unless a panel-id source is given and modbus checked key by key") {
  CHECK(load_config_text(kValid, file(), task_catalog()).line.panel_id_source == PanelIdSource::kNone);
  REQUIRE(kValid.back() == '\n');
  const int line = static_cast<int>(std::count(kValid.begin(), kValid.end(), '\n')) + 1;  // the `line:` key's
  const auto ok = load_config_text(
      kValid + "line:\n  panel_id_source: modbus\n  modbus:\n    server: 10.0.0.5:502\n    plc_block: 10\n", file(), task_catalog());
  CHECK(ok.line.panel_id_source == PanelIdSource::kModbus);
  CHECK(ok.line.modbus.server == "10.0.0.5:502");
  CHECK(ok.line.modbus.plc_block == 10);
  CHECK(ok.line.modbus.cell_block == 100);
  CHECK(ok.line.modbus.poll == millis(20));
  CHECK(ok.line.silent == seconds(1));
  const auto at = [&](int l, int c) { return file() + ":" + std::to_string(line + l) + ":" + std::to_string(c) + ": "; };
  auto m = messages(check(kValid + "line:\n  panel_id_source: modbus\n"));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == at(1, 3) + "line.modbus: missing required key 'modbus.server' (panel_id_source: modbus): the PLC's ADDRESS:PORT");
  m = messages(check(kValid + "line:\n  panel_id_source: modbus\n  modbus:\n    server: plc.local:502\n"));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == at(3, 13) + "line.modbus.server: 'plc.local' is not an IPv4 address (e.g. 127.0.0.1, or 0.0.0.0 for every interface)");
  m = messages(check(kValid + "line:\n  panel_id_source: modbus\n  modbus:\n    server: 10.0.0.5:502\n    cell_block: 30\n"));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == at(4, 17) + "line.modbus.cell_block: the cell's block (30..+8) overlaps the PLC's (0..+49)");
  m = messages(check(kValid + "line:\n  panel_id_source: modbus\n  silent_ms: 50\n  modbus:\n    server: 10.0.0.5:502\n"));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == at(2, 14) + "line.silent_ms: silent_ms 50 must be at least three polls (modbus.poll_ms 20)");
  m = messages(check(kValid + "line:\n  panel_id_source: opc-ua\n"));
  REQUIRE(m.size() == 1);
  CHECK(m[0].rfind(at(1, 20) + "line.panel_id_source: ", 0) == 0);
}

TEST_CASE_METHOD(Fixture, "the broker: paths beside the configuration and its names and secrets checked") {
  std::filesystem::create_directories(dir.path() / "records");
  std::filesystem::create_directories(dir.path() / "secrets");
  const std::string password = dir.write("secrets/mark-1.password", "s3cret\n");
  std::filesystem::permissions(password, std::filesystem::perms::owner_read | std::filesystem::perms::owner_write);
  const std::string ca = dir.write("secrets/ca.crt", "-----BEGIN CERTIFICATE-----\n");
  const std::string with_folder = replace(kValid, "name: test-cell", "name: test-cell\n  record_folder: records");
  const int line = static_cast<int>(std::count(with_folder.begin(), with_folder.end(), '\n')) + 1;  // `line:`
  const auto at = [&](int l, int c) { return file() + ":" + std::to_string(line + l) + ":" + std::to_string(c) + ": "; };
  const std::string broker = "line:\n  panel_id_source: broker\n  broker:\n    server: 10.0.0.2:8883\n    line: line-1\n"
                             "    station: mark-1\n    username: mark-1\n    password_file: secrets/mark-1.password\n"
                             "    ca_file: secrets/ca.crt\n";
  const auto ok = load_config_text(with_folder + broker, file(), task_catalog());
  CHECK(ok.line.panel_id_source == PanelIdSource::kBroker);
  CHECK(ok.line.broker.password_file == password);
  CHECK(ok.line.broker.ca_file == ca);
  CHECK(ok.line.broker.keepalive == seconds(5));
  CHECK(ok.line.broker.record_retain == seconds(600));
  // A station name that is not a topic level, a password others can read, no record folder.
  auto m = messages(check(with_folder + replace(broker, "station: mark-1", "station: mark/1")));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == at(5, 14) + "line.broker.station: 'mark/1': only letters, digits, - and _ (it is a topic level and the client id)");
  std::filesystem::permissions(password, std::filesystem::perms::group_read | std::filesystem::perms::others_read,
                               std::filesystem::perm_options::add);
  m = messages(check(with_folder + broker));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == at(7, 20) + "line.broker.password_file: '" + password + "' can be read by others (mode 0644): chmod 600 it");
  m = messages(check(with_folder + replace(broker, "secrets/ca.crt", "secrets/missing.crt")));
  REQUIRE(m.size() == 2);  // (and the password's mode)
  CHECK(m[1] == at(8, 14) + "line.broker.ca_file: '" + (dir.path() / "secrets/missing.crt").string() + "' is not a regular file");
  const int plain = static_cast<int>(std::count(kValid.begin(), kValid.end(), '\n')) + 1;
  m = messages(check(kValid + broker));
  REQUIRE(m.size() == 2);
  CHECK(m[1] == file() + ":" + std::to_string(plain + 3) +
                    ":5: line.broker: a station on the broker keeps the records it receives in cell.record_folder until "
                    "they are used: set it");
  m = messages(check(with_folder + "line:\n  panel_id_source: broker\n"));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == at(1, 3) + "line.broker: missing required key 'broker.server' (panel_id_source: broker): the broker's ADDRESS:PORT");
}

TEST_CASE("pairing in order is warned about only for a marking cell with a record folder and no panel-id source") {
  CellConfig cfg;
  control::TaskSpec marking;
  marking.name = "marking";
  cfg.executive.tasks.push_back(marking);
  CHECK(pairing_warning(cfg).empty());  // no record folder: no records to pair
  cfg.record_folder = "/var/lib/markcell/records";
  CHECK(pairing_warning(cfg).rfind("line.panel_id_source is none: records pair with panels in the order they come, so a "
                                   "panel taken off the line",
                                   0) == 0);
  cfg.line.panel_id_source = PanelIdSource::kModbus;
  CHECK(pairing_warning(cfg).empty());
  cfg.line.panel_id_source = PanelIdSource::kNone;
  cfg.executive.tasks.clear();  // no marking task: nothing is sprayed
  CHECK(pairing_warning(cfg).empty());
}

TEST_CASE_METHOD(Fixture, "the pose log: its folder resolved and required to exist, its rotation size in range") {
  std::filesystem::create_directories(dir.path() / "poses");
  const auto ok = load_config_text(
      replace(kValid, "name: test-cell", "name: test-cell\n  pose_log_folder: poses\n  pose_log_rotate_mb: 8"), file(), task_catalog());
  CHECK(ok.pose_log_folder == (dir.path() / "poses").string());
  CHECK(ok.pose_log_rotate_mb == 8);
  CHECK(load_config_text(kValid, file(), task_catalog()).pose_log_rotate_mb == 64);  // the default
  const auto m = messages(check(replace(kValid, "name: test-cell", "name: test-cell\n  pose_log_folder: nowhere\n  pose_log_rotate_mb: 0")));
  REQUIRE(m.size() == 2);
  CHECK(m[0] == file() + ":3:20: cell.pose_log_folder: folder '" + (dir.path() / "nowhere").string() + "' does not exist");
  CHECK(m[1] == file() + ":4:23: cell.pose_log_rotate_mb: expected an integer in [1, 1048576], got 0");
}

TEST_CASE_METHOD(Fixture, "camera_trigger: twice the frame rate, and only with the cameras on the trigger line") {
  const std::string with_trigger =
      replace(kValid, "    sim_world: {lane: control, period_us: 1000, budget_us: 300}\n",
              "    sim_world: {lane: control, period_us: 1000, budget_us: 300}\n"
              "    camera_trigger: {lane: control, period_us: 17000, budget_us: 50}\n");
  CHECK(check(with_trigger).empty());  // 17 ms: 29.41 frames/s against 30, within 2 %
  auto m = messages(check(replace(with_trigger, "period_us: 17000", "period_us: 33000")));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == file() + ":14:21: executive.tasks.camera_trigger: period_us 33000 gives 15.15 frames/s (a rising edge every "
                         "other run); devices.cameras.fps is 30: set period_us to 17000 (the multiple of the 1000 us tick nearest 16667)");
  m = messages(check(replace(with_trigger, "trigger: hardware}", "trigger: software}")));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == file() + ":14:21: executive.tasks.camera_trigger: devices.cameras.trigger is software: the cameras are not on "
                         "the trigger line; remove camera_trigger or set trigger: hardware");
}

TEST_CASE_METHOD(Fixture, "the PLC inputs' filter and the re-arm after an e-stop: defaults, values, errors with their position") {
  REQUIRE(check(kValid).empty());
  CellConfig c = load_config(file(), task_catalog());
  CHECK(c.gpio.input_filter == millis(3));
  CHECK(c.safe_stop.rearm == RearmConfig::kCycleEnable);
  REQUIRE(check(replace(replace(kValid, "chip: gpiochip0", "chip: gpiochip0\n    input_filter_us: 500"), "plc_fault_line: true}",
                        "plc_fault_line: true, rearm: never}")).empty());
  c = load_config(file(), task_catalog());
  CHECK(c.gpio.input_filter == micros(500));
  CHECK(c.safe_stop.rearm == RearmConfig::kNever);
  auto m = messages(check(replace(replace(kValid, "chip: gpiochip0", "chip: gpiochip0\n    input_filter_us: 200000"),
                                  "plc_fault_line: true}", "plc_fault_line: true, rearm: sometimes}")));
  REQUIRE(m.size() == 2);
  CHECK(m[0] == file() + ":17:53: safe_stop.rearm: expected one of: cycle_enable, never, got \"sometimes\"");
  CHECK(m[1] == file() + ":22:22: devices.gpio.input_filter_us: expected an integer in [0, 100000], got 200000");
}

TEST_CASE_METHOD(Fixture, "only a regular file of a bounded size is read: a FIFO, a device, a folder, a huge file are refused at once") {
  const std::string fifo = (dir.path() / "fifo.yaml").string();
  REQUIRE(::mkfifo(fifo.c_str(), 0600) == 0);  // nobody writes it: reading it would block for ever
  auto m = messages(check_config(fifo, task_catalog()));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == fifo + ": (document): a FIFO, not read (a cell configuration must be a regular file)");
  m = messages(check_config("/dev/zero", task_catalog()));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == "/dev/zero: (document): a character device, not read (a cell configuration must be a regular file)");
  m = messages(check_config(dir.path().string(), task_catalog()));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == dir.path().string() + ": (document): a directory, not read (a cell configuration must be a regular file)");
  const std::string huge = dir.write("huge.yaml", kValid + "# " + std::string(kMaxConfigBytes, 'x') + "\n");
  m = messages(check_config(huge, task_catalog()));
  REQUIRE(m.size() == 1);
  CHECK(m[0].find(huge + ": (document): " + std::to_string(kValid.size() + kMaxConfigBytes + 3) + " bytes, more than the 1048576 allowed") == 0);
}

TEST_CASE_METHOD(Fixture, "a nesting bomb, an empty file, a second document, a key given twice: each an error with its position") {
  auto m = messages(check(std::string(50'000, '[') + "\n"));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == file() + ":1:1: (document): nested more than 64 levels deep");
  m = messages(check(""));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == file() + ":1:1: (document): the file is empty: expected the cell configuration (a map)");
  m = messages(check(kValid + "---\ncell: {name: other}\n"));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == file() + ":40:1: (document): a second YAML document: a cell configuration is one document");
  m = messages(check(replace(kValid, "    arm_link: {lane", "    plc_io: {lane: control, period_us: 2000, budget_us: 100}\n    arm_link: {lane")));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == file() + ":11:5: executive.tasks.plc_io: declared twice in this map (yaml would keep only one)");
  m = messages(check(replace(kValid, "  door: {macro_features: 10}", "  door: {macro_features: 10}\n  door: {macro_features: 8}")));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == file() + ":39:3: panel_types.door: declared twice in this map (yaml would keep only one)");
}

TEST_CASE_METHOD(Fixture, "recipes: a panel type's process settings over the spray and marking sections, each checked at its key") {
  const std::string two = replace(kValid, "  door: {macro_features: 10}\n",
                                  "  door: {macro_features: 10, recipe: {standoff_m: 0.18, pulse_ms: 60, settle_mm: 1.0, "
                                  "placement_limit_mm: 0.5}}\n  fender: {macro_features: 10}\n");
  const CellConfig c =
      load_config(dir.write("cell.yaml", two + "marking: {standoff_m: 0.22, command_lead_ms: 40}\n"), task_catalog());
  REQUIRE(c.panel_types.size() == 2);
  const PanelTypeConfig& door = c.panel_types[0];
  const PanelTypeConfig& fender = c.panel_types[1];
  CHECK(door.has_recipe);
  CHECK_FALSE(fender.has_recipe);
  CHECK(door.marking.standoff == Approx(0.18));
  CHECK(door.pulse == millis(60));
  CHECK(door.marking.settle_position == Approx(0.001));
  CHECK(door.marking.intercalibration.max_placement_sigma == Approx(0.0005));
  CHECK(door.marking.command_lead == millis(40));  // not a recipe's key: the section's, for every type
  CHECK(fender.marking.standoff == Approx(0.22));  // no recipe: the sections' values
  CHECK(fender.pulse == millis(80));
  CHECK(fender.marking.settle_position == c.marking.settle_position);

  // A key out of range and a key a recipe cannot set: each at its position, the keys it can
  // named; a pulse the valve would refuse, against the spray section's limits.
  auto m = messages(check(replace(kValid, "  door: {macro_features: 10}\n",
                                  "  door: {macro_features: 10, recipe: {standoff_m: 5, command_lead_ms: 10}}\n")));
  REQUIRE(m.size() == 2);
  CHECK(m[0] == file() + ":38:54: panel_types.door.recipe.command_lead_ms: unknown key 'command_lead_ms' (expected one of: "
                         "pulse_ms, standoff_m, settle_mm, settle_deg, settle_ms, defect_timeout_s, placement_limit_mm, "
                         "placement_hold_s)");
  CHECK(m[1] == file() + ":38:51: panel_types.door.recipe.standoff_m: expected a number in [0.01, 1], got 5");
  m = messages(check(replace(kValid, "  door: {macro_features: 10}\n", "  door: {macro_features: 10, recipe: {pulse_ms: 600}}\n")));
  REQUIRE(m.size() == 1);
  CHECK(m[0] == file() + ":38:49: panel_types.door.recipe.pulse_ms: 600 ms is outside the valve's limits, "
                         "spray.min_pulse_ms 5 to spray.max_pulse_ms 500");
}

TEST_CASE_METHOD(Fixture, "a reload takes the recipes the file gives now, and refuses a file that is invalid or has other panel types") {
  const std::string with_recipe =
      replace(kValid, "  door: {macro_features: 10}\n", "  door: {macro_features: 10, recipe: {standoff_m: 0.18}}\n");
  const CellConfig running = load_config(dir.write("cell.yaml", with_recipe), task_catalog());
  // Edited: a new stand-off for the door, and a marking section's key (that one takes a restart).
  dir.write("cell.yaml", replace(with_recipe, "standoff_m: 0.18", "standoff_m: 0.16, settle_ms: 80") +
                             "marking: {standoff_m: 0.30, settle_mm: 2.0}\n");
  const std::vector<PanelTypeConfig> reloaded = reload_recipes(running, task_catalog());
  REQUIRE(reloaded.size() == 1);
  CHECK(reloaded[0].marking.standoff == Approx(0.16));
  CHECK(reloaded[0].marking.settle_time == millis(80));
  CHECK(reloaded[0].marking.settle_position == running.marking.settle_position);  // the running section's, not 2 mm
  // Invalid now: every error, nothing taken.
  dir.write("cell.yaml", replace(with_recipe, "standoff_m: 0.18", "standoff_m: 7"));
  try {
    reload_recipes(running, task_catalog());
    FAIL("an invalid file was taken");
  } catch (const ConfigInvalid& e) {
    REQUIRE(e.errors().size() == 1);
    CHECK(e.errors()[0].to_string() == file() + ":38:51: panel_types.door.recipe.standoff_m: expected a number in [0.01, 1], got 7");
  }
  // Another panel type: a restart's business.
  dir.write("cell.yaml", replace(with_recipe, "  door: {", "  hood: {"));
  try {
    reload_recipes(running, task_catalog());
    FAIL("changed panel types were taken");
  } catch (const ConfigInvalid& e) {
    REQUIRE(e.errors().size() == 1);
    CHECK(e.errors()[0].to_string() == file() + ": panel_types: the panel types changed (their names, order, files or "
                                                "macro_features): that takes a restart (systemctl restart markcell)");
  }
}
