#include "markcell/host/config.hpp"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <concepts>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <sstream>

#include <sys/stat.h>

#include "markcell/common/bounded_file.hpp"
#include "markcell/common/param.hpp"
#include "markcell/host/inspection_station.hpp"
#include "markcell/host/operator_page.hpp"

#include "markcell/vision/calibration_io.hpp"
#include "markcell/vision/panel_tracker.hpp"

namespace markcell::host {

std::string ConfigError::to_string() const {
  std::ostringstream os;
  os << file;
  if (line > 0) os << ":" << line << ":" << column;
  os << ": " << (path.empty() ? "(document)" : path) << ": " << message;
  return os.str();
}

namespace {
std::string join_errors(const std::vector<ConfigError>& errors) {
  std::string s = std::to_string(errors.size()) + " configuration error(s):";
  for (const auto& e : errors) s += "\n  " + e.to_string();
  return s;
}
}  // namespace

ConfigInvalid::ConfigInvalid(std::vector<ConfigError> errors)
    : std::runtime_error(join_errors(errors)), errors_(std::move(errors)) {}

std::string_view to_string(ArmTransport t) {
  return t == ArmTransport::kCan ? "can" : t == ArmTransport::kSerial ? "serial" : "simulated";
}
std::string_view to_string(CameraSource s) {
  return s == CameraSource::kAravis ? "aravis" : s == CameraSource::kRecording ? "recording" : "simulated";
}
std::string_view to_string(CameraTrigger t) { return t == CameraTrigger::kHardware ? "hardware" : "software"; }
std::string_view to_string(TaskKind k) { return k == TaskKind::kHeavy ? "heavy" : "control"; }
std::string_view to_string(ArmSafeAction a) { return a == ArmSafeAction::kHome ? "home" : "hold"; }

namespace {

namespace fs = std::filesystem;

std::string octal_mode(mode_t mode) {  // 0644
  std::string m = "0000";
  for (int i = 3; i >= 0; --i, mode >>= 3) m[static_cast<std::size_t>(i)] = static_cast<char>('0' + (mode & 7));
  return m;
}

std::string node_kind(const YAML::Node& n) {
  switch (n.Type()) {
    case YAML::NodeType::Map: return "a map";
    case YAML::NodeType::Sequence: return "a sequence";
    case YAML::NodeType::Null: return "nothing (null)";
    case YAML::NodeType::Scalar: return "\"" + n.Scalar() + "\"";
    default: return "nothing";
  }
}

std::string join(const std::vector<std::string>& items) {
  std::string s;
  for (const auto& i : items) s += (s.empty() ? "" : ", ") + i;
  return s;
}

const TaskDecl* find_task(TaskTable table, std::string_view name) {
  for (const auto& d : table)
    if (d.name == name) return &d;
  return nullptr;
}

// Walks the document, collecting every error with its position. Each `map()` call
// declares the keys a map may have; anything else is reported as unknown.
class Reader {
 public:
  Reader(std::string file, std::vector<ConfigError>& errors) : file_(std::move(file)), errors_(errors) {}

  void error(const YAML::Node& at, const std::string& path, const std::string& message) {
    ConfigError e;
    e.file = file_;
    const YAML::Mark mark = at.IsDefined() ? at.Mark() : YAML::Mark::null_mark();
    if (mark.line >= 0) {
      e.line = mark.line + 1;
      e.column = mark.column + 1;
    }
    e.path = path;
    e.message = message;
    errors_.push_back(std::move(e));
  }
  void error_at(const YAML::Mark& mark, const std::string& path, const std::string& message) {
    errors_.push_back(ConfigError{file_, mark.line + 1, mark.column + 1, path, message});
  }

  // A map with exactly these keys allowed. Returns false (after reporting) when the node
  // is not a map.
  bool map(const YAML::Node& node, const std::string& path, const std::vector<std::string>& allowed) {
    if (!node.IsMap()) {
      error(node, path, "expected a map, got " + node_kind(node));
      return false;
    }
    std::vector<std::string> seen;
    for (const auto& kv : node) {
      const std::string key = kv.first.Scalar();
      const std::string key_path = path.empty() ? key : path + "." + key;
      if (std::find(seen.begin(), seen.end(), key) != seen.end()) {
        error_at(kv.first.Mark(), key_path, "duplicate key '" + key + "'");
      }
      seen.push_back(key);
      if (std::find(allowed.begin(), allowed.end(), key) == allowed.end())
        error_at(kv.first.Mark(), key_path, "unknown key '" + key + "' (expected one of: " + join(allowed) + ")");
    }
    return true;
  }

  // A map whose keys are names the caller checks (lanes, tasks, panel types).
  bool named_map(const YAML::Node& node, const std::string& path) {
    if (!node.IsMap()) {
      error(node, path, "expected a map of names, got " + node_kind(node));
      return false;
    }
    if (node.size() == 0) {
      error(node, path, "expected at least one entry");
      return false;
    }
    return true;
  }

  // Returns the child or, when required and missing, reports it (at the parent).
  // A key given twice in one map: yaml-cpp keeps one of them silently (a task declared
  // twice, a panel type twice). Each repeat is an error at its own position. Bounded:
  // the text's nesting was checked before parsing.
  void duplicate_keys(const YAML::Node& node, const std::string& path, int depth = 0) {
    if (depth > kMaxYamlNesting) return;
    if (node.IsMap()) {
      std::vector<std::string> seen;
      for (const auto& kv : node) {
        const std::string key = kv.first.IsScalar() ? kv.first.Scalar() : std::string();
        if (!key.empty() && std::find(seen.begin(), seen.end(), key) != seen.end())
          error(kv.first, join_path(path, key), "declared twice in this map (yaml would keep only one)");
        seen.push_back(key);
        duplicate_keys(kv.second, join_path(path, key), depth + 1);
      }
    } else if (node.IsSequence()) {
      for (std::size_t i = 0; i < node.size(); ++i) duplicate_keys(node[i], path + "[" + std::to_string(i) + "]", depth + 1);
    }
  }

  std::optional<YAML::Node> child(const YAML::Node& parent, const std::string& path, const std::string& key,
                                  bool required) {
    if (!parent.IsMap()) return std::nullopt;
    const YAML::Node n = parent[key];
    if (!n.IsDefined()) {
      if (required) error(parent, join_path(path, key), "missing required key '" + key + "'");
      return std::nullopt;
    }
    return n;
  }

  static std::string join_path(const std::string& path, const std::string& key) {
    return path.empty() ? key : path + "." + key;
  }

