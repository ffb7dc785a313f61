// The rig's subcommands: sim and replay.
#include "markcell/rig/commands.hpp"

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>

#include <nlohmann/json.hpp>

#include "markcell/common/log_escape.hpp"
#include "markcell/common/splitmix.hpp"
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
using Json = nlohmann::ordered_json;

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


// The paper's Table I through the real chain (docs/inspection.md "Table I"): `panels`
// panels, doors and fenders in turn, each at its own attitude at both stations (drawn
// from the seed), each rendered at the inspection station, measured by it, rendered at
// the marking station and inter-calibrated by the cell; the averages over the panels of
// each panel's max |e| and rms per axis, as the paper's.
int table_i_command(const CellConfig& config, std::uint64_t seed, int panels, double seconds, const std::string& scanner_file,
                    const std::string& out, const rig::ReplayOptions& base) {
  const std::string folder = rig::scenario_folder(config.file);
  const auto marking = vision::load_stereo_calibration(config.calibration.stereo);
  const auto scanner = vision::load_stereo_calibration(scanner_file);
  rig::ReplayOptions options = base;
  options.both_predictors = false;
  const bool progress = options.progress;
  options.progress = false;
  SplitMix rng{seed * 0x9E3779B97F4A7C15ULL + 0x7AB1E1ULL};
  Json rows = Json::array();
  Eigen::Vector3d sum_max = Eigen::Vector3d::Zero(), sum_rms = Eigen::Vector3d::Zero();
  std::vector<double> mf_errors;
  int counted = 0, measured = 0, mfs = 0;
  const auto rotation = [](double roll, double pitch, double yaw) {
    return (Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitX()) *
            Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitY()))
        .toRotationMatrix();
  };
  for (int i = 0; i < panels; ++i) {
    if (options.stop != nullptr && options.stop->load() != 0) return 128 + options.stop->load();
    rig::Scenario s = rig::find_scenario(i % 2 == 0 ? "paper-door" : "paper-fender", folder, seed + static_cast<std::uint64_t>(i));
    char name[32];
    std::snprintf(name, sizeof name, "panel-%02d", i + 1);
    s.name = std::string("table-i-") + name;
    // The panel's attitude at the inspection station (each draw a statement: the same
    // seed gives the same panels on every compiler, docs/determinism.md) ...
    const double sx = rng.uniform(-0.03, 0.03), sy = rng.uniform(-0.03, 0.03), sz = rng.uniform(-0.08, 0.08);
    const double s_roll = rng.uniform(-0.03, 0.03), s_pitch = rng.uniform(-0.05, 0.05), s_yaw = rng.uniform(-0.10, 0.10);
    s.X_SL_Panel.translation() += Eigen::Vector3d(sx, sy, sz);
    s.X_SL_Panel.linear() = s.X_SL_Panel.linear() * rotation(s_roll, s_pitch, s_yaw);
    // ... and on the line at the marking station (its fixture: turned a little on the line).
    const double m_roll = rng.uniform(-0.02, 0.02), m_pitch = rng.uniform(-0.03, 0.03), m_yaw = rng.uniform(-0.04, 0.04);
    s.path.X_CamR_Line.linear() = s.path.X_CamR_Line.linear() * rotation(m_roll, m_pitch, m_yaw);
    const rig::Panel panel = rig::configured_panel(config.panel_types, s.panel_type);
    const std::filesystem::path dir = std::filesystem::path(out) / name;
    const std::filesystem::path recording = dir / "recording";
    if (std::filesystem::exists(recording / "recording.yaml")) std::filesystem::remove_all(recording);
    rig::GenerateOptions g;
    g.max_duration = static_cast<Nanos>(seconds * 1e9);
    g.stop = options.stop;
    rig::RenderSettings render;
    render.threads = 2;
    rig::generate_recording(s, panel, recording.string(), marking, scanner, render, g);
    options.out_dir = dir.string();
    const rig::ReplayReport report = rig::replay_recording(config, recording.string(), options);
    (void)rig::write_report(report, config, dir.string());
    const control::Intercalibration& ic = report.runs.front().panel.intercalibration;
    const auto insp = rig::inspection_figures(recording.string());
    if (insp) {
      measured += insp->measured;
      mfs += insp->mfs;
      mf_errors.insert(mf_errors.end(), insp->errors_mm.begin(), insp->errors_mm.end());
    }
    Json row{{"panel", name}, {"panel_type", s.panel_type}, {"seed", s.seed}, {"inliers", ic.inliers},
             {"status", std::string(control::to_string(ic.status))}};
    if (ic.inliers > 0) {
      sum_max += ic.max_abs;
      sum_rms += ic.rms;
      ++counted;
      row["max_abs_cm"] = {ic.max_abs.x() * 100, ic.max_abs.y() * 100, ic.max_abs.z() * 100};
      row["rms_cm"] = {ic.rms.x() * 100, ic.rms.y() * 100, ic.rms.z() * 100};
    }
    if (insp) row["mf_error_mm"] = {{"median", insp->error_median_mm}, {"max", insp->error_max_mm}, {"measured", insp->measured}};
    rows.push_back(row);
    if (progress) {
      char line[200];
      std::snprintf(line, sizeof line, "[table-i] %s %-6s inter-cal max |e| %.2f %.2f %.2f cm, rms %.2f %.2f %.2f cm, %d MFs\n", name,
                    s.panel_type.c_str(), ic.max_abs.x() * 100, ic.max_abs.y() * 100, ic.max_abs.z() * 100, ic.rms.x() * 100,
                    ic.rms.y() * 100, ic.rms.z() * 100, ic.inliers);
      std::cerr << line;
    }
  }
  if (counted == 0) {
    std::cerr << "markcell sim table-i: no panel was inter-calibrated\n";
    return kExitRuntime;
  }
  const Eigen::Vector3d mean_max = sum_max / counted * 100, mean_rms = sum_rms / counted * 100;
  std::sort(mf_errors.begin(), mf_errors.end());
  const double mf_median = mf_errors.empty() ? 0.0 : mf_errors[mf_errors.size() / 2];
  const double mf_max = mf_errors.empty() ? 0.0 : mf_errors.back();
  Json doc{{"table_i", {{"panels", counted},
                        {"max_abs_cm", {mean_max.x(), mean_max.y(), mean_max.z()}},
                        {"rms_cm", {mean_rms.x(), mean_rms.y(), mean_rms.z()}}}},
           {"paper", {{"panels", 30}, {"max_abs_cm", {1.63, 0.89, 2.01}}, {"rms_cm", {0.86, 0.45, 1.16}}}},
           {"inspection", {{"macro_features", mfs}, {"measured", measured}, {"mf_error_mm", {{"median", mf_median}, {"max", mf_max}}}}},
           {"seed", seed},
           {"seconds_per_panel", seconds},
           {"panels", rows}};
  std::filesystem::create_directories(out);
  const std::string json = (std::filesystem::path(out) / "report.json").string();
  std::ofstream(json) << doc.dump(2) << "\n";
  char table[600];
  std::snprintf(table, sizeof table,
                "Table I through the real chain: %d panels (doors and fenders in turn), averages over the panels\n"
                "                       x      y      z    the paper (30 panels)\n"
                "  max |e|, cm       %5.2f  %5.2f  %5.2f    1.63  0.89  2.01\n"
                "  rms, cm           %5.2f  %5.2f  %5.2f    0.86  0.45  1.16\n"
                "inspection station: %d of %d MFs measured; error against the truth median %.2f / max %.2f mm\n",
                counted, mean_max.x(), mean_max.y(), mean_max.z(), mean_rms.x(), mean_rms.y(), mean_rms.z(), measured, mfs,
                mf_median, mf_max);
  std::cout << table << "wrote " << json << "\n";
  return counted == panels ? 0 : kExitRuntime;
}
}  // namespace

