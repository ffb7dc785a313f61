// `markcell config-schema`: a JSON Schema of cell.yaml from the parameters' own
// declarations (each struct's Visit(), common/param.hpp), so the schema, the loader and
// the example's documented defaults are one list. Output is deterministic: keys in
// declaration order, numbers printed with %.12g (an editor shows 0.6, not
// 0.6000000000000001 for a default stored in radians).
#include <concepts>
#include <cstdio>
#include <sstream>
#include <string>
#include <vector>

#include "markcell/host/config.hpp"
#include "markcell/host/json.hpp"

namespace markcell::host {
namespace {

std::string num(double v) {
  char b[40];
  std::snprintf(b, sizeof b, "%.12g", v);
  return b;
}

std::string described(const Param& p) {
  std::string d(p.doc);
  if (p.unit != Unit::kNone) d += " [" + std::string(unit_name(p.unit)) + "]";
  return json_quote(d);
}

// One section's properties, written as its struct declares them.
class SchemaWriter {
 public:
  void operator()(const Param& p, double& field) {
    add(p, "\"type\": \"number\", " + range(p) + ", \"default\": " + num(from_si(field, p.unit)));
  }
  template <std::integral T>
    requires(!std::same_as<T, bool> && !std::same_as<T, Nanos>)
  void operator()(const Param& p, T& field) {
    if (p.unit == Unit::kOddWindowPx)
      add(p, "\"type\": \"integer\", " + range(p) + ", \"not\": {\"multipleOf\": 2}, \"default\": " +
                 std::to_string(2 * field + 1));
    else
      add(p, "\"type\": \"integer\", " + range(p) + ", \"default\": " + std::to_string(field));
  }
  void operator()(const Param& p, Nanos& field) {
    const std::string type = integer_duration(p.unit) ? "integer" : "number";
    add(p, "\"type\": \"" + type + "\", " + range(p) + ", \"default\": " + num(from_nanos(field, p.unit)));
  }
  void operator()(const Param& p, bool& field) {
    add(p, std::string("\"type\": \"boolean\", \"default\": ") + (field ? "true" : "false"));
  }
  void operator()(const Param& p, std::string& field) {
    add(p, "\"type\": \"string\", \"minLength\": " + num(p.lo) + ", \"maxLength\": " + num(p.hi) +
               (field.empty() ? std::string() : ", \"default\": " + json_quote(field)));
  }
  void operator()(const Param& p, Eigen::Vector3d& field) { triple(p, {field.x(), field.y(), field.z()}); }
  void operator()(const Param& p, std::array<double, 3>& field) { triple(p, field); }
  template <typename E, std::size_t N>
  void operator()(const Param& p, Choice<E, N> c) {
    std::string names, current;
    for (const auto& o : c.options) {
      names += (names.empty() ? "" : ", ") + json_quote(o.name);
      if (o.value == c.value) current = json_quote(o.name);
    }
    add(p, "\"enum\": [" + names + "], \"default\": " + current);
  }
  template <typename T>
  void operator()(const Param& p, Section<T> section) {
    SchemaWriter nested;
    section.value.Visit(nested);
    add_object(p.key, nested.object(p.doc), p.required);
  }

  // A key the loader reads by hand in the same map, with its schema.
  void add_object(std::string_view key, const std::string& schema, bool required) {
    if (!properties_.empty()) properties_ += ", ";
    properties_ += json_quote(key) + ": " + schema;
    if (required) required_ += (required_.empty() ? "" : ", ") + json_quote(key);
  }

  // {"type": "object", "additionalProperties": false, "required": [...], "properties": {...}}
  std::string object(std::string_view doc) const {
    std::string out = "{\"type\": \"object\", \"description\": " + json_quote(doc) + ", \"additionalProperties\": false";
    if (!required_.empty()) out += ", \"required\": [" + required_ + "]";
    return out + ", \"properties\": {" + properties_ + "}}";
  }