  template <typename T>
  void integer(const YAML::Node& parent, const std::string& path, const std::string& key, T& out, long long lo,
               long long hi, bool required = true) {
    const auto n = child(parent, path, key, required);
    if (!n) return;
    const std::string p = join_path(path, key);
    long long v = 0;
    const std::string range = "[" + std::to_string(lo) + ", " + std::to_string(hi) + "]";
    if (!n->IsScalar() || !YAML::convert<long long>::decode(*n, v)) {
      error(*n, p, "expected an integer in " + range + ", got " + node_kind(*n));
      return;
    }
    if (v < lo || v > hi) {
      error(*n, p, "expected an integer in " + range + ", got " + std::to_string(v));
      return;
    }
    out = static_cast<T>(v);
  }

  void number(const YAML::Node& parent, const std::string& path, const std::string& key, double& out, double lo,
              double hi, bool required = true) {
    const auto n = child(parent, path, key, required);
    if (!n) return;
    const std::string p = join_path(path, key);
    double v = 0;
    std::ostringstream range;
    range << "[" << lo << ", " << hi << "]";
    if (!n->IsScalar() || !YAML::convert<double>::decode(*n, v) || !std::isfinite(v)) {
      error(*n, p, "expected a number in " + range.str() + ", got " + node_kind(*n));
      return;
    }
    if (v < lo || v > hi) {
      std::ostringstream os;
      os << "expected a number in " << range.str() << ", got " << v;
      error(*n, p, os.str());
      return;
    }
    out = v;
  }

  void boolean(const YAML::Node& parent, const std::string& path, const std::string& key, bool& out,
               bool required = true) {
    const auto n = child(parent, path, key, required);
    if (!n) return;
    bool v = false;
    if (!n->IsScalar() || !YAML::convert<bool>::decode(*n, v)) {
      error(*n, join_path(path, key), "expected true or false, got " + node_kind(*n));
      return;
    }
    out = v;
  }

  void text(const YAML::Node& parent, const std::string& path, const std::string& key, std::string& out,
            bool required = true, std::size_t max_length = 255) {
    const auto n = child(parent, path, key, required);
    if (!n) return;
    const std::string p = join_path(path, key);
    if (!n->IsScalar() || n->Scalar().empty()) {
      error(*n, p, "expected a non-empty string, got " + node_kind(*n));
      return;
    }
    if (n->Scalar().size() > max_length) {
      error(*n, p, "expected at most " + std::to_string(max_length) + " characters, got " +
                       std::to_string(n->Scalar().size()));
      return;
    }
    out = n->Scalar();
  }

  template <typename E>
  void choice(const YAML::Node& parent, const std::string& path, const std::string& key, E& out,
              const std::vector<std::pair<std::string, E>>& options, bool required = true) {
    const auto n = child(parent, path, key, required);
    if (!n) return;
    std::vector<std::string> names;
    for (const auto& o : options) names.push_back(o.first);
    if (n->IsScalar()) {
      for (const auto& o : options)
        if (o.first == n->Scalar()) {
          out = o.second;
          return;
        }
    }
    error(*n, join_path(path, key), "expected one of: " + join(names) + ", got " + node_kind(*n));
  }

  void vec3(const YAML::Node& parent, const std::string& path, const std::string& key, std::array<double, 3>& out,
            double lo, double hi, bool required = true) {
    const auto n = child(parent, path, key, required);
    if (!n) return;
    const std::string p = join_path(path, key);
    std::ostringstream expected;
    expected << "expected a sequence of 3 numbers in [" << lo << ", " << hi << "]";
    if (!n->IsSequence() || n->size() != 3) {
      error(*n, p, expected.str() + ", got " + node_kind(*n));
      return;
    }
    std::array<double, 3> v{};
    for (std::size_t i = 0; i < 3; ++i) {
      const YAML::Node e = (*n)[i];
      if (!e.IsScalar() || !YAML::convert<double>::decode(e, v[i]) || !std::isfinite(v[i]) || v[i] < lo || v[i] > hi) {
        error(e, p + "[" + std::to_string(i) + "]", expected.str() + ", got " + node_kind(e));
        return;
      }
    }
    out = v;
  }

  // A path relative to the configuration's folder that must name an existing file (or,
  // with `folder`, an existing folder).
  void existing_file(const YAML::Node& parent, const std::string& path, const std::string& key, std::string& out,
                     bool folder = false) {
    std::string raw;
    text(parent, path, key, raw, true, 4096);
    if (raw.empty()) return;
    fs::path p(raw);
    if (p.is_relative()) p = fs::path(file_).parent_path() / p;
    p = p.lexically_normal();
    std::error_code ec;
    if (folder ? !fs::is_directory(p, ec) : !fs::is_regular_file(p, ec)) {
      error((*child(parent, path, key, true)), join_path(path, key),
            std::string(folder ? "folder '" : "file '") + raw + "' not found (looked for " + p.string() + ")");
      return;
    }
    out = p.string();
  }

  std::size_t error_count() const { return errors_.size(); }
  // Whether the key at `path` was reported since the error count was `since`.
  bool failed_since(std::size_t since, const std::string& path) const {
    for (std::size_t i = since; i < errors_.size(); ++i)
      if (errors_[i].path == path) return true;
    return false;
  }

 private:
  std::string file_;
  std::vector<ConfigError>& errors_;
};

template <class Params>
void read_params(Reader& r, const YAML::Node& node, const std::string& path, Params& params,
                 const std::vector<std::string>& extra_keys = {});

// Reads the parameters a struct declares in its Visit() from one section of the YAML,
// through the Reader (so every error keeps its FILE:LINE:COL: key.path: form). A key
// left out keeps the field's declared default untouched; a key given is converted once
// from the unit the configuration writes it in to the field's SI.
class YamlParams {
 public:
  YamlParams(Reader& r, const YAML::Node& node, std::string path) : r_(r), node_(node), path_(std::move(path)) {}

