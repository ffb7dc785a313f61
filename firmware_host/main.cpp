// markcell: the controller of a robotic defect-marking cell. One executable; the
// subcommands are the cell (`run`), its tools and its benchmarks.
//
// Exit codes: 0 success; 1 runtime failure (a device, a fault at start-up); 2 invalid
// configuration or arguments (every problem is printed, each naming what to fix).
#include <signal.h>

#include <CLI/CLI.hpp>
#include <cstdio>
#include <iostream>
#include <string>

#include "markcell/common/check.hpp"
#include "markcell/common/log_escape.hpp"
#include "markcell/tools/base_calibration_run.hpp"
#include "markcell/tools/bench.hpp"
#include "markcell/tools/capacity.hpp"
#include "markcell/host/cell.hpp"
#include "markcell/host/config.hpp"
#include "markcell/tools/record.hpp"
#include "markcell/host/record_folder.hpp"
#include "markcell/sim/plc_script.hpp"
#include "markcell/host/results_file.hpp"
#include "markcell/host/service_loop.hpp"
#include "markcell/tools/select_mfs_window.hpp"
#include "markcell/rig/replay.hpp"
#include "markcell/host/stop_signal.hpp"
#include "markcell/rig/scenario.hpp"
#include "markcell/vision/calibration_io.hpp"
#include "markcell/vision/panel_tracker.hpp"
#include "markcell/vision/stereo_calibration.hpp"

#include <filesystem>
#include <fstream>
#include <optional>
#include <opencv2/imgcodecs.hpp>

