// The service's subcommands: check-config, config-schema, run, publish-record (and inspect).
#include <signal.h>

#include <cmath>
#include <iostream>
#include <memory>

#include "markcell/common/bounded_file.hpp"
#include "markcell/host/calibration_state.hpp"
#include "markcell/host/command.hpp"
#include "markcell/host/inspection_record.hpp"
#include "markcell/host/inspection_station.hpp"
#include "markcell/host/service_loop.hpp"
#include "markcell/sim/plc_script.hpp"

namespace markcell::host {
namespace {

int check_config_command(const std::string& file) {
  const auto errors = check_config(file, task_catalog());
  if (errors.empty() && is_inspection_station_config(read_bounded_file(file, kMaxConfigBytes, "a configuration"))) {
    const InspectionStationConfig config = load_inspection_station_config(file);
    std::cout << file << ": valid (an inspection station: markcell inspect)\n"
              << "scanner calibration " << config.scanner_calibration << ": " << calibration_summary(config.scanner_calibration)
              << "\n";
    return 0;
  }
  if (errors.empty()) {
    std::cout << file << ": valid\n";
    // The calibrations it uses, by file, date and fit: the one in use named beside its
    // earlier versions (markcell calibrations lists them).
    if (const std::optional<CellConfig> config = load_or_report(file)) {
      if (const std::string warning = pairing_warning(*config); !warning.empty()) std::cerr << file << ": warning: " << warning << "\n";
      std::cout << "stereo calibration " << config->calibration.stereo << ": "
                << calibration_summary(config->calibration.stereo) << "\n";
      if (!config->calibration.base.empty())
        std::cout << "base calibration " << config->calibration.base << ": " << calibration_summary(config->calibration.base)
                  << "\n";
    }
    return 0;
  }
  for (const auto& e : errors) std::cerr << e.to_string() << "\n";
  std::cerr << errors.size() << " error(s) in " << file << "\n";
  return kExitConfig;
}

int run_command(const std::string& file, const std::string& clock_name, double seconds, const std::string& plc_script,
                const sigset_t& stop_signals) {
  // SIGHUP reloads (systemctl reload markcell): blocked before the cell's threads exist
  // (they inherit the mask, so none of them is ended by it) and taken by the service loop.
  sigset_t signals = stop_signals;
  sigaddset(&signals, SIGHUP);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  const std::optional<CellConfig> loaded = load_or_report(file);
  if (!loaded) return kExitConfig;
  const CellConfig& config = *loaded;
  std::vector<sim::PlcEvent> plc_events;
  if (!plc_script.empty()) {
    if (!config.gpio.simulated) {
      std::cerr << "markcell: --plc-script drives simulated PLC lines; " << file
                << " has devices.gpio.simulated: false (the real PLC drives the real lines)\n";
      return kExitConfig;
    }
    try {
      plc_events = sim::load_plc_script(plc_script);
    } catch (const std::exception& e) {
      std::cerr << "markcell: " << e.what() << "\n";
      return kExitConfig;
    }
  }
  const ClockKind clock = clock_name == "sim" ? ClockKind::kSimulated : ClockKind::kReal;
  Cell cell(config, clock);
  std::unique_ptr<ServiceLoop> service;
  try {
    ServiceOptions options;
    options.clock = clock;
    options.duration = static_cast<Nanos>(std::llround(seconds * 1e9));
    options.plc_events = std::move(plc_events);
    options.pose_log_folder = config.pose_log_folder;
    options.pose_log_rotate_bytes = config.pose_log_rotate_mb * 1024 * 1024;
    options.operator_page = true;
    service = std::make_unique<ServiceLoop>(config, cell, std::move(options));
    service->start();
  } catch (const std::exception& e) {
    std::cerr << "markcell: start-up failed: " << e.what() << "\n";
    return kExitRuntime;
  }
  return service->run(signals);
}

}  // namespace

std::optional<CellConfig> load_or_report(const std::string& file) {
  try {
    return load_config(file, task_catalog());
  } catch (const ConfigInvalid& e) {
    for (const auto& err : e.errors()) std::cerr << err.to_string() << "\n";
    std::cerr << e.errors().size() << " error(s) in " << file << "\n";
    return std::nullopt;
  }
}

void add_service_commands(CLI::App& app, Commands& out, const sigset_t& stop_signals) {
  struct Options {
    std::string check_file;
    bool list_tasks = false;
    std::string run_file;
    std::string clock_name = "real";
    double run_seconds = 0;
    std::string run_plc_script;
  };
  const auto o = std::make_shared<Options>();

  auto* check = app.add_subcommand("check-config", "Validate a cell configuration; print every error and exit 2 if any");
  check->add_option("FILE", o->check_file, "Cell configuration (YAML)");
  check->add_flag("--tasks", o->list_tasks, "Print the tasks this build provides (a Markdown table) instead");
  out.push_back({check, [o] {
                   if (o->list_tasks) {
                     std::cout << task_table_markdown(task_catalog());
                     return 0;
                   }
                   if (o->check_file.empty()) {
                     std::cerr << "check-config: FILE is required (or --tasks)\n";
                     return kExitConfig;
                   }
                   return check_config_command(o->check_file);
                 }});

  auto* schema = app.add_subcommand("config-schema",
                                    "Print a JSON Schema of the cell configuration (for editors; from the parameters' declarations)");
  out.push_back({schema, [] {
                   std::cout << config_schema_json(task_catalog());
                   return 0;
                 }});

  auto* run = app.add_subcommand("run", "Run the cell from its configuration until SIGTERM/SIGINT (or --seconds)");
  run->add_option("--config,-c", o->run_file, "Cell configuration (YAML)")->required();
  run->add_option("--clock", o->clock_name, "real: CLOCK_MONOTONIC; sim: simulated time, as fast as it computes")
      ->check(CLI::IsMember({"real", "sim"}));
  run->add_option("--seconds", o->run_seconds, "Stop after this long (0: until a signal; needed with --clock sim)")
      ->check(CLI::NonNegativeNumber);
  run->add_option("--plc-script", o->run_plc_script,
                  "Simulated GPIO only: drive the PLC inputs from FILE ('SECONDS LINE 0|1' per line, from the start)")
      ->check(CLI::ExistingFile);
  out.push_back({run,
                 [o, stop_signals] {
                   if (o->clock_name == "sim" && o->run_seconds <= 0) {
                     std::cerr << "markcell run: --clock sim needs --seconds (simulated time has no signal to stop it)\n";
                     return kExitConfig;
                   }
                   return run_command(o->run_file, o->clock_name, o->run_seconds, o->run_plc_script, stop_signals);
                 },
                 true});

  struct PublishOptions {
    std::string config;
    std::vector<std::string> records;
  };
  const auto p = std::make_shared<PublishOptions>();
  auto* publish = app.add_subcommand(
      "publish-record",
      "The inspection station's side of the broker: publish inspection records (the drop folder's files), each retained "
      "on its panel's topic (docs/line.md)");
  publish->add_option("--config,-c", p->config, "The station's configuration (its line.broker and panel_types)")->required();
  publish->add_option("RECORD", p->records, "Inspection record files (vision/RECORDING.md, inspection.yaml)")->required();
  out.push_back({publish, [p] {
                   return with_config(p->config, [&](const CellConfig& config) {
                     if (config.line.broker.server.empty()) {
                       std::cerr << "markcell publish-record: " << config.file << ": line.broker is not configured\n";
                       return kExitConfig;
                     }
                     // Every record read and validated before the first is published.
                     std::vector<std::pair<std::string, std::string>> texts;
                     for (const std::string& path : p->records) {
                       try {
                         std::string text = read_bounded_file(path, BrokerLink::kMaxPayloadBytes, "an inspection record");
                         (void)parse_inspection_record(text, path, config.panel_types);
                         if (!ends_with_end_marker(text))
                           throw RecordInvalid(path + ": its last line is not YAML's end-of-document marker '...'");
                         texts.emplace_back(path, std::move(text));
                       } catch (const std::exception& e) {
                         std::cerr << "markcell publish-record: " << e.what() << "\n";
                         return kExitConfig;
                       }
                     }
                     try {
                       BrokerLink link(config.line.broker, BrokerLink::Role::kInspection, config.record_folder,
                                       config.panel_types, nullptr, [](void*) { return monotonic_now(); }, nullptr);
                       link.connect();
                       link.publish_state("online", "publishing " + std::to_string(texts.size()) + " record(s)", "");
                       for (const auto& [path, text] : texts) {
                         if (!link.publish_record(text, path, config.line.broker.connect_timeout))
                           throw std::runtime_error(path + ": not acknowledged by the broker: " +
                                                    (link.error().empty() ? "no answer" : link.error()));
                         std::cout << "published " << path << " (retained "
                                   << config.line.broker.record_retain / seconds(1) << " s)\n";
                       }
                       link.stop("published " + std::to_string(texts.size()) + " record(s)");
                     } catch (const std::exception& e) {
                       std::cerr << "markcell publish-record: the broker: " << e.what() << "\n";
                       return kExitRuntime;
                     }
                     return 0;
                   });
                 }});
  add_inspect_command(app, out);
}

}  // namespace markcell::host
