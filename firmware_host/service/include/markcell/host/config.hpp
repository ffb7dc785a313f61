#pragma once
// The cell configuration: one YAML file per cell (config/cell.example.yaml documents
// every key). Loading validates everything before anything starts and reports every
// problem, each with file, line, column, key path and what was expected.
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "markcell/common/param.hpp"
#include "markcell/common/time.hpp"
#include "markcell/drivers/camera.hpp"
#include "markcell/drivers/can_arm_link.hpp"
#include "markcell/drivers/serial_arm_link.hpp"
#include "markcell/drivers/watchdog_device.hpp"
#include "markcell/control/base_calibration.hpp"
#include "markcell/control/executive.hpp"
#include "markcell/control/line_role.hpp"
#include "markcell/control/marking.hpp"
#include "markcell/control/planner.hpp"
#include "markcell/vision/panel_tracker.hpp"

namespace markcell::host {

// What the loader reads at most (docs/operation.md): a larger file, or one nested
// deeper, is refused before it is parsed.
inline constexpr std::size_t kMaxConfigBytes = 1 << 20;
inline constexpr int kMaxYamlNesting = 64;

struct ConfigError {
  std::string file;
  int line = 0;    // 1-based; 0 when the position is unknown
  int column = 0;  // 1-based
  std::string path;  // key path, e.g. executive.tasks.plc_io.budget_us
  std::string message;
  std::string to_string() const;  // FILE:LINE:COL: PATH: MESSAGE
};

class ConfigInvalid : public std::runtime_error {
 public:
  explicit ConfigInvalid(std::vector<ConfigError> errors);
  const std::vector<ConfigError>& errors() const { return errors_; }

 private:
  std::vector<ConfigError> errors_;
};

// The PLC and cell I/O lines, by role (control/line_role.hpp).
using control::LineRole;
using control::kLineRoleCount;
using control::is_output;
using control::to_string;

struct GpioLineConfig {
  std::string line;        // line name as the kernel knows it (gpioinfo), or a number
  bool active_low = false;

  template <class V>
  void Visit(V& v) {
    v(Param{"line", Unit::kNone, 1, 255, "the line's name as the kernel knows it (gpioinfo), or its number", true}, line);
    v(Param{"active_low", Unit::kNone, 0, 0, "the wiring inverts the level"}, active_low);
  }
};

// `devices.gpio`; its `lines` (one GpioLineConfig per LineRole) are read as a table.
struct GpioConfig {
  bool simulated = true;
  std::string chip;        // chip name (gpiochip0), label, or path under /dev
  std::array<GpioLineConfig, kLineRoleCount> lines;
  // The PLC inputs' debounce on their edges' times (plc_io.hpp, docs/safety.md): a
  // pulse shorter than this is ignored, a level that lasts it counts. The valve's own
  // interlock on panel present is not filtered.
  Nanos input_filter = millis(3);

  template <class V>
  void Visit(V& v) {
    v(Param{"simulated", Unit::kNone, 0, 0, "false: the libgpiod chip below", true}, simulated);
    v(Param{"chip", Unit::kNone, 1, 255, "name, label or /dev path of the GPIO chip", true}, chip);
    v(Param{"input_filter_us", Unit::kMicrosecond, 0, 100'000, "PLC inputs' debounce: shorter pulses are ignored"},
      input_filter);
  }
};

enum class ArmTransport : std::uint8_t { kSimulated, kCan, kSerial };
std::string_view to_string(ArmTransport t);

// `devices.arm.can`: the bus's interface here, the link's parameters in the driver.
struct CanConfig {
  std::string interface = "can0";
  drivers::CanArmLinkConfig link;

  template <class V>
  void Visit(V& v) {
    v(Param{"interface", Unit::kNone, 1, 15, "the SocketCAN interface (IFNAMSIZ - 1 characters at most)", true}, interface);
    link.Visit(v);
  }
  template <class Report>
  void validate(Report&& report) const {
    link.validate(report);
  }
};

// `devices.arm.limits`. Their defaults are the arm model's (drivers::SimArmLimits), through
// the planner's model (control::ArmTimingModel) for the TCP limits and the reach: the
// cell's plan and its simulated arm use these values.
struct ArmLimitsConfig {
  double reach = control::ArmTimingModel{}.reach;                  // m, from the base origin
  double max_tcp_speed = control::ArmTimingModel{}.max_speed;      // m/s
  double max_tcp_accel = control::ArmTimingModel{}.max_accel;      // m/s^2
  std::array<double, 3> home = drivers::SimArmLimits{}.home.position;  // tool position at home, base frame, m