namespace {

using namespace markcell;
using namespace markcell::host;


// SIGTERM and SIGINT, taken synchronously by the main thread with sigtimedwait. They are
// blocked first thing in main(): before any lane exists (every thread inherits the
// mask), and before start-up work, so a stop requested while starting is held and
// honoured, never lost (a background job of a shell even starts with SIGINT ignored).
sigset_t stop_signals() {
  sigset_t s;
  sigemptyset(&s);
  sigaddset(&s, SIGTERM);
  sigaddset(&s, SIGINT);
  return s;
}

int check_config_command(const std::string& file) {
  const auto errors = check_config(file, task_catalog());
  if (errors.empty()) {
    std::cout << file << ": valid\n";
    return 0;
  }
  for (const auto& e : errors) std::cerr << e.to_string() << "\n";
  std::cerr << errors.size() << " error(s) in " << file << "\n";
  return kExitConfig;
}

std::optional<CellConfig> load_or_report(const std::string& file) {
  try {
    return load_config(file, task_catalog());
  } catch (const ConfigInvalid& e) {
    for (const auto& err : e.errors()) std::cerr << err.to_string() << "\n";
    std::cerr << e.errors().size() << " error(s) in " << file << "\n";
    return std::nullopt;
  }
}

int run_command(const std::string& file, const std::string& clock_name, double seconds, const std::string& plc_script) {
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
  const sigset_t signals = stop_signals();
  const ClockKind clock = clock_name == "sim" ? ClockKind::kSimulated : ClockKind::kReal;
  Cell cell(config, clock);
  std::unique_ptr<ServiceLoop> service;
  try {
    service = std::make_unique<ServiceLoop>(config, cell, ServiceOptions{clock, seconds, std::move(plc_events)});
    service->start();
  } catch (const std::exception& e) {
    std::cerr << "markcell: start-up failed: " << e.what() << "\n";
    return kExitRuntime;
  }
  return service->run(signals);
}

int calibrate_stereo_command(const std::string& folder, const std::string& board_text, double square,
                             const std::string& out) {
  vision::BoardSpec board;
  char x = 0;
  if (std::sscanf(board_text.c_str(), "%d%c%d", &board.cols, &x, &board.rows) != 3 || x != 'x' || board.cols < 3 ||
      board.rows < 3) {
    std::cerr << "markcell calibrate-stereo: --board '" << board_text << "': expected COLSxROWS inner corners, e.g. 9x6\n";
    return kExitConfig;
  }
  board.square = square;
  std::vector<std::string> unpaired;
  std::vector<vision::StereoView> views;
  try {
    views = vision::read_stereo_views(folder, unpaired);
  } catch (const std::exception& e) {
    std::cerr << "markcell calibrate-stereo: " << folder << ": " << e.what() << "\n";
    return kExitConfig;
  }
  for (const auto& u : unpaired) std::cout << "unpaired image (skipped): " << u << "\n";
  vision::StereoCalibrationResult r;
  try {
    r = vision::calibrate_stereo(views, board);
  } catch (const vision::CalibrationError& e) {
    std::cerr << "markcell calibrate-stereo: " << e.what() << "\n";
    return kExitRuntime;
  }
  for (const auto& s : r.skipped) std::cout << "skipped view " << s << "\n";
  std::printf("views used: %zu\n", r.used.size());
  for (std::size_t i = 0; i < r.used.size(); ++i) std::printf("  %-24s reprojection RMS %.3f px\n", r.used[i].c_str(), r.view_errors[i]);
  std::printf("RMS reprojection error: %.3f px\n", r.rms);
  std::printf("mean epipolar error: %.3f px\n", r.epipolar_error);
  std::printf("baseline: %.4f m\n", r.calibration.baseline());
  std::printf("focal lengths: left %.2f %.2f px, right %.2f %.2f px\n", r.calibration.left.K(0, 0), r.calibration.left.K(1, 1),
              r.calibration.right.K(0, 0), r.calibration.right.K(1, 1));
  vision::save_stereo_calibration(out, r.calibration);
  std::cout << "wrote " << out << "\n";
  return 0;
}

// With the simulated arm: the rig's calibration-board scenario (the camera truly where
// the configured X_Base_CamR is not quite); otherwise the live arm and cameras. Writes
// `out` only when the fit is within the limits.
int calibrate_base_command(const CellConfig& config, const std::string& out, std::uint64_t seed, const std::string& images,
                           const std::string& report_dir) {
  const BaseCalibrationConfig& bc = config.base_calibration;
  if (bc.poses.size() < 6) {
    std::cerr << config.file << ": base_calibration.poses: " << bc.poses.size()
              << " poses configured, calibrate-base needs at least 6 (15 or more recommended)\n";
    return kExitConfig;
  }
  if (config.calibration.base.empty()) {
    std::cerr << config.file << ": calibration.base: calibrate-base needs the nominal X_Base_CamR (from the cell's drawing) "
              << "to tell the ends of the board apart\n";
    return kExitConfig;
  }
  const Eigen::Isometry3d nominal = vision::load_pose(config.calibration.base, "X_Base_CamR");
  const vision::StereoCalibration stereo = vision::load_stereo_calibration(config.calibration.stereo);
  const vision::StereoRig rig(stereo);
  std::unique_ptr<BaseCalibrationDevices> devices;
  std::optional<Eigen::Isometry3d> truth;
  if (config.arm.transport == ArmTransport::kSimulated) {
    const rig::Scenario scenario = rig::make_scenario("calibration-board", seed);
    truth = nominal * scenario.X_CamRnominal_CamR;
    devices = make_rig_board_devices(config, stereo, *truth, seed);
    std::cout << "calibrate-base on the rig's calibration-board scenario (seed " << seed
              << "): the simulated arm behind the CAN arm link, the board rendered where it holds it\n";
  } else {
    devices = make_live_devices(config);
  }
  const BaseCalibrationRun run = run_base_calibration(*devices, rig, nominal, bc, &std::cout);
  std::cout << base_calibration_table(run);
  if (truth)
    std::printf("against the rig's truth: %.2f mm, %.3f deg\n", translation_error(run.result.X_Base_CamR, *truth) * 1e3,
                rotation_error_deg(run.result.X_Base_CamR, *truth));
  if (!images.empty()) {
    std::filesystem::create_directories(images);
    for (std::size_t i = 0; i < run.left_images.size(); ++i) {
      char name[64];
      std::snprintf(name, sizeof name, "view%02zu_left.png", i + 1);
      cv::imwrite((std::filesystem::path(images) / name).string(), run.left_images[i]);
      std::snprintf(name, sizeof name, "view%02zu_right.png", i + 1);
      cv::imwrite((std::filesystem::path(images) / name).string(), run.right_images[i]);
    }
    std::cout << "wrote the " << run.left_images.size() << " stereo pairs to " << images << "\n";
  }
  if (!report_dir.empty()) {
    std::filesystem::create_directories(report_dir);
    const std::string report = (std::filesystem::path(report_dir) / "report.json").string();
    std::ofstream(report) << base_calibration_json(run, "calibration-board", seed, truth ? &*truth : nullptr);
    std::cout << "wrote " << report << "\n";
  }
  if (!run.result.ok()) {
    std::cerr << "markcell calibrate-base: refused (" << control::to_string(run.result.status) << "): " << run.result.reason
              << "; " << out << " not written\n";
    return kExitRuntime;
  }
  vision::save_pose(out, "X_Base_CamR", run.result.X_Base_CamR);
  std::cout << "wrote X_Base_CamR to " << out << "\n";
  return 0;
}


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

int sim_command(const CellConfig& config, const std::string& scenario_name, std::uint64_t seed, double seconds_limit,
                double fps, const std::string& scanner_file, const std::string& out, const rig::ReplayOptions& options) {
  rig::Scenario scenario;
  try {
    scenario = rig::make_scenario(scenario_name, seed);
  } catch (const std::invalid_argument& e) {
    std::cerr << "markcell sim: " << e.what() << "\n";
    return kExitConfig;
  }
  if (scenario.board_only) {
    const auto o = std::filesystem::path(out);
    return calibrate_base_command(config, (o / "base.yaml").string(), seed, (o / "board").string(), out);
  }
  const std::filesystem::path recording = std::filesystem::path(out) / "recording";
  // The folder is the rig's own output: a previous run's recording is replaced.
  if (std::filesystem::exists(recording / "recording.yaml")) std::filesystem::remove_all(recording);
  const auto marking = vision::load_stereo_calibration(config.calibration.stereo);
  const auto scanner = vision::load_stereo_calibration(scanner_file);
  rig::GenerateOptions g;
  if (seconds_limit > 0) g.max_duration = static_cast<Nanos>(seconds_limit * 1e9);
  g.fps = fps;
  g.stop = options.stop;
  if (options.progress) std::cerr << "markcell sim: rendering " << scenario_name << " into " << recording.string() << "\n";
  std::size_t frames = 0;
  try {
    frames = rig::generate_recording(scenario, recording.string(), marking, scanner, rig::RenderSettings{}, g);
  } catch (const rig::GenerationStopped& e) {
    std::cerr << "markcell sim: " << escape_log(e.what()) << "\n";
    return 128 + e.signal;
  }
  if (options.progress) std::cerr << "markcell sim: " << frames << " stereo frames; replaying through the cell\n";
  return replay_command(config, recording.string(), out, options);
}

int select_mfs_command(const std::string& image, const std::string& panel, const std::string& out,
                       const std::vector<std::string>& positions, const std::string& scenario, int snap, int search_x,
                       int search_y) {
  vision::PanelTypeModel model;
  if (!scenario.empty()) {
    // The rig's stand-in for the installation engineer: the scenario's panel rendered
    // square to the left camera, its MFs where the panel model has them.
    const auto s = rig::make_scenario(scenario, 1);
    const auto cal = vision::load_stereo_calibration("config/calibration/marking_stereo.yaml");
    cv::Mat reference;
    model = rig::reference_panel_type(s, cal, rig::RenderSettings{}, &reference);
    if (!image.empty()) cv::imwrite(image, reference);
  } else {
    const cv::Mat img = cv::imread(image, cv::IMREAD_GRAYSCALE);
    if (img.empty()) {
      std::cerr << "markcell select-mfs: --image " << image << ": cannot read it as an image\n";
      return kExitConfig;
    }
    std::vector<Eigen::Vector2d> px;
    if (positions.empty()) {  // the window: the engineer clicks them
      try {
        const auto chosen = select_mfs_window(img, "markcell select-mfs: " + panel, snap, std::cout);
        if (!chosen) {
          std::cerr << "markcell select-mfs: closed without saving; " << out << " not written\n";
          return kExitRuntime;
        }
        px = *chosen;
        snap = 0;  // already where the window showed them
      } catch (const std::exception& e) {
        std::cerr << "markcell select-mfs: " << e.what() << "\n";
        return kExitRuntime;
      }
    }
    for (const auto& p : positions) {
      double x = 0, y = 0;
      char comma = 0;
      if (std::sscanf(p.c_str(), "%lf%c%lf", &x, &comma, &y) != 3 || comma != ',') {
        std::cerr << "markcell select-mfs: --mf '" << p << "': expected X,Y in pixels\n";
        return kExitConfig;
      }
      px.emplace_back(x, y);
    }
    try {
      model = vision::make_panel_type(panel, img, px, snap, search_x, search_y);
    } catch (const std::exception& e) {
      std::cerr << "markcell select-mfs: " << e.what() << "\n";
      return kExitConfig;
    }
  }
  vision::save_panel_type(out, model);
  std::cout << "panel type '" << model.name << "': " << model.count << " macro-features\n";
  for (int i = 0; i < model.count; ++i)
    std::printf("  MF %2d at (%.2f, %.2f) px\n", i + 1, model.reference_px[static_cast<std::size_t>(i)].x(),
                model.reference_px[static_cast<std::size_t>(i)].y());
  std::cout << "wrote " << out << "\n";
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  const sigset_t signals = stop_signals();
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  CLI::App app{"markcell: controller of a robotic cell that tracks moving body panels and spray-marks their surface defects"};
  app.require_subcommand(1);
  app.set_help_all_flag("--help-all", "Show help for every subcommand");

  std::string check_file;
  auto* check = app.add_subcommand("check-config", "Validate a cell configuration; print every error and exit 2 if any");
  bool list_tasks = false;
  check->add_option("FILE", check_file, "Cell configuration (YAML)");
  check->add_flag("--tasks", list_tasks, "Print the tasks this build provides (a Markdown table) instead");

  auto* schema = app.add_subcommand("config-schema",
                                    "Print a JSON Schema of the cell configuration (for editors; from the parameters' declarations)");

  std::string run_file;
  std::string clock_name = "real";
  double run_seconds = 0;
  auto* run = app.add_subcommand("run", "Run the cell from its configuration until SIGTERM/SIGINT (or --seconds)");
  run->add_option("--config,-c", run_file, "Cell configuration (YAML)")->required();
  run->add_option("--clock", clock_name, "real: CLOCK_MONOTONIC; sim: simulated time, as fast as it computes")
      ->check(CLI::IsMember({"real", "sim"}));
  run->add_option("--seconds", run_seconds, "Stop after this long (0: until a signal; needed with --clock sim)")
      ->check(CLI::NonNegativeNumber);
  std::string run_plc_script;
  run->add_option("--plc-script", run_plc_script,
                  "Simulated GPIO only: drive the PLC inputs from FILE ('SECONDS LINE 0|1' per line, from the start)")
      ->check(CLI::ExistingFile);

  std::string cal_images, cal_board = "9x6", cal_out;
  double cal_square = 0.04;
  auto* calibrate = app.add_subcommand("calibrate-stereo", "Calibrate a stereo pair from chessboard image pairs (*left* / *right* names)");
  calibrate->add_option("--images", cal_images, "Folder of image pairs: NAMEleftX.png with NAMErightX.png")->required()->check(CLI::ExistingDirectory);
  calibrate->add_option("--board", cal_board, "Inner corners, COLSxROWS")->required();
  calibrate->add_option("--square", cal_square, "Square size in metres")->required()->check(CLI::PositiveNumber);
  calibrate->add_option("--out", cal_out, "Calibration file to write (OpenCV FileStorage YAML)")->required();

  std::string base_config = "config/cell.example.yaml", base_out, base_images;
  std::uint64_t base_seed = 1;
  auto* calibrate_base = app.add_subcommand(
      "calibrate-base", "Fit X_Base_CamR from a checkerboard on the gripper at the configured arm poses (simulated arm: the rig)");
  calibrate_base->add_option("--config,-c", base_config, "Cell configuration (YAML): devices, base_calibration section");
  calibrate_base->add_option("--out", base_out, "Calibration file to write X_Base_CamR to (only when within the limits)")->required();
  calibrate_base->add_option("--images", base_images, "Also save the stereo pairs taken into this folder");
  calibrate_base->add_option("--seed", base_seed, "The rig's calibration-board scenario seed (simulated arm only)");

  std::string record_config = "config/cell.example.yaml";
  RecordOptions record_options;
  auto* record = app.add_subcommand("record", "Write live stereo pairs from the configured Aravis cameras as a recording (vision/RECORDING.md)");
  record->add_option("--config,-c", record_config, "Cell configuration (devices.cameras: ids, size, rate, trigger; calibration.stereo)");
  record->add_option("--out,-o", record_options.out, "Recording folder to write (must not hold a recording)")->required();
  record->add_option("--frames,-n", record_options.frames, "Stereo pairs to record")->check(CLI::Range(1, 1000000));
  record->add_option("--panel", record_options.panel_type, "Panel type recorded (the manifest's panel_type)")->required();
  record->add_option("--left", record_options.left_id, "Left camera id (default: the configuration's)");
  record->add_option("--right", record_options.right_id, "Right camera id (default: the configuration's)");

  std::string capacity_config = "config/cell.example.yaml";
  std::vector<double> capacity_speeds{0.014, 0.15, 0.30, 0.60}, capacity_spacings{0.05, 0.10, 0.20, 0.30};
  double capacity_depth = 3.1, capacity_length = 1.0;
  auto* capacity = app.add_subcommand("capacity", "How many defects at spacing d one pass can mark at a line speed (the planner's model)");
  capacity->add_option("--config,-c", capacity_config, "Cell configuration (arm limits, settle, pulse, X_Base_CamR)");
  capacity->add_option("--speed", capacity_speeds, "Line speeds, m/s (repeat)")->check(CLI::PositiveNumber);
  capacity->add_option("--spacing", capacity_spacings, "Defect spacings along the line, m (repeat)")->check(CLI::PositiveNumber);
  capacity->add_option("--depth", capacity_depth, "Panel surface distance from CamR, m")->check(CLI::PositiveNumber);
  capacity->add_option("--length", capacity_length, "Panel length along the line, m (the row it carries)")->check(CLI::PositiveNumber);

  std::string rig_config = "config/cell.example.yaml", rig_out, sim_scenario, replay_recording, scanner_file;
  std::uint64_t sim_seed = 1;
  double sim_seconds = 0, sim_fps = -1, radius_mm = 10;
  bool one_predictor = false, quiet = false, no_arm = false;
  std::string rig_plc_script, rig_gpio_sim, rig_arm_serial_peer;
  auto* sim = app.add_subcommand("sim", "Generate a rig scenario and replay it through the cell in simulated time; score and report it");
  sim->add_option("SCENARIO", sim_scenario, "Scenario: paper-door, paper-fender, paper-curved, line-fast, occlusion-person, frame-drops, nine-defects, calibration-board")
      ->required();
  sim->add_option("--seed", sim_seed, "Scenario seed (noise, speed fluctuation, drops)");
  sim->add_option("--seconds", sim_seconds, "Shorten the scenario to this many seconds")->check(CLI::PositiveNumber);
  sim->add_option("--fps", sim_fps, "Frame rate of the generated recording (default: the scenario's, 30)")->check(CLI::PositiveNumber);
  sim->add_option("--scanner", scanner_file, "Inspection scanner calibration (default: calibration/inspection_stereo.yaml next to the config)");
  auto* replay = app.add_subcommand("replay", "Replay a recording through the cell in simulated time; score it when it has ground truth");
  replay->add_option("RECORDING", replay_recording, "Recording folder (vision/RECORDING.md)")->required()->check(CLI::ExistingDirectory);
  replay->add_option("--gpio-sim", rig_gpio_sim,
                     "Replay in real time on the configured real devices (libgpiod chip, CAN or serial arm link): the rig's "
                     "PLC and valve through this gpio-sim chip's sysfs folder, its simulated arm a node on the CAN interface "
                     "or on the serial line's other end (--arm-serial-peer)")
      ->check(CLI::ExistingDirectory);
  replay->add_option("--arm-serial-peer", rig_arm_serial_peer,
                     "With --gpio-sim and an arm on a serial line: the line's other end, where the rig's arm answers "
                     "(a second port on a null-modem cable, or socat's other pty)")
      ->needs("--gpio-sim")
      ->check(CLI::ExistingPath);
  for (auto* c : {sim, replay}) {
    c->add_option("--config,-c", rig_config, "Cell configuration (YAML)");
    c->add_option("--out,-o", rig_out, "Folder for report.json, the plots (and the generated recording)")->required();
    c->add_option("--radius-mm", radius_mm, "A spray within this of a defect's centre marks it")->check(CLI::PositiveNumber);
    c->add_flag("--one-predictor", one_predictor, "Replay with the configured predictor only (default: both, same frames)");
    c->add_option("--plc-script", rig_plc_script, "PLC inputs during the replay ('SECONDS LINE 0|1' per line, from the start): an e-stop, a panel leaving early")
        ->check(CLI::ExistingFile);
    c->add_flag("--no-arm", no_arm, "Do not draw the simulated arm into synthetic frames (it occludes macro-features in closed loop)");
    c->add_flag("--quiet,-q", quiet, "No progress lines");
  }

  std::string mf_image, mf_panel, mf_out, mf_scenario;
  std::vector<std::string> mf_positions;
  int mf_snap = 6, mf_search_x = 160, mf_search_y = 40;
  auto* select_mfs = app.add_subcommand("select-mfs", "Choose a panel type's macro-features on a reference image of the left camera");
  select_mfs->add_option("--image", mf_image, "Reference image of the left camera (with --from-scenario: where to write it)");
  select_mfs->add_option("--panel", mf_panel, "Panel type name (as in the configuration's panel_types)");
  select_mfs->add_option("--out", mf_out, "Panel type file to write")->required();
  select_mfs->add_option("--mf", mf_positions, "Headless: an MF at X,Y pixels (repeat, in order)");
  select_mfs->add_option("--snap", mf_snap, "Snap each MF to the strongest Shi-Tomasi corner within this many pixels")->check(CLI::Range(0, 20));
  select_mfs->add_option("--search-x", mf_search_x, "How far (px) a new panel may sit from the reference along x")->check(CLI::Range(0, 2000));
  select_mfs->add_option("--search-y", mf_search_y, "... and along y")->check(CLI::Range(0, 2000));
  select_mfs->add_option("--from-scenario", mf_scenario, "Take the MFs of a rig scenario's panel model instead (no image needed)");

  auto* bench = app.add_subcommand("bench", "Benchmarks");
  bench->require_subcommand(1);
  LoopBenchOptions loop_options;
  std::string bench_config = "config/cell.example.yaml";
  auto* loop = bench->add_subcommand("loop", "Control lane wake-up latency at 1 kHz vs cyclictest, same run");
  loop->add_option("--config,-c", bench_config, "Cell configuration (its control lane's core and priority)");
  loop->add_option("--seconds", loop_options.seconds, "Duration of each of the two measurements")->check(CLI::PositiveNumber);
  loop->add_option("--lane", loop_options.lane, "Which lane of the configuration to measure");
  loop->add_option("--json", loop_options.json_path, "Write the results as JSON to this file");
  loop->add_option("--cyclictest", loop_options.cyclictest, "The cyclictest executable");
  VisionBenchOptions vision_options;
  auto* vision_bench = bench->add_subcommand("vision", "The vision task per stereo pair vs cv::buildOpticalFlowPyramid (the floor), one thread");
  vision_bench->add_option("--config,-c", bench_config, "Cell configuration (calibration, panel types, tracker settings)");
  vision_bench->add_option("--frames", vision_options.frames, "Stereo pairs to time (rendered first)")->check(CLI::Range(10, 100000));
  vision_bench->add_option("--scenario", vision_options.scenario, "Rig scenario whose frames are rendered");
  vision_bench->add_option("--json", vision_options.json_path, "Write the results as JSON to this file");

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : kExitConfig;
  }