  void operator()(const Param& p, double& field) {
    if (!given(p)) return;
    double v = 0;
    r_.number(node_, path_, std::string(p.key), v, p.lo, p.hi, false);
    if (read_ok()) field = to_si(v, p.unit);
  }
  // Integers of any width (counts, node ids, baud rates): the range is the Param's.
  template <std::integral T>
    requires(!std::same_as<T, bool> && !std::same_as<T, Nanos>)
  void operator()(const Param& p, T& field) {
    if (!given(p)) return;
    long long v = 0;
    r_.integer(node_, path_, std::string(p.key), v, static_cast<long long>(p.lo), static_cast<long long>(p.hi), false);
    if (!read_ok()) return;
    if (p.unit == Unit::kOddWindowPx) {
      if (v % 2 == 0) {
        r_.error(node_[std::string(p.key)], key_path(p), "must be odd (a window centred on the point)");
        return;
      }
      field = static_cast<T>(v / 2);
    } else {
      field = static_cast<T>(v);
    }
  }
  void operator()(const Param& p, Nanos& field) {
    if (!given(p)) return;
    if (integer_duration(p.unit)) {
      long long v = 0;
      r_.integer(node_, path_, std::string(p.key), v, static_cast<long long>(p.lo), static_cast<long long>(p.hi), false);
      if (read_ok()) field = v * static_cast<Nanos>(nanos_per(p.unit));
    } else {
      double v = 0;
      r_.number(node_, path_, std::string(p.key), v, p.lo, p.hi, false);
      if (read_ok()) field = to_nanos(v, p.unit);
    }
  }
  // Text: `lo` and `hi` bound its length.
  void operator()(const Param& p, std::string& field) {
    if (given(p)) r_.text(node_, path_, std::string(p.key), field, false, static_cast<std::size_t>(p.hi));
  }
  // A nested map, read by its own declarations.
  template <typename T>
  void operator()(const Param& p, Section<T> section) {
    if (given(p)) read_params(r_, node_[std::string(p.key)], key_path(p), section.value);
  }
  void operator()(const Param& p, bool& field) {
    if (given(p)) r_.boolean(node_, path_, std::string(p.key), field, false);
  }
  void operator()(const Param& p, Eigen::Vector3d& field) {
    if (!given(p)) return;
    std::array<double, 3> v{field.x(), field.y(), field.z()};
    r_.vec3(node_, path_, std::string(p.key), v, p.lo, p.hi, false);
    if (read_ok()) field = Eigen::Vector3d(v[0], v[1], v[2]);
  }
  void operator()(const Param& p, std::array<double, 3>& field) {
    if (!given(p)) return;
    std::array<double, 3> v = field;
    r_.vec3(node_, path_, std::string(p.key), v, p.lo, p.hi, false);
    if (read_ok())
      for (std::size_t i = 0; i < 3; ++i) field[i] = to_si(v[i], p.unit);
  }
  template <typename E, std::size_t N>
  void operator()(const Param& p, Choice<E, N> c) {
    if (!given(p)) return;
    std::vector<std::pair<std::string, E>> options;
    for (const auto& o : c.options) options.emplace_back(std::string(o.name), o.value);
    r_.choice(node_, path_, std::string(p.key), c.value, options, false);
  }

 private:
  // Whether the key is there; read_ok() then says whether reading it added no error.
  // A required key left out is reported here (at its section).
  bool given(const Param& p) {
    errors_before_ = r_.error_count();
    return r_.child(node_, path_, std::string(p.key), p.required).has_value();
  }
  bool read_ok() const { return r_.error_count() == errors_before_; }
  std::string key_path(const Param& p) const { return path_ + "." + std::string(p.key); }