  template <class V>
  void Visit(V& v) {
    v(Param{"reach_m", Unit::kMetre, 0.1, 5.0, "the tool's reach from the base origin", true}, reach);
    v(Param{"max_tcp_speed_m_s", Unit::kMetrePerSecond, 0.01, 10.0, "the tool's speed limit", true}, max_tcp_speed);
    v(Param{"max_tcp_accel_m_s2", Unit::kMetrePerSecond2, 0.01, 100.0, "the tool's acceleration limit", true},
      max_tcp_accel);
    v(Param{"home_m", Unit::kMetre, -5.0, 5.0, "the tool's position at home, base frame", true}, home);
  }
  template <class Report>
  void validate(Report&& report) const {
    if (std::sqrt(home[0] * home[0] + home[1] * home[1] + home[2] * home[2]) > reach)
      report("home_m", "home is beyond reach_m");
  }
};

struct ArmConfig {
  ArmTransport transport = ArmTransport::kSimulated;
  CanConfig can;
  drivers::SerialArmLinkConfig serial;
  ArmLimitsConfig limits;
};

// `spray`. The pulse's default is the planner's (control::ArmTimingModel::pulse): the
// plan times each defect with the pulse the valve gives.
struct SprayConfig {
  Nanos pulse = control::ArmTimingModel{}.pulse;
  Nanos min_pulse = millis(5);
  Nanos max_pulse = millis(500);