void add_rig_commands(CLI::App& app, Commands& out, const sigset_t& stop_signals, BoardCalibration calibrate_board) {
  struct Options {
    std::string rig_config = host::default_config_file(), rig_out, sim_scenario, replay_recording, scanner_file;
    std::uint64_t sim_seed = 1;
    double sim_seconds = 0, sim_fps = -1, radius_mm = 10;
    int table_panels = 30;
    bool one_predictor = false, quiet = false, no_arm = false, draw_arm = false;
    std::string rig_plc_script, rig_gpio_sim, rig_arm_serial_peer, replay_calibration;
  };
  const auto o = std::make_shared<Options>();
  auto* sim = app.add_subcommand("sim", "Generate a rig scenario and replay it through the cell in simulated time; score and report it");
  sim->add_option("SCENARIO", o->sim_scenario,
                  "A scenario file (FILE.yaml), or the name of one in scenarios/ beside the configuration: paper-door, "
                  "paper-fender, paper-curved, line-fast, occlusion-person, frame-drops, nine-defects, calibration-board; or "
                  "table-i: the paper's Table I over 30 panels through both stations")
      ->required();
  auto* seed_option = sim->add_option("--seed", o->sim_seed, "Scenario seed (noise, speed fluctuation, drops; default: the file's)");
  sim->add_option("--seconds", o->sim_seconds, "Shorten the scenario to this many seconds")->check(CLI::PositiveNumber);
  sim->add_option("--fps", o->sim_fps, "Frame rate of the generated recording (default: the scenario's, 30)")->check(CLI::PositiveNumber);
  sim->add_option("--panels", o->table_panels, "table-i: how many panels (default 30, as the paper's Table I)")
      ->check(CLI::Range(1, 1000));
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
    if (o->sim_scenario == "table-i")
      return table_i_command(*config, o->sim_seed, o->table_panels, o->sim_seconds > 0 ? o->sim_seconds : 3.0, scanner_file,
                             o->rig_out, options);
    return sim_command(*config, o->sim_scenario, seed_option->count() > 0, o->sim_seed, o->sim_seconds, o->sim_fps, scanner_file, o->rig_out, options,
                       calibrate_board);
  };
  out.push_back({sim, [run] { return run(false); }, true});
  out.push_back({replay, [run] { return run(true); }, true});
}

}  // namespace markcell::rig