  Reader& r_;
  const YAML::Node& node_;
  std::string path_;
  std::size_t errors_before_ = 0;
};

// The keys a struct's Visit() declares, in its order: what its section may hold.
struct ParamKeys {
  std::vector<std::string> keys;
  template <typename T>
  void operator()(const Param& p, T&&) {
    keys.emplace_back(p.key);
  }
};

// One section whose parameters a struct declares (TrackerParams, MarkingParams, ...): its
// keys, each read and converted, then the struct's own cross-field checks, each at the
// key it names (at the section when that key is not written). `extra_keys`: what the
// caller reads by hand in the same map (lists, maps of names, files).
template <class Params>
void read_params(Reader& r, const YAML::Node& node, const std::string& path, Params& params,
                 const std::vector<std::string>& extra_keys) {
  ParamKeys declared;
  params.Visit(declared);
  declared.keys.insert(declared.keys.end(), extra_keys.begin(), extra_keys.end());
  if (!r.map(node, path, declared.keys)) return;
  YamlParams reader(r, node, path);
  params.Visit(reader);
  if constexpr (requires { params.validate([](std::string_view, std::string_view) {}); }) {
    params.validate([&](std::string_view key, std::string_view message) {
      const YAML::Node at = node[std::string(key)];
      r.error(at.IsDefined() ? at : node, path + "." + std::string(key), std::string(message));
    });
  }
}

void read_executive(Reader& r, const YAML::Node& node, TaskTable known_tasks, CellConfig& cfg,
                    std::vector<YAML::Mark>& task_marks) {
  const std::string P = "executive";
  auto& spec = cfg.executive;
  const std::size_t errors_before = r.error_count();
  read_params(r, node, P, spec, {"lanes", "tasks"});
  if (!node.IsMap()) return;
  // The checks below build on the tick and the stall limit: not on a value refused.
  const long long tick_us = r.failed_since(errors_before, P + ".base_tick_us") ? 0 : spec.tick / kNanosPerMicro;
  const long long stall_ms = r.failed_since(errors_before, P + ".lane_stall_ms") ? 0 : spec.lane_stall_limit / millis(1);

  std::vector<std::string> lane_names;
  if (const auto lanes = r.child(node, P, "lanes", true); lanes && r.named_map(*lanes, P + ".lanes")) {
    if (lanes->size() > static_cast<std::size_t>(control::kMaxTaskLanes))
      r.error(*lanes, P + ".lanes",
              "at most " + std::to_string(control::kMaxTaskLanes) + " lanes, got " + std::to_string(lanes->size()));
    for (const auto& kv : *lanes) {
      const std::string name = kv.first.Scalar();
      const std::string LP = P + ".lanes." + name;
      control::LaneSpec lane;
      lane.name = name;
      read_params(r, kv.second, LP, lane);
      lane_names.push_back(name);
      spec.lanes.push_back(lane);
    }
  }

  if (const auto tasks = r.child(node, P, "tasks", true); tasks && r.named_map(*tasks, P + ".tasks")) {
    if (tasks->size() > static_cast<std::size_t>(control::kMaxTasks))
      r.error(*tasks, P + ".tasks",
              "at most " + std::to_string(control::kMaxTasks) + " tasks, got " + std::to_string(tasks->size()));
    for (const auto& kv : *tasks) {
      const std::string name = kv.first.Scalar();
      const std::string TP = P + ".tasks." + name;
      if (!find_task(known_tasks, name)) {
        std::vector<std::string> names;
        for (const auto& d : known_tasks) names.emplace_back(d.name);
        r.error_at(kv.first.Mark(), TP, "unknown task '" + name + "' (markcell provides: " + join(names) + ")");
      }
      const YAML::Node& t = kv.second;
      if (!r.map(t, TP, {"lane", "period_us", "phase_us", "budget_us", "on_overrun"})) continue;
      control::TaskSpec task;
      task.name = name;
      std::string lane;
      r.text(t, TP, "lane", lane);
      if (!lane.empty()) {
        const auto it = std::find(lane_names.begin(), lane_names.end(), lane);
        if (it == lane_names.end())
          r.error(t["lane"], TP + ".lane",
                  "lane '" + lane + "' is not declared in executive.lanes (declared: " + join(lane_names) + ")");
        else
          task.lane = static_cast<int>(it - lane_names.begin());
      }
      long long period_us = 0, phase_us = 0, budget_us = 0;
      r.integer(t, TP, "period_us", period_us, 1, 3'600'000'000LL);
      r.integer(t, TP, "phase_us", phase_us, 0, 3'600'000'000LL, false);
      r.integer(t, TP, "budget_us", budget_us, 1, 3'600'000'000LL);
      r.choice(t, TP, "on_overrun", task.overrun,
               {{"log", control::OverrunPolicy::kLog},
                {"degrade", control::OverrunPolicy::kDegrade},
                {"safe_stop", control::OverrunPolicy::kSafeStop}},
               false);
      if (tick_us > 0 && period_us > 0) {
        if (period_us % tick_us != 0)
          r.error(t["period_us"], TP + ".period_us",
                  "period_us " + std::to_string(period_us) + " is not a multiple of executive.base_tick_us " +
                      std::to_string(tick_us));
        else
          task.period_ticks = static_cast<std::uint32_t>(period_us / tick_us);
        if (phase_us % tick_us != 0)
          r.error(t["phase_us"], TP + ".phase_us",
                  "phase_us " + std::to_string(phase_us) + " is not a multiple of executive.base_tick_us " +
                      std::to_string(tick_us));
        else if (phase_us >= period_us)
          r.error(t["phase_us"], TP + ".phase_us",
                  "phase_us " + std::to_string(phase_us) + " must be less than period_us " + std::to_string(period_us));
        else
          task.phase_ticks = static_cast<std::uint32_t>(phase_us / tick_us);
      }
      if (budget_us > 0 && period_us > 0 && budget_us > period_us)
        r.error(t["budget_us"], TP + ".budget_us",
                "budget_us " + std::to_string(budget_us) + " is longer than period_us " + std::to_string(period_us));
      task.budget = micros(budget_us);
      spec.tasks.push_back(task);
      task_marks.push_back(kv.first.Mark());
    }
    // Every lane must run something, and the stall limit must allow for its slowest gap.
    for (std::size_t l = 0; l < spec.lanes.size(); ++l) {
      long long gap_us = 0;
      bool has_task = false;
      for (const auto& task : spec.tasks)
        if (task.lane == static_cast<int>(l)) {
          has_task = true;
          const long long p = static_cast<long long>(task.period_ticks) * tick_us;
          if (gap_us == 0 || p < gap_us) gap_us = p;
        }
      const std::string LP = P + ".lanes." + spec.lanes[l].name;
      if (!has_task)
        r.error(node["lanes"][spec.lanes[l].name], LP, "lane '" + spec.lanes[l].name + "' runs no task");
      else if (gap_us > 0 && stall_ms > 0 && stall_ms * 1000 <= 2 * gap_us)
        r.error(node["lane_stall_ms"], P + ".lane_stall_ms",
                "lane_stall_ms " + std::to_string(stall_ms) + " must exceed twice the period of lane '" +
                    spec.lanes[l].name + "' (" + std::to_string(gap_us) + " us)");
    }
  }
}

void read_gpio(Reader& r, const YAML::Node& node, GpioConfig& g) {
  const std::string P = "devices.gpio";
  read_params(r, node, P, g, {"lines"});
  std::vector<std::string> roles;
  for (std::size_t i = 0; i < kLineRoleCount; ++i) roles.emplace_back(to_string(static_cast<LineRole>(i)));
  const auto lines = r.child(node, P, "lines", true);
  if (!lines || !r.map(*lines, P + ".lines", roles)) return;
  for (std::size_t i = 0; i < kLineRoleCount; ++i) {
    const std::string LP = P + ".lines." + roles[i];
    const auto l = r.child(*lines, P + ".lines", roles[i], true);
    if (!l) continue;
    read_params(r, *l, LP, g.lines[i]);
    for (std::size_t j = 0; j < i; ++j)
      if (!g.lines[i].line.empty() && g.lines[j].line == g.lines[i].line)
        r.error((*l)["line"], LP + ".line",
                "line '" + g.lines[i].line + "' is already used by " + roles[j] + " (each role needs its own line)");
  }
}

void read_arm(Reader& r, const YAML::Node& node, ArmConfig& a) {
  const std::string P = "devices.arm";
  if (!r.map(node, P, {"transport", "can", "serial", "limits"})) return;
  if (const auto l = r.child(node, P, "limits", true)) read_params(r, *l, P + ".limits", a.limits);
  r.choice(node, P, "transport", a.transport,
           {{"simulated", ArmTransport::kSimulated}, {"can", ArmTransport::kCan}, {"serial", ArmTransport::kSerial}});
  // The link the transport names must be written; the other may stay (and is checked).
  if (const auto c = r.child(node, P, "can", a.transport == ArmTransport::kCan)) read_params(r, *c, P + ".can", a.can);
  if (const auto s = r.child(node, P, "serial", a.transport == ArmTransport::kSerial))
    read_params(r, *s, P + ".serial", a.serial);
}

void read_cameras(Reader& r, const YAML::Node& node, CameraConfig& c) {
  const std::string P = "devices.cameras";
  read_params(r, node, P, c, {"recording"});
  if (!node.IsMap()) return;
  if (c.source == CameraSource::kRecording) {
    r.existing_file(node, P, "recording", c.recording, true);
  } else if (node["recording"].IsDefined()) {
    r.error(node["recording"], P + ".recording", "only used with source: recording");
  }
}

void read_calibration(Reader& r, const YAML::Node& node, CellConfig& cfg) {
  const std::string P = "calibration";
  if (!r.map(node, P, {"stereo", "base"})) return;
  r.existing_file(node, P, "stereo", cfg.calibration.stereo);
  r.existing_file(node, P, "base", cfg.calibration.base);
  // The files themselves: parsed now so that a bad matrix stops the start, with its key.
  if (!cfg.calibration.stereo.empty()) {
    try {
      const auto stereo = vision::load_stereo_calibration(cfg.calibration.stereo);
      if (stereo.left.width != cfg.cameras.width || stereo.left.height != cfg.cameras.height)
        r.error(node["stereo"], P + ".stereo",
                "calibrated for " + std::to_string(stereo.left.width) + "x" + std::to_string(stereo.left.height) +
                    " images, devices.cameras is " + std::to_string(cfg.cameras.width) + "x" +
                    std::to_string(cfg.cameras.height));
    } catch (const vision::CalibrationError& e) {
      r.error(node["stereo"], P + ".stereo", e.what());
    }
  }
  if (!cfg.calibration.base.empty()) {
    try {
      vision::load_pose(cfg.calibration.base, "X_Base_CamR");
    } catch (const vision::CalibrationError& e) {
      r.error(node["base"], P + ".base", e.what());
    }
  }
}

void read_panel_types(Reader& r, const YAML::Node& node, CellConfig& cfg) {
  const std::string P = "panel_types";
  if (!r.named_map(node, P)) return;
  if (node.size() > static_cast<std::size_t>(control::kMaxPanelTypes)) {
    r.error(node, P, std::to_string(node.size()) + " panel types, at most " + std::to_string(control::kMaxPanelTypes));
    return;
  }
  for (const auto& kv : node) {
    const std::string name = kv.first.Scalar();
    const std::string TP = P + "." + name;
    PanelTypeConfig panel;
    panel.name = name;
    read_params(r, kv.second, TP, panel, {"file", "recipe"});
    if (kv.second.IsMap()) {
      if (kv.second["file"].IsDefined()) {
        r.existing_file(kv.second, TP, "file", panel.file);
        if (!panel.file.empty()) {
          try {
            const auto model = vision::load_panel_type(panel.file);
            if (model.count() != panel.macro_features)
              r.error(kv.second["file"], TP + ".file",
                      "has " + std::to_string(model.count()) + " macro-features, macro_features says " +
                          std::to_string(panel.macro_features));
            if (model.name != name)
              r.error(kv.second["file"], TP + ".file", "is the panel type '" + model.name + "', not '" + name + "'");
          } catch (const std::exception& e) {
            r.error(kv.second["file"], TP + ".file", e.what());
          }
        }
      }
    }
    cfg.panel_types.push_back(panel);
  }
}

// Each panel type's process settings: the `spray:` and `marking:` sections' (read
// before), with its `recipe` over them. Its pulse within the valve's limits.
void read_recipes(Reader& r, const YAML::Node& types, CellConfig& cfg) {
  for (PanelTypeConfig& panel : cfg.panel_types) {
    RecipeParams recipe{cfg.spray, cfg.marking};
    const YAML::Node type = types.IsDefined() && types.IsMap() ? types[panel.name] : YAML::Node();
    if (type.IsDefined() && type.IsMap() && type["recipe"].IsDefined()) {
      const std::string RP = "panel_types." + panel.name + ".recipe";
      const std::size_t errors_before = r.error_count();
      read_params(r, type["recipe"], RP, recipe);
      panel.has_recipe = true;
      if (r.error_count() == errors_before &&
          (recipe.spray.pulse < cfg.spray.min_pulse || recipe.spray.pulse > cfg.spray.max_pulse)) {
        char message[160];
        std::snprintf(message, sizeof message, "%g ms is outside the valve's limits, spray.min_pulse_ms %g to spray.max_pulse_ms %g",
                      static_cast<double>(recipe.spray.pulse) / 1e6, static_cast<double>(cfg.spray.min_pulse) / 1e6,
                      static_cast<double>(cfg.spray.max_pulse) / 1e6);
        r.error(type["recipe"]["pulse_ms"], RP + ".pulse_ms", message);
      }
    }
    panel.marking = recipe.marking;
    panel.pulse = recipe.spray.pulse;
  }
}

void read_base_calibration(Reader& r, const YAML::Node& node, BaseCalibrationConfig& b) {
  const std::string P = "base_calibration";
  read_params(r, node, P, b, {"X_Tool_Board", "poses"});
  if (!node.IsMap()) return;
  // Six numbers: a position in metres and a rotation vector in degrees.
  const auto six = [&](const YAML::Node& n, const std::string& path, PoseSix& out) {
    const char* expected = "expected [x, y, z, rx, ry, rz]: metres within 10, a rotation vector in degrees within 360";
    if (!n.IsSequence() || n.size() != 6) {
      r.error(n, path, std::string(expected) + ", got " + node_kind(n));
      return false;
    }
    PoseSix v{};
    for (std::size_t i = 0; i < 6; ++i) {
      const YAML::Node e = n[i];
      const double lim = i < 3 ? 10.0 : 360.0;
      if (!e.IsScalar() || !YAML::convert<double>::decode(e, v[i]) || !std::isfinite(v[i]) || std::abs(v[i]) > lim) {
        r.error(e, path + "[" + std::to_string(i) + "]", std::string(expected) + ", got " + node_kind(e));
        return false;
      }
    }
    out = v;
    return true;
  };
  if (const auto m = r.child(node, P, "X_Tool_Board", false)) six(*m, P + ".X_Tool_Board", b.X_Tool_Board);
  if (const auto poses = r.child(node, P, "poses", false)) {
    if (!poses->IsSequence() || poses->size() < 6 || poses->size() > 200) {
      r.error(*poses, P + ".poses", "expected a list of 6 to 200 poses, got " + node_kind(*poses) +
                                        (poses->IsSequence() ? " of " + std::to_string(poses->size()) : std::string()));
    } else {
      b.poses.clear();
      for (std::size_t i = 0; i < poses->size(); ++i) {
        PoseSix p{};
        if (six((*poses)[i], P + ".poses[" + std::to_string(i) + "]", p)) b.poses.push_back(p);
      }
    }
  }
}

}  // namespace


namespace {

std::string read_config_text(const std::string& path) {
  try {
    return read_bounded_file(path, kMaxConfigBytes, "a cell configuration");
  } catch (const FileRefused& e) {
    // The message starts with the path; the error names it once.
    std::string what = e.what();
    if (what.rfind(path + ": ", 0) == 0) what.erase(0, path.size() + 2);
    throw ConfigInvalid({ConfigError{path, 0, 0, "", what}});
  }
}

}  // namespace

CellConfig load_config(const std::string& path, TaskTable known_tasks) {
  return load_config_text(read_config_text(path), path, known_tasks);
}

std::vector<ConfigError> check_config(const std::string& path, TaskTable known_tasks) {
  try {
    return check_config_text(read_config_text(path), path, known_tasks);
  } catch (const ConfigInvalid& e) {
    return e.errors();
  }
}

std::vector<PanelTypeConfig> reload_recipes(const CellConfig& running, TaskTable known_tasks) {
  // The file as it is now, read once: valid as a whole, or nothing changes.
  const std::string text = read_config_text(running.file);
  const CellConfig fresh = load_config_text(text, running.file, known_tasks);
  bool same = fresh.panel_types.size() == running.panel_types.size();
  for (std::size_t i = 0; same && i < fresh.panel_types.size(); ++i) {
    const PanelTypeConfig &a = fresh.panel_types[i], &b = running.panel_types[i];
    same = a.name == b.name && a.file == b.file && a.macro_features == b.macro_features;
  }
  if (!same)
    throw ConfigInvalid({ConfigError{running.file, 0, 0, "panel_types",
                                     "the panel types changed (their names, order, files or macro_features): "
                                     "that takes a restart (systemctl restart markcell)"}});
  // Its recipes over the running spray and marking sections: those sections' own keys,
  // like every other section, change with a restart only.
  std::vector<ConfigError> errors;
  Reader r(running.file, errors);
  CellConfig out = running;
  read_recipes(r, static_cast<const YAML::Node&>(YAML::Load(text))["panel_types"], out);
  if (!errors.empty()) throw ConfigInvalid(std::move(errors));
  return out.panel_types;
}

std::vector<ConfigError> check_config_text(const std::string& text, const std::string& path,
                                           TaskTable known_tasks) {
  std::vector<ConfigError> errors;
  try {
    if (is_inspection_station_config(text)) load_inspection_station_config_text(text, path);
    else load_config_text(text, path, known_tasks);
  } catch (const ConfigInvalid& e) {
    errors = e.errors();
  }
  return errors;
}

namespace {
// The document, bounded and parsed: one YAML map's worth of text, no deeper than the
// loader walks, one document. `what` names the kind of configuration in messages.
YAML::Node parse_config_root(const std::string& text, const std::string& path, const std::string& what,
                             const std::string& the_what) {
  YAML::Node root;
  if (text.size() > kMaxConfigBytes)
    throw ConfigInvalid({ConfigError{path, 1, 1, "", std::to_string(text.size()) + " bytes, more than the " +
                                                       std::to_string(kMaxConfigBytes) + " allowed for " + what}});
  if (const int line = nesting_beyond(text, kMaxYamlNesting); line > 0)
    throw ConfigInvalid({ConfigError{path, line, 1, "", "nested more than " + std::to_string(kMaxYamlNesting) + " levels deep"}});
  try {
    if (const int line = second_document_line(text); line > 0)
      throw ConfigInvalid({ConfigError{path, line, 1, "", "a second YAML document: " + what + " is one document"}});
    root = YAML::Load(text);
    if (!root.IsDefined() || root.IsNull())
      throw ConfigInvalid({ConfigError{path, 1, 1, "", "the file is empty: expected " + the_what + " (a map)"}});
  } catch (const YAML::ParserException& e) {
    throw ConfigInvalid({ConfigError{path, e.mark.line + 1, e.mark.column + 1, "", "YAML syntax: " + e.msg}});
  } catch (const YAML::Exception& e) {
    throw ConfigInvalid({ConfigError{path, e.mark.line + 1, e.mark.column + 1, "", "YAML: " + e.msg}});
  }
  return root;
}
}  // namespace

CellConfig load_config_text(const std::string& text, const std::string& path, TaskTable known_tasks) {
  std::vector<ConfigError> errors;
  Reader r(path, errors);
  CellConfig cfg;
  cfg.file = path;
  const YAML::Node root = parse_config_root(text, path, "a cell configuration", "the cell configuration");
  r.duplicate_keys(root, "");
  if (!errors.empty()) throw ConfigInvalid(errors);
  if (root.IsMap() && root["station"].IsDefined()) {
    r.error(root["station"], "station",
            is_inspection_station_config(text)
                ? "this is an inspection station's configuration: markcell inspect --config reads it"
                : "a marking cell's configuration has no station key (station: inspection is an inspection station's)");
    throw ConfigInvalid(errors);
  }
  std::vector<std::string> sections;
  for (const auto& section : kConfigSections) sections.emplace_back(section.key);
  if (!r.map(root, "", sections)) throw ConfigInvalid(errors);
  // A top-level section, required as kConfigSections says.
  const auto section = [&](std::string_view key) {
    const auto* s = std::find_if(kConfigSections.begin(), kConfigSections.end(),
                                 [&](const ConfigSection& c) { return c.key == key; });
    return r.child(root, "", std::string(key), s != kConfigSections.end() && s->required);
  };

  if (const auto cell = section("cell"); cell && r.map(*cell, "cell", {"name", "results_file", "record_folder", "pose_log_folder", "pose_log_rotate_mb", "operator_page"})) {
    r.text(*cell, "cell", "name", cfg.name);
    // A path resolved against the config file's folder; `folder` must exist.
    const auto path_in = [&](const char* key, std::string& out, const auto& folder_of) {
      std::string raw;
      r.text(*cell, "cell", key, raw, false, 4096);
      if (raw.empty()) return;
      std::filesystem::path p(raw);
      if (p.is_relative()) p = std::filesystem::path(path).parent_path() / p;
      p = p.lexically_normal();
      const std::filesystem::path folder = folder_of(p);
      std::error_code ec;
      if (!std::filesystem::is_directory(folder, ec))
        r.error((*cell)[key], std::string("cell.") + key, "folder '" + folder.string() + "' does not exist");
      out = p.string();
    };
    path_in("results_file", cfg.results_file, [](const std::filesystem::path& p) { return p.parent_path(); });
    path_in("record_folder", cfg.record_folder, [](const std::filesystem::path& p) { return p; });
    path_in("pose_log_folder", cfg.pose_log_folder, [](const std::filesystem::path& p) { return p; });
    r.integer(*cell, "cell", "pose_log_rotate_mb", cfg.pose_log_rotate_mb, 1, 1 << 20, false);
    std::string listen;
    r.text(*cell, "cell", "operator_page", listen, false, 64);
    std::string address, error;
    int port = 0;
    if (!listen.empty() && !parse_listen_address(listen, address, port, error))
      r.error((*cell)["operator_page"], "cell.operator_page", error);
    else cfg.operator_page = listen;
  }
  std::vector<YAML::Mark> task_marks;
  if (const auto e = section("executive")) read_executive(r, *e, known_tasks, cfg, task_marks);
  if (const auto w = section("watchdog")) read_params(r, *w, "watchdog", cfg.watchdog);
  if (const auto s = section("safe_stop")) read_params(r, *s, "safe_stop", cfg.safe_stop);
  if (const auto sp = section("spray")) read_params(r, *sp, "spray", cfg.spray);
  if (const auto d = section("devices"); d && r.map(*d, "devices", {"gpio", "arm", "cameras"})) {
    if (const auto g = r.child(*d, "devices", "gpio", true)) read_gpio(r, *g, cfg.gpio);
    if (const auto a = r.child(*d, "devices", "arm", true)) read_arm(r, *a, cfg.arm);
    if (const auto c = r.child(*d, "devices", "cameras", true)) read_cameras(r, *c, cfg.cameras);
  }
  if (const auto c = section("calibration")) read_calibration(r, *c, cfg);
  if (const auto p = section("panel_types")) read_panel_types(r, *p, cfg);
  if (const auto v = section("vision")) read_params(r, *v, "vision", cfg.vision);
  if (const auto m = section("marking")) read_params(r, *m, "marking", cfg.marking);
  read_recipes(r, static_cast<const YAML::Node&>(root)["panel_types"], cfg);
  if (const auto b = section("base_calibration")) read_base_calibration(r, *b, cfg.base_calibration);
  if (const auto l = section("line")) {
    read_params(r, *l, "line", cfg.line);
    std::string address, error;
    int port = 0;
    const YAML::Node& line = *l;
    if (!cfg.line.modbus.server.empty() && !parse_listen_address(cfg.line.modbus.server, address, port, error))
      r.error(line["modbus"]["server"], "line.modbus.server", error);
    BrokerConfig& b = cfg.line.broker;
    if (!b.server.empty()) {
      const YAML::Node broker = line["broker"];
      if (!parse_listen_address(b.server, address, port, error)) r.error(broker["server"], "line.broker.server", error);
      // Topic levels and a client id: no wildcards, no separators, nothing to escape.
      for (auto [key, value] : {std::pair<const char*, const std::string*>{"line", &b.line}, {"station", &b.station}})
        if (std::any_of(value->begin(), value->end(), [](char c) {
              return !(std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_');
            }))
          r.error(broker[key], std::string("line.broker.") + key,
                  "'" + *value + "': only letters, digits, - and _ (it is a topic level and the client id)");
      // The secrets beside the configuration: regular files (the password's is read at start).
      for (auto [key, value] : {std::pair<const char*, std::string*>{"password_file", &b.password_file}, {"ca_file", &b.ca_file}}) {
        if (value->empty()) continue;
        std::filesystem::path p(*value);
        if (p.is_relative()) p = std::filesystem::path(path).parent_path() / p;
        *value = p.lexically_normal().string();
        struct stat st{};
        if (::stat(value->c_str(), &st) != 0 || !S_ISREG(st.st_mode))
          r.error(broker[key], std::string("line.broker.") + key, "'" + *value + "' is not a regular file");
        else if (std::string_view(key) == "password_file" && (st.st_mode & 077) != 0)
          r.error(broker[key], "line.broker.password_file",
                  "'" + *value + "' can be read by others (mode " + octal_mode(st.st_mode) + "): chmod 600 it");
      }
      if (cfg.record_folder.empty())
        r.error(broker, "line.broker",
                "a station on the broker keeps the records it receives in cell.record_folder until they are used: set it");
    }
  }

  // Simulated devices are advanced by the sim_world task: one without the other is a
  // configuration that cannot run.
  // yaml-cpp throws when a scalar is indexed or a missing key's node is asked its type:
  // every level is checked to be defined and a map first (both found by the fuzzer).
  const auto is_map = [](const YAML::Node& n) { return n.IsDefined() && n.IsMap(); };
  const YAML::Node& const_root = root;
  const YAML::Node executive = const_root["executive"];
  if (const YAML::Node tasks = is_map(executive) ? executive["tasks"] : YAML::Node(); is_map(tasks)) {
    // The table's declarations: which tasks must be there, which go with simulated
    // devices, which need others, and that heavy work has a lane of its own.
    const bool simulated = cfg.arm.transport == ArmTransport::kSimulated;
    for (const auto& d : known_tasks) {
      const std::string name(d.name);
      const bool present = tasks[name].IsDefined();
      if (d.presence == TaskPresence::kRequired && !present)
        r.error(tasks, "executive.tasks", "the " + name + " task must be in the table (it " + std::string(d.doc) + ")");
      if (d.presence == TaskPresence::kWithSimulatedDevices && simulated && !present)
        r.error(tasks, "executive.tasks", "devices.arm.transport is simulated: the " + name + " task must be in the table");
      if (d.presence == TaskPresence::kWithSimulatedDevices && !simulated && present)
        r.error(tasks[name], "executive.tasks." + name, "no device is simulated: remove " + name);
      if (!present) continue;
      for (const auto& need : d.needs)
        if (!need.task.empty() && !tasks[std::string(need.task)].IsDefined())
          r.error(tasks[name], "executive.tasks." + name,
                  "the " + name + " task needs the " + std::string(need.task) + " task in the table" +
                      (need.why.empty() ? std::string() : " (" + std::string(need.why) + ")"));
    }
    for (const auto& heavy : cfg.executive.tasks) {
      const TaskDecl* hd = find_task(known_tasks, heavy.name);
      if (!hd || hd->kind != TaskKind::kHeavy) continue;
      for (const auto& other : cfg.executive.tasks) {
        const TaskDecl* od = find_task(known_tasks, other.name);
        if (od && od->kind == TaskKind::kControl && other.lane == heavy.lane) {
          r.error(tasks[heavy.name]["lane"], "executive.tasks." + heavy.name + ".lane",
                  "the " + heavy.name + " task does per-frame work: it needs a lane without control tasks (" + other.name +
                      " is on this one)");
          break;
        }
      }
    }
    const bool has_vision = tasks["vision"].IsDefined();
    if (has_vision && cfg.calibration.stereo.empty())
      r.error(tasks["vision"], "executive.tasks.vision", "the vision task needs calibration.stereo");
    if (const YAML::Node trig = tasks["camera_trigger"]; trig.IsDefined()) {
      if (cfg.cameras.trigger != CameraTrigger::kHardware)
        r.error(trig, "executive.tasks.camera_trigger",
                "devices.cameras.trigger is software: the cameras are not on the trigger line; remove camera_trigger or set trigger: hardware");
      // One rising edge every other run: the task runs at twice the frame rate.
      for (const auto& t : cfg.executive.tasks)
        if (t.name == "camera_trigger" && cfg.cameras.fps > 0) {
          const double period_us = static_cast<double>(t.period_ticks) * static_cast<double>(cfg.executive.tick) / 1e3;
          const double want_us = 1e6 / (2.0 * cfg.cameras.fps);
          if (std::abs(period_us - want_us) > 0.02 * want_us) {
            const double tick_us = static_cast<double>(cfg.executive.tick) / 1e3;
            char message[240];
            std::snprintf(message, sizeof message,
                          "period_us %.0f gives %.2f frames/s (a rising edge every other run); devices.cameras.fps is %g: "
                          "set period_us to %.0f (the multiple of the %.0f us tick nearest %.0f)",
                          period_us, 1e6 / (2.0 * period_us), cfg.cameras.fps, std::max(1.0, std::round(want_us / tick_us)) * tick_us,
                          tick_us, want_us);
            r.error(trig, "executive.tasks.camera_trigger", message);
          }
        }
    }
    const YAML::Node types = const_root["panel_types"];
    const auto file_given = [&](const std::string& name) {
      return is_map(types) && is_map(types[name]) && types[name]["file"].IsDefined();
    };
    if (has_vision)
      for (const auto& panel : cfg.panel_types)
        if (panel.file.empty() && !file_given(panel.name))
          r.error(tasks["vision"], "executive.tasks.vision",
                  "panel type '" + panel.name + "' has no file (panel_types." + panel.name + ".file, made by markcell select-mfs)");
  }
  if (!errors.empty()) throw ConfigInvalid(std::move(errors));
  // The loader has checked everything the executive checks; this is the last line of
  // defence and must agree.
  control::validate(cfg.executive);
  return cfg;
}

bool is_inspection_station_config(const std::string& text) {
  // A line `station: inspection` at the top level (column 1), a comment after it allowed.
  std::size_t at = 0;
  while (at < text.size()) {
    const std::size_t end = std::min(text.find('\n', at), text.size());
    std::string_view line(text.data() + at, end - at);
    if (const std::size_t hash = line.find('#'); hash != std::string_view::npos) line = line.substr(0, hash);
    while (!line.empty() && (line.back() == ' ' || line.back() == '\r' || line.back() == '\t')) line.remove_suffix(1);
    if (line == "station: inspection" || line == "station: \"inspection\"" || line == "station: 'inspection'") return true;
    at = end + 1;
  }
  return false;
}

InspectionStationConfig load_inspection_station_config(const std::string& path) {
  return load_inspection_station_config_text(read_config_text(path), path);
}

InspectionStationConfig load_inspection_station_config_text(const std::string& text, const std::string& path) {
  std::vector<ConfigError> errors;
  Reader r(path, errors);
  InspectionStationConfig cfg;
  cfg.file = path;
  const YAML::Node root = parse_config_root(text, path, "an inspection station's configuration", "the inspection station's configuration");
  r.duplicate_keys(root, "");
  if (!errors.empty()) throw ConfigInvalid(errors);
  if (!r.map(root, "", {"station", "inspection", "panel_types", "vision"})) throw ConfigInvalid(errors);
  std::string station;
  r.text(root, "", "station", station);
  if (!station.empty() && station != "inspection")
    r.error(root["station"], "station", "expected inspection, got '" + station + "' (a marking cell's configuration has no station key)");
  vision::StereoCalibration scanner;
  bool have_scanner = false;
  if (const auto s = r.child(root, "", "inspection", true);
      s && r.map(*s, "inspection", {"name", "scanner_calibration", "record_folder", "min_points_per_defect"})) {
    r.text(*s, "inspection", "name", cfg.name);
    r.existing_file(*s, "inspection", "scanner_calibration", cfg.scanner_calibration);
    if (!cfg.scanner_calibration.empty()) {
      try {
        scanner = vision::load_stereo_calibration(cfg.scanner_calibration);
        have_scanner = true;
      } catch (const std::exception& e) {
        r.error((*s)["scanner_calibration"], "inspection.scanner_calibration", e.what());
      }
    }
    if ((*s)["record_folder"].IsDefined()) r.existing_file(*s, "inspection", "record_folder", cfg.record_folder, true);
    r.integer(*s, "inspection", "min_points_per_defect", cfg.min_points_per_defect, 1, control::kMaxDefectPoints, false);
  }
  if (const auto p = r.child(root, "", "panel_types", true)) {
    CellConfig types;
    read_panel_types(r, *p, types);
    cfg.panel_types = types.panel_types;
    for (const PanelTypeConfig& panel : cfg.panel_types) {
      const YAML::Node n = (*p)[panel.name];
      const std::string TP = "panel_types." + panel.name;
      if (!n.IsMap()) continue;
      if (n["recipe"].IsDefined())
        r.error(n["recipe"], TP + ".recipe", "an inspection station does not spray: a recipe belongs in the marking cell's configuration");
      if (!n["file"].IsDefined()) {
        r.error(n, TP, "missing required key 'file' (the panel type's MFs on a scanner image, markcell select-mfs)");
        continue;
      }
      if (panel.file.empty() || !have_scanner) continue;
      try {
        const auto model = vision::load_panel_type(panel.file);
        if (model.image_width != scanner.left.width || model.image_height != scanner.left.height)
          r.error(n["file"], TP + ".file",
                  std::string("its MFs were picked on a ") + std::to_string(model.image_width) + "x" + std::to_string(model.image_height) +
                      " image; the scanner's cameras are " + std::to_string(scanner.left.width) + "x" +
                      std::to_string(scanner.left.height) + " (select-mfs on a scanner image)");
      } catch (const std::exception&) {
        // read_panel_types has said what is wrong with it.
      }
    }
  }
  if (const auto v = r.child(root, "", "vision", false)) read_params(r, *v, "vision", cfg.vision);
  if (!errors.empty()) throw ConfigInvalid(std::move(errors));
  return cfg;
}

}  // namespace markcell::host