  template <class V>
  void Visit(V& v) {
    v(Param{"pulse_ms", Unit::kMillisecond, 1, 10'000, "length of one spray (the valve opens and closes on the tick)", true},
      pulse);
    v(Param{"min_pulse_ms", Unit::kMillisecond, 1, 10'000, "the valve refuses a pulse shorter than this ...", true}, min_pulse);
    v(Param{"max_pulse_ms", Unit::kMillisecond, 1, 10'000, "... or longer than this (a bad length, not a spray)", true},
      max_pulse);
  }
  template <class Report>
  void validate(Report&& report) const {
    const auto ms = [](Nanos t) { return std::to_string(t / millis(1)); };
    if (pulse < min_pulse || pulse > max_pulse)
      report("pulse_ms", "pulse_ms " + ms(pulse) + " is outside [min_pulse_ms, max_pulse_ms] = [" + ms(min_pulse) + ", " +
                             ms(max_pulse) + "]");
  }
};

enum class CameraSource : std::uint8_t { kSimulated, kAravis, kRecording };
using CameraTrigger = drivers::TriggerMode;
std::string_view to_string(CameraSource s);
std::string_view to_string(CameraTrigger t);

// `devices.cameras`: the pair's source, what both cameras are set to (the driver's
// CameraSettings: size, rate, trigger), and each camera's own settings under `left` and
// `right` (id, exposure, gain, GigE Vision packet size and delay); `recording` is read by
// hand (a folder that must exist).
struct CameraConfig : drivers::CameraSettings {
  CameraSource source = CameraSource::kSimulated;
  drivers::CameraUnitSettings left;
  drivers::CameraUnitSettings right;
  Nanos latency = millis(15);  // exposure to frame in memory (transfer); replayed frames arrive this late
  Nanos lost_after = millis(1500);  // a live camera with no frame for this long is reported lost and reconnected
  std::string recording;       // source: recording; absolute

  template <class V>
  void Visit(V& v) {
    v(Param{"source", Unit::kNone, 0, 0, "simulated | aravis | recording", true},
      Choice<CameraSource, 3>{source,
                              {{{"simulated", CameraSource::kSimulated},
                                {"aravis", CameraSource::kAravis},
                                {"recording", CameraSource::kRecording}}}});
    CameraSettings::Visit(v);
    v(Param{"left", Unit::kNone, 0, 0, "the left camera's own settings (required with source: aravis)"},
      Section<drivers::CameraUnitSettings>{left});
    v(Param{"right", Unit::kNone, 0, 0, "the right camera's own settings (required with source: aravis)"},
      Section<drivers::CameraUnitSettings>{right});
    v(Param{"latency_ms", Unit::kMillisecond, 0, 1000, "exposure to frame in memory; replayed frames arrive this late"},
      latency);
    v(Param{"lost_after_ms", Unit::kMillisecond, 100, 60'000, "a live camera with no frame this long is lost"},
      lost_after);
  }
  template <class Report>
  void validate(Report&& report) const {
    if (source == CameraSource::kAravis) {
      if (left.id.empty()) report("left", "missing required key 'left.id' (source: aravis): the left camera's Aravis device id");
      if (right.id.empty()) report("right", "missing required key 'right.id' (source: aravis): the right camera's Aravis device id");
    }
    if (!left.id.empty() && left.id == right.id) report("right", "right.id must differ from left.id '" + left.id + "'");
    for (const auto* own : {&left, &right}) {
      if (fps > 0 && own->exposure_us > 1e6 / fps) {
        char message[160];
        std::snprintf(message, sizeof message, "exposure_us %g is longer than a frame at fps %g (%.0f us)", own->exposure_us,
                      fps, 1e6 / fps);
        report(own == &left ? "left" : "right", message);
      }
    }
  }
};

struct WatchdogConfig {
  bool systemd = true;
  Nanos systemd_interval = millis(100);  // when systemd gives no WATCHDOG_USEC
  struct Device {
    bool enabled = false;
    drivers::WatchdogDeviceConfig config;
    template <class V>
    void Visit(V& v) {
      v(Param{"enabled", Unit::kNone, 0, 0, "the hardware watchdog: the device resets the machine if not fed", true},
        enabled);
      config.Visit(v);
    }
  } device;

  template <class V>
  void Visit(V& v) {
    v(Param{"systemd", Unit::kNone, 0, 0, "READY=1, WATCHDOG=1 (only while all lanes tick), STOPPING=1", true}, systemd);
    v(Param{"systemd_interval_ms", Unit::kMillisecond, 10, 600'000, "feed interval when systemd gives none"},
      systemd_interval);
    v(Param{"device", Unit::kNone, 0, 0, "the hardware watchdog device", true}, Section<Device>{device});
  }
};

enum class ArmSafeAction : std::uint8_t { kHold, kHome };
std::string_view to_string(ArmSafeAction a);

enum class RearmConfig : std::uint8_t { kCycleEnable, kNever };

struct SafeStopConfig {
  ArmSafeAction arm = ArmSafeAction::kHold;
  // After an e-stop: the e-stop released, then a rising edge of cycle enable re-arms
  // (the arm sent home first), or `never` (a restart of the service).
  RearmConfig rearm = RearmConfig::kCycleEnable;
  bool plc_fault_line = true;  // raise the PLC fault output on every safe stop

  template <class V>
  void Visit(V& v) {
    v(Param{"arm", Unit::kNone, 0, 0, "what the arm does on a safe stop", true},
      Choice<ArmSafeAction, 2>{arm, {{{"hold", ArmSafeAction::kHold}, {"home", ArmSafeAction::kHome}}}});
    v(Param{"plc_fault_line", Unit::kNone, 0, 0, "raise plc_fault on every safe stop", true}, plc_fault_line);
    v(Param{"rearm", Unit::kNone, 0, 0, "after an e-stop: cycle_enable (released, then an edge) or never (restart)"},
      Choice<RearmConfig, 2>{rearm, {{{"cycle_enable", RearmConfig::kCycleEnable}, {"never", RearmConfig::kNever}}}});
  }
};

// `panel_types.NAME.recipe`: the process settings that belong to a panel type rather
// than to the cell (its paint and surface: the pulse and the stand-off; how exactly it
// must be hit: the settle tolerances; how surely its defects must be placed), each
// defaulting to the `spray:` or `marking:` section's value. Declared where they are
// (SprayConfig::Visit, control::MarkingParams::Visit), optional here: these keys of
// theirs, with their units, ranges and texts.
inline constexpr std::array<std::string_view, 8> kRecipeKeys{
    "pulse_ms", "standoff_m", "settle_mm", "settle_deg", "settle_ms", "defect_timeout_s", "placement_limit_mm", "placement_hold_s"};

// A visitor passing on only kRecipeKeys' parameters, each optional.
template <class V>
struct RecipeKeysOnly {
  V& visitor;
  template <class T>
  void operator()(const Param& p, T&& field) {
    for (const std::string_view key : kRecipeKeys)
      if (key == p.key) {
        Param optional = p;
        optional.required = false;
        visitor(optional, std::forward<T>(field));
        return;
      }
  }
};

struct RecipeParams {
  SprayConfig spray;               // its pulse
  control::MarkingParams marking;  // the rest

  template <class V>
  void Visit(V& v) {
    RecipeKeysOnly<V> only{v};
    spray.Visit(only);
    marking.Visit(only);
  }
};

// `panel_types.NAME`; its `file` is read by hand (a file that must exist, and parse).
struct PanelTypeConfig {
  std::string name;
  int macro_features = 10;
  std::string file;  // the panel type's MFs and templates (markcell select-mfs); absolute
  // Its process settings: `marking:` and `spray:`'s, with its `recipe` over them.
  control::MarkingParams marking;
  Nanos pulse = 0;
  bool has_recipe = false;

  template <class V>
  void Visit(V& v) {
    v(Param{"macro_features", Unit::kNone, 3, 16, "how many MFs the panel type's file has", true}, macro_features);
  }
};

struct CalibrationPaths {
  std::string stereo;  // absolute, resolved against the config file's folder
  std::string base;
};

// `markcell calibrate-base`: the board on the gripper and the poses the arm takes it to.
// A pose is [x, y, z] in metres and a rotation vector [rx, ry, rz] in degrees, both in
// the base frame (the arm link's tool-pose convention).
using PoseSix = std::array<double, 6>;
// Its `X_Tool_Board` and `poses` (six numbers each) are read by hand.
struct BaseCalibrationConfig {
  control::BoardGeometry board;
  PoseSix X_Tool_Board{-0.24, -0.15, 0.02, 0, 0, 0};  // the board's first inner corner on the tool
  std::vector<PoseSix> poses;   // at least 6; 15 or more recommended
  double max_rms_mm = 2.0;      // refuse to write a fit above these
  double max_abs_mm = 6.0;
  Nanos move_timeout = seconds(15);  // per pose: in position within this, or the pose is skipped
  Nanos settle = millis(300);        // in position this long before the picture

  template <class V>
  void Visit(V& v) {
    v(Param{"board", Unit::kNone, 0, 0, "the checkerboard on the gripper"}, Section<control::BoardGeometry>{board});
    v(Param{"max_rms_mm", Unit::kNone, 0.01, 100.0, "the fit is refused above this RMS residual per axis, in mm"},
      max_rms_mm);
    v(Param{"max_abs_mm", Unit::kNone, 0.01, 500.0, "... or above this largest residual, in mm"}, max_abs_mm);
    v(Param{"move_timeout_s", Unit::kSecond, 0.1, 600.0, "a pose not reached within this is skipped"}, move_timeout);
    v(Param{"settle_ms", Unit::kMillisecond, 0, 60'000, "in position this long before the picture"}, settle);
  }
};

// `line`: where the marking station learns which panel comes next (docs/line.md). With
// no source, records pair with panels in the order they come (check-config warns).
enum class PanelIdSource : std::uint8_t { kNone, kModbus, kBroker };

// `line.modbus`: the line's PLC as a Modbus TCP server (the register map: docs/line.md).
struct ModbusLinkConfig {
  std::string server;  // ADDRESS:PORT (IPv4)
  int unit_id = 1;
  int plc_block = 0;
  int cell_block = 100;
  Nanos poll = millis(20);
  Nanos response_timeout = millis(200);

  template <class V>
  void Visit(V& v) {
    v(Param{"server", Unit::kNone, 1, 64, "the PLC's Modbus TCP server, ADDRESS:PORT (IPv4)", true}, server);
    v(Param{"unit_id", Unit::kNone, 0, 255, "the unit (slave) id the PLC answers to"}, unit_id);
    v(Param{"plc_block", Unit::kNone, 0, 65535 - 49, "first holding register of the PLC's block (50 registers)"}, plc_block);
    v(Param{"cell_block", Unit::kNone, 0, 65535 - 8, "first holding register of the cell's block (9 registers)"}, cell_block);
    v(Param{"poll_ms", Unit::kMillisecond, 5, 1000, "one exchange (write the cell's block, read the PLC's) this often"}, poll);
    v(Param{"response_timeout_ms", Unit::kMillisecond, 10, 5000, "a request (or the connection) unanswered this long fails"},
      response_timeout);
  }
  template <class Report>
  void validate(Report&& report) const {
    if (cell_block < plc_block + 50 && plc_block < cell_block + 9)
      report("cell_block", "the cell's block (" + std::to_string(cell_block) + "..+8) overlaps the PLC's (" +
                               std::to_string(plc_block) + "..+49)");
  }
};

// `line.broker`: the stations' MQTT broker (topics and delivery: docs/line.md). A marking
// station receives its line's records through it (kept in cell.record_folder until used)
// and publishes its state and results; an inspection station publishes records.
struct BrokerConfig {
  std::string server;         // ADDRESS:PORT (IPv4); empty: no broker
  std::string line;           // the topics' line level: markcell/<line>/...
  std::string station;        // this station's level and its MQTT client id
  std::string username;       // the station's user at the broker
  std::string password_file;  // absolute (resolved against the config's folder); its first line is the password
  std::string ca_file;        // absolute; the broker's certificate must be signed by it (TLS)
  Nanos keepalive = seconds(5);
  Nanos connect_timeout = seconds(5);
  Nanos record_retain = seconds(600);  // an inspection station's record stays retained this long

  template <class V>
  void Visit(V& v) {
    v(Param{"server", Unit::kNone, 1, 64, "the broker, ADDRESS:PORT (IPv4; its TLS certificate names ADDRESS)", true}, server);
    v(Param{"line", Unit::kNone, 1, 32, "the line's name in the topics (letters, digits, - and _)", true}, line);
    v(Param{"station", Unit::kNone, 1, 32, "this station's name in the topics and its client id (letters, digits, - and _)",
            true},
      station);
    v(Param{"username", Unit::kNone, 1, 64, "the station's user at the broker", true}, username);
    v(Param{"password_file", Unit::kNone, 1, 4096, "a file (mode 0600 or 0400) whose first line is the password", true},
      password_file);
    v(Param{"ca_file", Unit::kNone, 1, 4096, "the CA certificate (PEM) that signed the broker's certificate", true},
      ca_file);
    v(Param{"keepalive_s", Unit::kSecond, 5, 60, "the broker declares the station gone (last will) after 1.5 times this"},
      keepalive);
    v(Param{"connect_timeout_s", Unit::kSecond, 1, 60, "the broker's answer to a connect awaited this long"},
      connect_timeout);
    v(Param{"record_retain_s", Unit::kSecond, 10, 86'400,
            "inspection: a record stays retained this long (a marking station restarting within it gets it again)"},
      record_retain);
  }
};

struct LineConfig {
  PanelIdSource panel_id_source = PanelIdSource::kNone;
  ModbusLinkConfig modbus;
  BrokerConfig broker;
  Nanos silent = seconds(1);

  template <class V>
  void Visit(V& v) {
    v(Param{"panel_id_source", Unit::kNone, 0, 0,
            "none (records pair with panels in order) | modbus (the PLC says which) | broker (arrival messages)"},
      Choice<PanelIdSource, 3>{panel_id_source,
                               {{{"none", PanelIdSource::kNone},
                                 {"modbus", PanelIdSource::kModbus},
                                 {"broker", PanelIdSource::kBroker}}}});
    v(Param{"silent_ms", Unit::kMillisecond, 50, 60'000, "the panel-id source unanswered this long: safe stop"}, silent);
    v(Param{"modbus", Unit::kNone, 0, 0, "the PLC over Modbus TCP (required with panel_id_source: modbus)"},
      Section<ModbusLinkConfig>{modbus});
    v(Param{"broker", Unit::kNone, 0, 0, "the stations' MQTT broker (records, arrivals, state, results)"},
      Section<BrokerConfig>{broker});
  }
  template <class Report>
  void validate(Report&& report) const {
    if (panel_id_source == PanelIdSource::kModbus && modbus.server.empty())
      report("modbus", "missing required key 'modbus.server' (panel_id_source: modbus): the PLC's ADDRESS:PORT");
    if (panel_id_source == PanelIdSource::kModbus && silent < 3 * modbus.poll)
      report("silent_ms", "silent_ms " + std::to_string(silent / millis(1)) + " must be at least three polls (modbus.poll_ms " +
                              std::to_string(modbus.poll / millis(1)) + ")");
    if (panel_id_source == PanelIdSource::kBroker && broker.server.empty())
      report("broker", "missing required key 'broker.server' (panel_id_source: broker): the broker's ADDRESS:PORT");
  }
};

struct CellConfig {
  std::string file;     // the YAML file it came from
  std::string name;
  std::string results_file;  // every panel's result appended and synced here (empty: none); absolute
  std::string record_folder;  // inspection records arrive here (empty: none); absolute
  std::string pose_log_folder;  // poses.csv and mf_tracks.csv written here (empty: none); absolute
  std::uint64_t pose_log_rotate_mb = 64;  // each file rotated to FILE.1 past this size
  std::string operator_page;  // ADDRESS:PORT the operator page and /metrics listen on (empty: off)
  control::ExecutiveSpec executive;
  WatchdogConfig watchdog;
  SafeStopConfig safe_stop;
  SprayConfig spray;
  GpioConfig gpio;
  ArmConfig arm;
  CameraConfig cameras;
  CalibrationPaths calibration;
  std::vector<PanelTypeConfig> panel_types;
  vision::TrackerParams vision;    // the `vision:` section (its keys declared in TrackerParams::Visit)
  control::MarkingParams marking;  // the `marking:` section (MarkingParams::Visit); the cell fills in the rest
  BaseCalibrationConfig base_calibration;
  LineConfig line;  // the `line:` section: the panel-id source
};

// What the loader knows of a task. The cell's task table (cell.cpp, kCellTasks) declares
// each task once, with this and its bind function; the loader's rules, check-config's
// list (`markcell check-config --tasks`), the schema and docs/executive.md's table come
// from it.
enum class TaskKind : std::uint8_t {
  kControl,  // a short bounded step on a fast lane (1 kHz): devices, PLC, the marking sequence
  kHeavy,    // per-frame work (the vision task): on a lane with no control task
};
enum class TaskPresence : std::uint8_t {
  kOptional,
  kRequired,                // in every table
  kWithSimulatedDevices,    // in the table exactly when a device is simulated
};
struct TaskDecl {
  std::string_view name;
  TaskKind kind = TaskKind::kControl;
  TaskPresence presence = TaskPresence::kOptional;
  std::string_view doc;  // what it does, as a verb phrase ("opens and closes the valve"): a required task's reason
  // Tasks that must be in the table with this one, each with the reason.
  struct Need {
    std::string_view task, why;
  };
  std::array<Need, 2> needs{};
};
using TaskTable = std::span<const TaskDecl>;
std::string_view to_string(TaskKind k);
// The table as docs/executive.md shows it: one Markdown row per task.
std::string task_table_markdown(TaskTable tasks);

// The configuration's top-level sections, in the example's order.
struct ConfigSection {
  std::string_view key;
  bool required;
  std::string_view doc;
};
inline constexpr std::array<ConfigSection, 12> kConfigSections{{
    {"cell", true, "the cell's name, its results file and its inspection-record folder"},
    {"executive", true, "the base tick, the lanes (threads) and the task table"},
    {"watchdog", true, "systemd's watchdog and the hardware watchdog device"},
    {"safe_stop", true, "what a safe stop does to the arm and the PLC, and how the cell re-arms"},
    {"spray", true, "the spray valve's pulse"},
    {"devices", true, "the GPIO lines, the arm and its link, the cameras"},
    {"calibration", true, "the stereo and base calibration files"},
    {"panel_types", true, "each panel type's macro-features file"},
    {"vision", false, "the panel tracker (all keys optional)"},
    {"marking", false, "the marking sequence (all keys optional)"},
    {"base_calibration", false, "markcell calibrate-base: the board and the poses"},
    {"line", false, "where the cell learns which panel comes next: the PLC over Modbus TCP, or none (in order)"},
}};

// A JSON Schema (draft-07) of the configuration, generated from the same declarations
// the loader reads (the Visit() of each parameter struct): for editors that complete and
// check cell.yaml. The sections still read by hand are described as objects; the loader
// (markcell check-config) remains the full check. `known_tasks` names the task table's
// allowed keys.
std::string config_schema_json(TaskTable known_tasks);

// Validates and loads; throws ConfigInvalid with every error found. `known_tasks`: the
// tasks this build of markcell provides (a configured task must be one of them, and their
// declarations' rules hold).
CellConfig load_config(const std::string& path, TaskTable known_tasks);
// The same from text already in memory; `path` names it in messages and is where
// relative calibration paths are resolved from.
CellConfig load_config_text(const std::string& text, const std::string& path, TaskTable known_tasks);
// `systemctl reload markcell` (SIGHUP): the running configuration's panel types with the
// recipes its file gives them now, over the running `spray` and `marking` sections.
// Throws ConfigInvalid with every error (FILE:LINE:COL) when the file is not a valid
// configuration now, or when its panel types (names, order, files, macro_features)
// differ from the running ones: those, and every other section, take a restart.
std::vector<PanelTypeConfig> reload_recipes(const CellConfig& running, TaskTable known_tasks);
std::vector<ConfigError> check_config_text(const std::string& text, const std::string& path,
                                           TaskTable known_tasks);
// Same checks, returning the errors instead of throwing (empty: valid).
std::vector<ConfigError> check_config(const std::string& path, TaskTable known_tasks);

}  // namespace markcell::host