  // Only `run`, `sim` and `replay` take SIGTERM and SIGINT themselves (to stop in order,
  // outputs safe, reports marked); every other command is ended by them at once, as by
  // default (a recording cut short has no recording.yaml, so is no recording).
  if (!*run && !*sim && !*replay) pthread_sigmask(SIG_UNBLOCK, &signals, nullptr);

  try {
    if (*check) {
      if (list_tasks) {
        std::cout << task_table_markdown(task_catalog());
        return 0;
      }
      if (check_file.empty()) {
        std::cerr << "check-config: FILE is required (or --tasks)\n";
        return kExitConfig;
      }
      return check_config_command(check_file);
    }
    if (*schema) {
      std::cout << config_schema_json(task_catalog());
      return 0;
    }
    if (*calibrate) return calibrate_stereo_command(cal_images, cal_board, cal_square, cal_out);
    if (*record) {
      const auto config = load_or_report(record_config);
      if (!config) return kExitConfig;
      const RecordSummary r = record_stereo(*config, record_options, &std::cerr);
      std::printf("recorded %d stereo pairs into %s (%d waits without a pair, %llu unpaired frames dropped)\n", r.pairs,
                  record_options.out.c_str(), r.timeouts, static_cast<unsigned long long>(r.unpaired));
      return r.pairs == record_options.frames ? 0 : kExitRuntime;
    }
    if (*capacity) {
      const auto config = load_or_report(capacity_config);
      if (!config) return kExitConfig;
      const Eigen::Isometry3d X_Base_CamR =
          config->calibration.base.empty() ? Eigen::Isometry3d::Identity() : vision::load_pose(config->calibration.base, "X_Base_CamR");
      std::cout << capacity_table(*config, X_Base_CamR, capacity_speeds, capacity_spacings, capacity_depth, capacity_length);
      return 0;
    }
    if (*calibrate_base) {
      const auto config = load_or_report(base_config);
      if (!config) return kExitConfig;
      return calibrate_base_command(*config, base_out, base_seed, base_images, "");
    }
    if (*sim || *replay) {
      const auto config = load_or_report(rig_config);
      if (!config) return kExitConfig;
      // A stop asked for ends the run at its next step, with its report marked partial.
      StopSignalWatcher stop(signals);
      rig::ReplayOptions options;
      options.stop = &stop.signal();
      options.progress = !quiet;
      options.both_predictors = !one_predictor;
      options.draw_arm = !no_arm;
      options.gpio_sim = rig_gpio_sim;
      options.arm_serial_peer = rig_arm_serial_peer;
      if (!rig_plc_script.empty()) {
        try {
          options.plc_events = sim::load_plc_script(rig_plc_script);
        } catch (const std::exception& e) {
          std::cerr << "markcell: " << e.what() << "\n";
          return kExitConfig;
        }
      }
      options.radius = radius_mm / 1000.0;
      if (*replay) return replay_command(*config, replay_recording, rig_out, options);
      if (scanner_file.empty())
        scanner_file = (std::filesystem::path(rig_config).parent_path() / "calibration" / "inspection_stereo.yaml").string();
      return sim_command(*config, sim_scenario, sim_seed, sim_seconds, sim_fps, scanner_file, rig_out, options);
    }
    if (*select_mfs) {
      if (mf_scenario.empty() && (mf_image.empty() || mf_panel.empty())) {
        std::cerr << "markcell select-mfs: --image and --panel are needed (or --from-scenario)\n";
        return kExitConfig;
      }
      return select_mfs_command(mf_image, mf_panel, mf_out, mf_positions, mf_scenario, mf_snap, mf_search_x, mf_search_y);
    }
    if (*run) {
      if (clock_name == "sim" && run_seconds <= 0) {
        std::cerr << "markcell run: --clock sim needs --seconds (simulated time has no signal to stop it)\n";
        return kExitConfig;
      }
      return run_command(run_file, clock_name, run_seconds, run_plc_script);
    }
    if (*vision_bench) {
      const auto config = load_or_report(bench_config);
      if (!config) return kExitConfig;
      return bench_vision(*config, vision_options);
    }
    if (*loop) {
      const auto config = load_or_report(bench_config);
      if (!config) return kExitConfig;
      return bench_loop(*config, loop_options);
    }
  } catch (const std::exception& e) {
    std::cerr << "markcell: " << e.what() << "\n";
    return kExitRuntime;
  }
  return 0;
}
