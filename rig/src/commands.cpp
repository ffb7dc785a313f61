// The rig's subcommands: sim and replay.
#include "markcell/rig/commands.hpp"

#include <filesystem>
#include <iostream>
#include <memory>

#include "markcell/common/log_escape.hpp"
#include "markcell/host/install_paths.hpp"
#include "markcell/host/service_loop.hpp"
#include "markcell/host/stop_signal.hpp"
#include "markcell/rig/render.hpp"
#include "markcell/rig/replay.hpp"
#include "markcell/rig/panel.hpp"
#include "markcell/rig/scenario.hpp"
#include "markcell/sim/plc_script.hpp"
#include "markcell/vision/calibration_io.hpp"

namespace markcell::rig {
namespace {

using namespace markcell::host;

int replay_command(const CellConfig& config, const std::string& recording, const std::string& out,
                   const rig::ReplayOptions& base) {
  rig::ReplayOptions options = base;
  options.out_dir = out;
  const rig::ReplayReport report = rig::replay_recording(config, recording, options);
  const auto files = rig::write_report(report, config, out);
  std::cout << rig::report_table(report, files);
  // Stopped by a signal: the report is written (and marked partial); the exit status is
  // the shell's for a process ended by that signal.
  if (!report.stopped.empty() && options.stop != nullptr) return 128 + options.stop->load();
  return 0;
}

int sim_command(const CellConfig& config, const std::string& scenario_name, bool seed_given, std::uint64_t seed, double seconds_limit,
                double fps, const std::string& scanner_file, const std::string& out, const rig::ReplayOptions& base,
                const BoardCalibration& calibrate_board) {
  rig::Scenario scenario;
  rig::ReplayOptions options = base;
  std::string scenario_path;
  try {
    // A name is a shipped scenario (scenarios/ beside the configuration), a path a file.
    scenario_path = rig::scenario_file(scenario_name, rig::scenario_folder(config.file));
    scenario = rig::load_scenario(scenario_path);
    if (seed_given) scenario = rig::with_seed(scenario, seed);
    // The scenario's PLC script, unless --plc-script gave one.
    if (!scenario.plc_script.empty() && !options.plc_script_given) options.plc_events = sim::load_plc_script(scenario.plc_script);
  } catch (const std::exception& e) {
    std::cerr << "markcell sim: " << escape_log(e.what()) << "\n";
    return kExitConfig;
  }
  if (scenario.board_only) {
    const auto o = std::filesystem::path(out);
    return calibrate_board(config, (o / "base.yaml").string(), scenario.seed, (o / "board").string(), out);
  }
  const std::filesystem::path recording = std::filesystem::path(out) / "recording";
  // The folder is the rig's own output: a previous run's recording is replaced.
  if (std::filesystem::exists(recording / "recording.yaml")) std::filesystem::remove_all(recording);
  const auto marking = vision::load_stereo_calibration(config.calibration.stereo);
  const auto scanner = vision::load_stereo_calibration(scanner_file);
  rig::Panel panel;
  try {
    panel = rig::configured_panel(config.panel_types, scenario.panel_type);
    // A defect must lie on the panel's skin: off it, nothing would be there to mark and
    // the score would count a miss the cell could not help.
    for (std::size_t i = 0; i < scenario.defects.size(); ++i) {
      const rig::DefectSpec& d = scenario.defects[i];
      if (!panel.solid(d.x, d.y))
        throw std::invalid_argument(scenario_path + ": defects[" + std::to_string(i) + "] (id " + std::to_string(d.id) +
                                    ") at x " + std::to_string(d.x) + " m, y " + std::to_string(d.y) +
                                    " m is not on the " + panel.name + "'s surface");
    }
  } catch (const std::exception& e) {
    std::cerr << "markcell sim: " << escape_log(e.what()) << "\n";
    return kExitConfig;
  }
  rig::GenerateOptions g;
  if (seconds_limit > 0) g.max_duration = static_cast<Nanos>(seconds_limit * 1e9);
  g.fps = fps;
  g.stop = options.stop;
  if (options.progress) std::cerr << "markcell sim: rendering " << scenario_name << " into " << recording.string() << "\n";
  std::size_t frames = 0;
  rig::RenderSettings render;
  render.threads = 2;  // the two views side by side: the images are the same as on one thread
  try {
    frames = rig::generate_recording(scenario, panel, recording.string(), marking, scanner, render, g);
  } catch (const rig::GenerationStopped& e) {
    std::cerr << "markcell sim: " << escape_log(e.what()) << "\n";
    return 128 + e.signal;
  } catch (const std::exception& e) {
    std::cerr << "markcell sim: " << escape_log(e.what()) << "\n";
    return kExitRuntime;
  }
  if (options.progress) std::cerr << "markcell sim: " << frames << " stereo frames; replaying through the cell\n";
  return replay_command(config, recording.string(), out, options);
}

}  // namespace

void add_rig_commands(CLI::App& app, Commands& out, const sigset_t& stop_signals, BoardCalibration calibrate_board) {
  struct Options {
    std::string rig_config = host::default_config_file(), rig_out, sim_scenario, replay_recording, scanner_file;
    std::uint64_t sim_seed = 1;
    double sim_seconds = 0, sim_fps = -1, radius_mm = 10;
    bool one_predictor = false, quiet = false, no_arm = false, draw_arm = false;
    std::string rig_plc_script, rig_gpio_sim, rig_arm_serial_peer, replay_calibration;
  };
  const auto o = std::make_shared<Options>();
  auto* sim = app.add_subcommand("sim", "Generate a rig scenario and replay it through the cell in simulated time; score and report it");
  sim->add_option("SCENARIO", o->sim_scenario,
                  "A scenario file (FILE.yaml), or the name of one in scenarios/ beside the configuration: paper-door, "
                  "paper-fender, paper-curved, line-fast, occlusion-person, frame-drops, nine-defects, calibration-board")
      ->required();
  auto* seed_option = sim->add_option("--seed", o->sim_seed, "Scenario seed (noise, speed fluctuation, drops; default: the file's)");
  sim->add_option("--seconds", o->sim_seconds, "Shorten the scenario to this many seconds")->check(CLI::PositiveNumber);
  sim->add_option("--fps", o->sim_fps, "Frame rate of the generated recording (default: the scenario's, 30)")->check(CLI::PositiveNumber);
  sim->add_option("--scanner", o->scanner_file, "Inspection scanner calibration (default: inspection_stereo.yaml beside the configuration's stereo calibration)");
  auto* replay = app.add_subcommand("replay", "Replay a recording through the cell in simulated time; score it when it has ground truth");
  replay->add_option("RECORDING", o->replay_recording, "Recording folder (vision/RECORDING.md)")->required()->check(CLI::ExistingDirectory);
  replay->add_option("--gpio-sim", o->rig_gpio_sim,
                     "Replay in real time on the configured real devices (libgpiod chip, CAN or serial arm link): the rig's "
                     "PLC and valve through this gpio-sim chip's sysfs folder, its simulated arm a node on the CAN interface "
                     "or on the serial line's other end (--arm-serial-peer)")
      ->check(CLI::ExistingDirectory);
  replay->add_option("--arm-serial-peer", o->rig_arm_serial_peer,
                     "With --gpio-sim and an arm on a serial line: the line's other end, where the rig's arm answers "
                     "(a second port on a null-modem cable, or socat's other pty)")
      ->needs("--gpio-sim")
      ->check(CLI::ExistingPath);
  replay->add_option("--calibration", o->replay_calibration,
                     "Stereo calibration to replay with, when the recording's and the configuration's differ")
      ->check(CLI::ExistingFile);
  for (auto* c : {sim, replay}) {
    c->add_option("--config,-c", o->rig_config, std::string("Cell configuration (YAML)") + kDefaultConfigHelp);
    c->add_option("--out,-o", o->rig_out, "Folder for report.json, the plots (and the generated recording)")->required();
    c->add_option("--radius-mm", o->radius_mm, "A spray within this of a defect's centre marks it")->check(CLI::PositiveNumber);
    c->add_flag("--one-predictor", o->one_predictor, "Replay with the configured predictor only (default: both, same frames)");
    c->add_option("--plc-script", o->rig_plc_script, "PLC inputs during the replay ('SECONDS LINE 0|1' per line, from the start): an e-stop, a panel leaving early")
        ->check(CLI::ExistingFile);
    c->add_flag("--no-arm", o->no_arm, "Do not draw the simulated arm into synthetic frames (it occludes macro-features in closed loop)");
    c->add_flag("--quiet,-q", o->quiet, "No progress lines");
  }
  replay->add_flag("--draw-arm", o->draw_arm,
                   "Draw the simulated arm into the frames of a recording markcell sim did not make (a synthetic one of "
                   "another tool)")
      ->excludes("--no-arm");
  const auto run = [o, stop_signals, calibrate_board, seed_option](bool is_replay) {
    const auto config = load_or_report(o->rig_config);
    if (!config) return kExitConfig;
    // A stop asked for ends the run at its next step, with its report marked partial.
    StopSignalWatcher stop(stop_signals);
    ReplayOptions options;
    options.stop = &stop.signal();
    options.progress = !o->quiet;
    options.both_predictors = !o->one_predictor;
    options.draw_arm = o->no_arm    ? ReplayOptions::ArmDrawing::kNever
                       : o->draw_arm ? ReplayOptions::ArmDrawing::kAlways
                                     : ReplayOptions::ArmDrawing::kRigRecordings;
    options.calibration = o->replay_calibration;
    options.gpio_sim = o->rig_gpio_sim;
    options.arm_serial_peer = o->rig_arm_serial_peer;
    options.plc_script_given = !o->rig_plc_script.empty();
    if (!o->rig_plc_script.empty()) {
      try {
        options.plc_events = sim::load_plc_script(o->rig_plc_script);
      } catch (const std::exception& e) {
        std::cerr << "markcell: " << e.what() << "\n";
        return kExitConfig;
      }
    }
    options.radius = o->radius_mm / 1000.0;
    if (is_replay) return replay_command(*config, o->replay_recording, o->rig_out, options);
    std::string scanner_file = o->scanner_file;
    if (scanner_file.empty())
      scanner_file = (std::filesystem::path(config->calibration.stereo).parent_path() / "inspection_stereo.yaml").string();
    return sim_command(*config, o->sim_scenario, seed_option->count() > 0, o->sim_seed, o->sim_seconds, o->sim_fps, scanner_file, o->rig_out, options,
                       calibrate_board);
  };
  out.push_back({sim, [run] { return run(false); }, true});
  out.push_back({replay, [run] { return run(true); }, true});
}

}  // namespace markcell::rig