 private:
  static std::string range(const Param& p) { return "\"minimum\": " + num(p.lo) + ", \"maximum\": " + num(p.hi); }
  void triple(const Param& p, const std::array<double, 3>& v) {
    add(p, "\"type\": \"array\", \"minItems\": 3, \"maxItems\": 3, \"items\": {\"type\": \"number\", " + range(p) +
               "}, \"default\": [" + num(from_si(v[0], p.unit)) + ", " + num(from_si(v[1], p.unit)) + ", " +
               num(from_si(v[2], p.unit)) + "]");
  }
  void add(const Param& p, const std::string& body) {
    add_object(p.key, "{\"description\": " + described(p) + ", " + body + "}", p.required);
  }
  std::string properties_, required_;
};

// A section as its struct declares it, with the keys the loader reads by hand in it.
struct Extra {
  std::string_view key;
  std::string schema;
  bool required;
};
template <class Params>
std::string declared_section(Params params, std::string_view doc, const std::vector<Extra>& extras = {}) {
  SchemaWriter w;
  params.Visit(w);
  for (const auto& e : extras) w.add_object(e.key, e.schema, e.required);
  return w.object(doc);
}

// A map of names (lanes, tasks, panel types, the lines by role), each value one schema.
std::string named_map(std::string_view doc, const std::string& each, const std::string& names_enum = "") {
  std::string out = "{\"type\": \"object\", \"description\": " + json_quote(doc) + ", \"minProperties\": 1";
  if (!names_enum.empty()) out += ", \"propertyNames\": {\"enum\": [" + names_enum + "]}";
  return out + ", \"additionalProperties\": " + each + "}";
}

std::string text_item(std::string_view doc) {
  return "{\"type\": \"string\", \"minLength\": 1, \"description\": " + json_quote(doc) + "}";
}

std::string integer_item(std::string_view doc, long long lo, long long hi) {
  return "{\"type\": \"integer\", \"minimum\": " + std::to_string(lo) + ", \"maximum\": " + std::to_string(hi) +
         ", \"description\": " + json_quote(doc) + "}";
}

std::string pose_six(std::string_view doc) {
  return "{\"type\": \"array\", \"description\": " + json_quote(doc) +
         ", \"minItems\": 6, \"maxItems\": 6, \"items\": {\"type\": \"number\", \"minimum\": -360, \"maximum\": 360}}";
}

std::string executive_section(std::string_view doc, TaskTable known_tasks) {
  std::string tasks;
  for (const auto& t : known_tasks) tasks += (tasks.empty() ? "" : ", ") + json_quote(t.name);
  const std::string us = "{\"type\": \"integer\", \"minimum\": 0, \"maximum\": 3600000000}";
  const std::string task =
      "{\"type\": \"object\", \"additionalProperties\": false, \"required\": [\"lane\", \"period_us\", \"budget_us\"], "
      "\"properties\": {\"lane\": " + text_item("a lane of executive.lanes") + ", \"period_us\": " + us +
      ", \"phase_us\": " + us + ", \"budget_us\": " + us +
      ", \"on_overrun\": {\"enum\": [\"log\", \"degrade\", \"safe_stop\"], \"default\": \"log\"}}}";
  return declared_section(control::ExecutiveSpec{}, doc,
                          {{"lanes", named_map("one thread each", declared_section(control::LaneSpec{}, "a lane")), true},
                           {"tasks", named_map("the tasks this build provides, in their order within a tick", task, tasks),
                            true}});
}

std::string devices_section(std::string_view doc) {
  SchemaWriter lines;
  for (std::size_t i = 0; i < kLineRoleCount; ++i)
    lines.add_object(to_string(static_cast<LineRole>(i)), declared_section(GpioLineConfig{}, "the role's line"), true);
  const std::string gpio = declared_section(GpioConfig{}, "the chip, the lines by role, the PLC inputs' filter",
                                            {{"lines", lines.object("each role's line (gpioinfo names them)"), true}});
  SchemaWriter arm;
  arm.add_object("transport", "{\"enum\": [\"simulated\", \"can\", \"serial\"], \"description\": \"the arm's link\"}", true);
  arm.add_object("can", declared_section(CanConfig{}, "the CANopen link (required with transport: can)"), false);
  arm.add_object("serial", declared_section(drivers::SerialArmLinkConfig{}, "the serial link (required with transport: serial)"),
                 false);
  arm.add_object("limits", declared_section(ArmLimitsConfig{}, "the arm's limits (all keys required)"), true);
  const std::string cameras =
      declared_section(CameraConfig{}, "the stereo pair",
                       {{"recording", text_item("with source: recording: the recording's folder"), false}});
  SchemaWriter devices;
  devices.add_object("gpio", gpio, true);
  devices.add_object("arm", arm.object("the arm's transport, its link and its limits"), true);
  devices.add_object("cameras", cameras, true);
  return devices.object(doc);
}

}  // namespace

std::string config_schema_json(TaskTable known_tasks) {
  std::ostringstream os;
  os << "{\n  \"$schema\": \"http://json-schema.org/draft-07/schema#\",\n"
     << "  \"title\": \"markcell cell configuration\",\n"
     << "  \"description\": \"cell.yaml (docs/configuration.md). Generated by markcell config-schema from the parameters' "
        "declarations; markcell check-config adds the checks across keys and files.\",\n"
     << "  \"type\": \"object\",\n  \"additionalProperties\": false,\n";
  std::string required;
  for (const auto& s : kConfigSections)
    if (s.required) required += (required.empty() ? "" : ", ") + json_quote(s.key);
  os << "  \"required\": [" << required << "],\n  \"properties\": {\n";
  for (std::size_t i = 0; i < kConfigSections.size(); ++i) {
    const auto& s = kConfigSections[i];
    std::string body;
    if (s.key == "cell") {
      SchemaWriter cell;
      cell.add_object("name", text_item("appears in logs and results"), true);
      cell.add_object("results_file", text_item("each panel's result, appended and synced"), false);
      cell.add_object("record_folder", text_item("inspection records arrive here"), false);
      cell.add_object("pose_log_folder", text_item("poses.csv and mf_tracks.csv written here"), false);
      cell.add_object("pose_log_rotate_mb", integer_item("each pose log file rotated to FILE.1 past this size, MiB", 1, 1 << 20), false);
      cell.add_object("operator_page", text_item("ADDRESS:PORT the operator page and /metrics listen on (e.g. 127.0.0.1:8089); absent: off"), false);
      body = cell.object(s.doc);
    } else if (s.key == "executive") {
      body = executive_section(s.doc, known_tasks);
    } else if (s.key == "watchdog") {
      body = declared_section(WatchdogConfig{}, s.doc);
    } else if (s.key == "safe_stop") {
      body = declared_section(SafeStopConfig{}, s.doc);
    } else if (s.key == "spray") {
      body = declared_section(SprayConfig{}, s.doc);
    } else if (s.key == "devices") {
      body = devices_section(s.doc);
    } else if (s.key == "calibration") {
      SchemaWriter cal;
      cal.add_object("stereo", text_item("OpenCV FileStorage: K1 D1 K2 D2 R T image_width image_height"), true);
      cal.add_object("base", text_item("OpenCV FileStorage: X_Base_CamR (4x4)"), true);
      body = cal.object(s.doc);
    } else if (s.key == "panel_types") {
      body = named_map(
          s.doc, declared_section(PanelTypeConfig{}, "a panel type",
                                  {{"file", text_item("its MFs and templates (markcell select-mfs)"), false},
                                   {"recipe",
                                    declared_section(RecipeParams{},
                                                     "its process settings over the spray and marking sections' (each optional)"),
                                    false}}));
    } else if (s.key == "vision") {
      body = declared_section(vision::TrackerParams{}, s.doc);
    } else if (s.key == "marking") {
      body = declared_section(control::MarkingParams{}, s.doc);
    } else if (s.key == "line") {
      body = declared_section(LineConfig{}, s.doc);
    } else if (s.key == "base_calibration") {
      body = declared_section(
          BaseCalibrationConfig{}, s.doc,
          {{"X_Tool_Board", pose_six("the board's first inner corner on the tool: [x, y, z] m, rotation vector deg"), false},
           {"poses", "{\"type\": \"array\", \"minItems\": 6, \"maxItems\": 200, \"items\": " +
                         pose_six("a tool pose in the base frame: [x, y, z] m, rotation vector deg") + "}",
            false}});
    }
    os << "    " << json_quote(s.key) << ": " << body << (i + 1 < kConfigSections.size() ? ",\n" : "\n");
  }
  os << "  }\n}\n";
  return os.str();
}

std::string task_table_markdown(TaskTable tasks) {
  std::string out = "| task | kind | in the table | needs | what it does |\n| --- | --- | --- | --- | --- |\n";
  for (const auto& t : tasks) {
    std::string needs;
    for (const auto& n : t.needs)
      if (!n.task.empty()) needs += (needs.empty() ? "`" : ", `") + std::string(n.task) + "`";
    const char* presence = t.presence == TaskPresence::kRequired               ? "always"
                           : t.presence == TaskPresence::kWithSimulatedDevices ? "exactly with simulated devices"
                                                                               : "optional";
    out += "| `" + std::string(t.name) + "` | " + std::string(to_string(t.kind)) + " | " + presence + " | " +
           (needs.empty() ? "" : needs) + " | " + std::string(t.doc) + " |\n";
  }
  return out;
}

}  // namespace markcell::host
