// The tools' subcommands: calibrate-stereo, calibrate-base, record, capacity, select-mfs,
// bench loop, bench vision and bench render.
#include "markcell/tools/commands.hpp"

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <opencv2/imgcodecs.hpp>
#include <unistd.h>

#include "markcell/common/log_escape.hpp"
#include "markcell/host/calibration_state.hpp"
#include "markcell/host/install_paths.hpp"
#include "markcell/host/service_loop.hpp"
#include "markcell/rig/render.hpp"
#include "markcell/rig/panel.hpp"
#include "markcell/rig/scenario.hpp"
#include "markcell/tools/base_calibration_run.hpp"
#include "markcell/tools/bench.hpp"
#include "markcell/tools/capacity.hpp"
#include "markcell/tools/record.hpp"
#include "markcell/tools/panel_type_report.hpp"
#include "markcell/vision/calibration_io.hpp"
#include "markcell/vision/panel_tracker.hpp"
#include "markcell/vision/stereo_calibration.hpp"

namespace markcell::host {
namespace {

int calibrate_stereo_command(const std::string& folder, const std::string& board_text, double square,
                             const std::string& out, const std::string& left_id, const std::string& right_id) {
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
  std::vector<vision::CalibrationProvenance::View> view_rms;
  for (std::size_t i = 0; i < r.used.size(); ++i) view_rms.push_back({r.used[i], r.view_errors[i]});
  const vision::CalibrationProvenance provenance =
      make_provenance("calibrate-stereo", left_id, right_id, r.rms, "px", std::move(view_rms));
  try {
    write_calibration(out, [&](const std::string& file) { vision::save_stereo_calibration(file, r.calibration, &provenance); },
                      std::cout);
  } catch (const std::exception& e) {
    std::cerr << "markcell calibrate-stereo: " << e.what() << "\n";
    return kExitRuntime;
  }
  return 0;
}

// The ids the configuration names the cameras by, or the source when it names none.
std::string camera_name(const CameraConfig& cameras, const drivers::CameraUnitSettings& unit) {
  if (cameras.source == CameraSource::kAravis) return unit.id;
  return cameras.source == CameraSource::kSimulated ? "simulated" : "recording";
}

int calibrations_command(const CellConfig& config) {
  std::cout << calibration_listing("stereo", config.calibration.stereo);
  if (!config.calibration.base.empty()) std::cout << calibration_listing("base", config.calibration.base);
  return 0;
}

// The select-mfs window is markcell-select-mfs, beside this program (its own package, so
// the cell's does not pull highgui and Qt onto a headless cell computer): run in this
// process's place with the same choices.
int exec_select_mfs_window(const std::string& image, const std::string& panel, const std::string& out, int snap,
                           int search_x, int search_y) {
  std::error_code ec;
  const std::filesystem::path self = std::filesystem::read_symlink("/proc/self/exe", ec);
  const std::filesystem::path window = self.parent_path() / "markcell-select-mfs";
  if (ec || ::access(window.c_str(), X_OK) != 0) {
    std::cerr << "markcell select-mfs: the window is the program " << window.string()
              << ", which is not installed (Debian: the markcell-select-mfs package); "
              << "without it give the macro-features as --mf X,Y (3 or more)\n";
    return kExitRuntime;
  }
  const std::vector<std::string> args{window.string(), "--image", image, "--panel", panel, "--out", out,
                                      "--snap", std::to_string(snap), "--search-x", std::to_string(search_x),
                                      "--search-y", std::to_string(search_y)};
  std::vector<char*> argv;
  for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  std::cout.flush();
  std::fflush(stdout);
  ::execv(window.c_str(), argv.data());
  std::cerr << "markcell select-mfs: cannot run " << window.string() << ": " << std::strerror(errno) << "\n";
  return kExitRuntime;
}

int select_mfs_command(const std::string& image, const std::string& panel, const std::string& out,
                       const std::vector<std::string>& positions, const std::string& scenario, int snap, int search_x,
                       int search_y) {
  vision::PanelTypeModel model;
  std::vector<Eigen::Vector2d> clicked;  // the positions given on the command line, if any
  if (!scenario.empty()) {
    // The rig's stand-in for the installation engineer: the scenario's panel rendered
    // square to the left camera, its MFs where the panel model has them.
    const std::string config_dir = default_config_dir();
    const auto s = rig::find_scenario(scenario, config_dir + "/scenarios", 1);
    const auto cal = vision::load_stereo_calibration(default_calibration_dir() + "/marking_stereo.yaml");
    cv::Mat reference;
    const rig::Panel shipped = rig::load_panel(config_dir + "/panels/" + s.panel_type + ".yaml");
    model = rig::reference_panel_type(s, shipped, cal, rig::RenderSettings{}, &reference);
    if (!image.empty()) cv::imwrite(image, reference);
  } else if (positions.empty()) {  // the window, a program of its own: the engineer clicks them
    return exec_select_mfs_window(image, panel, out, snap, search_x, search_y);
  } else {
    const cv::Mat img = cv::imread(image, cv::IMREAD_GRAYSCALE);
    if (img.empty()) {
      std::cerr << "markcell select-mfs: --image " << image << ": cannot read it as an image\n";
      return kExitConfig;
    }
    std::vector<vision::MfPick> px;
    for (const auto& p : positions) {
      // X,Y or X,Y,KIND (corner, hole; without it, whichever is under the point; unseen: an
      // MF this station cannot measure, kept in the order: docs/inspection.md).
      double x = 0, y = 0;
      char comma = 0, rest[16] = {};
      const int n = std::sscanf(p.c_str(), "%lf%c%lf,%15s", &x, &comma, &y, rest);
      const std::string kind = rest;
      if (n < 3 || comma != ',' || (n == 4 && kind != "corner" && kind != "hole" && kind != "unseen") ||
          (n == 3 && p.find(',', p.find(',') + 1) != std::string::npos)) {
        std::cerr << "markcell select-mfs: --mf '" << escape_log(p) << "': expected X,Y or X,Y,corner or X,Y,hole or X,Y,unseen in pixels\n";
        return kExitConfig;
      }
      px.push_back({{x, y}, kind == "hole"     ? vision::MfKindRequest::kHole
                            : kind == "corner" ? vision::MfKindRequest::kCorner
                            : kind == "unseen" ? vision::MfKindRequest::kUnseen
                                               : vision::MfKindRequest::kAuto});
      clicked.emplace_back(x, y);
    }
    try {
      model = vision::make_panel_type(panel, img, px, snap, search_x, search_y);
    } catch (const std::exception& e) {
      std::cerr << "markcell select-mfs: " << e.what() << "\n";
      return kExitConfig;
    }
  }
  vision::save_panel_type(out, model);
  print_panel_type(model, clicked, out);
  return 0;
}

}  // namespace

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
    const rig::Scenario scenario = rig::find_scenario("calibration-board", rig::scenario_folder(config.file), seed);
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
  std::vector<vision::CalibrationProvenance::View> poses;
  for (const auto& p : run.result.poses)
    if (!p.outlier) poses.push_back({p.name, p.rms_norm * 1e3});
  const vision::CalibrationProvenance provenance =
      make_provenance("calibrate-base", camera_name(config.cameras, config.cameras.left),
                      camera_name(config.cameras, config.cameras.right), run.result.rms.norm() * 1e3, "mm", std::move(poses));
  try {
    write_calibration(out, [&](const std::string& file) { vision::save_pose(file, "X_Base_CamR", run.result.X_Base_CamR, &provenance); },
                      std::cout);
  } catch (const std::exception& e) {
    std::cerr << "markcell calibrate-base: " << e.what() << "\n";
    return kExitRuntime;
  }
  return 0;
}

void add_tool_commands(CLI::App& app, Commands& out) {
  struct Options {
    std::string cal_images, cal_board = "9x6", cal_out, cal_left_id, cal_right_id;
    std::string calibrations_config = default_config_file();
    double cal_square = 0.04;
    std::string base_config = default_config_file(), base_out, base_images;
    std::uint64_t base_seed = 1;
    std::string record_config = default_config_file();
    RecordOptions record;
    std::string capacity_config = default_config_file();
    std::vector<double> capacity_speeds{0.014, 0.15, 0.30, 0.60}, capacity_spacings{0.05, 0.10, 0.20, 0.30};
    double capacity_depth = 3.1, capacity_length = 1.0;
    std::string mf_image, mf_panel, mf_out, mf_scenario;
    std::vector<std::string> mf_positions;
    int mf_snap = 6, mf_search_x = 160, mf_search_y = 40;
    std::string bench_config = default_config_file();
    LoopBenchOptions loop;
    VisionBenchOptions vision;
    RenderBenchOptions render;
    BrokerBenchOptions broker;
  };
  const auto o = std::make_shared<Options>();

  auto* calibrate = app.add_subcommand("calibrate-stereo", "Calibrate a stereo pair from chessboard image pairs (*left* / *right* names)");
  calibrate->add_option("--images", o->cal_images, "Folder of image pairs: NAMEleftX.png with NAMErightX.png")->required()->check(CLI::ExistingDirectory);
  calibrate->add_option("--board", o->cal_board, "Inner corners, COLSxROWS")->required();
  calibrate->add_option("--square", o->cal_square, "Square size in metres")->required()->check(CLI::PositiveNumber);
  calibrate->add_option("--out", o->cal_out, "Calibration file to write (OpenCV FileStorage YAML); the one it replaces is kept in history/ beside it")->required();
  calibrate->add_option("--left-id", o->cal_left_id, "The left camera's id or serial, kept in the file (devices.cameras.left.id)");
  calibrate->add_option("--right-id", o->cal_right_id, "The right camera's id or serial, kept in the file");
  out.push_back({calibrate, [o] {
                   return calibrate_stereo_command(o->cal_images, o->cal_board, o->cal_square, o->cal_out, o->cal_left_id,
                                                   o->cal_right_id);
                 }});


  auto* calibrate_base = app.add_subcommand(
      "calibrate-base", "Fit X_Base_CamR from a checkerboard on the gripper at the configured arm poses (simulated arm: the rig)");
  calibrate_base->add_option("--config,-c", o->base_config, std::string("Cell configuration (YAML): devices, base_calibration section") + kDefaultConfigHelp);
  calibrate_base->add_option("--out", o->base_out, "Calibration file to write X_Base_CamR to (only when within the limits); the one it replaces is kept in history/ beside it")->required();
  calibrate_base->add_option("--images", o->base_images, "Also save the stereo pairs taken into this folder");
  calibrate_base->add_option("--seed", o->base_seed, "The rig's calibration-board scenario seed (simulated arm only)");
  out.push_back({calibrate_base, [o] {
                   return with_config(o->base_config, [&](const CellConfig& config) {
                     return calibrate_base_command(config, o->base_out, o->base_seed, o->base_images, "");
                   });
                 }});

  auto* calibrations = app.add_subcommand("calibrations", "List the calibrations in use: when and by what each was made, its fit, its earlier versions");
  calibrations->add_option("--config,-c", o->calibrations_config, std::string("Cell configuration (YAML): the calibration section") + kDefaultConfigHelp);
  out.push_back({calibrations, [o] { return with_config(o->calibrations_config, calibrations_command); }});

  auto* record = app.add_subcommand("record", "Write live stereo pairs from the configured Aravis cameras as a recording (vision/RECORDING.md)");
  record->add_option("--config,-c", o->record_config, std::string("Cell configuration (devices.cameras: ids, size, rate, trigger; calibration.stereo)") + kDefaultConfigHelp);
  record->add_option("--out,-o", o->record.out, "Recording folder to write (must not hold a recording)")->required();
  record->add_option("--frames,-n", o->record.frames, "Stereo pairs to record")->check(CLI::Range(1, 1000000));
  record->add_option("--panel", o->record.panel_type, "Panel type recorded (the manifest's panel_type)")->required();
  record->add_option("--left", o->record.left_id, "Left camera id (default: the configuration's)");
  record->add_option("--right", o->record.right_id, "Right camera id (default: the configuration's)");
  out.push_back({record, [o] {
                   return with_config(o->record_config, [&](const CellConfig& config) {
                     const RecordSummary r = record_stereo(config, o->record, &std::cerr);
                     std::printf("recorded %d stereo pairs into %s (%d waits without a pair, %llu unpaired frames dropped)\n", r.pairs,
                                 o->record.out.c_str(), r.timeouts, static_cast<unsigned long long>(r.unpaired));
                     return r.pairs == o->record.frames ? 0 : kExitRuntime;
                   });
                 }});

  auto* capacity = app.add_subcommand("capacity", "How many defects at spacing d one pass can mark at a line speed (the planner's model)");
  capacity->add_option("--config,-c", o->capacity_config, std::string("Cell configuration (arm limits, settle, pulse, X_Base_CamR)") + kDefaultConfigHelp);
  capacity->add_option("--speed", o->capacity_speeds, "Line speeds, m/s (repeat)")->check(CLI::PositiveNumber);
  capacity->add_option("--spacing", o->capacity_spacings, "Defect spacings along the line, m (repeat)")->check(CLI::PositiveNumber);
  capacity->add_option("--depth", o->capacity_depth, "Panel surface distance from CamR, m")->check(CLI::PositiveNumber);
  capacity->add_option("--length", o->capacity_length, "Panel length along the line, m (the row it carries)")->check(CLI::PositiveNumber);
  out.push_back({capacity, [o] {
                   return with_config(o->capacity_config, [&](const CellConfig& config) {
                     const Eigen::Isometry3d X_Base_CamR = config.calibration.base.empty()
                                                               ? Eigen::Isometry3d::Identity()
                                                               : vision::load_pose(config.calibration.base, "X_Base_CamR");
                     std::cout << capacity_table(config, X_Base_CamR, o->capacity_speeds, o->capacity_spacings, o->capacity_depth,
                                                 o->capacity_length);
                     return 0;
                   });
                 }});

  auto* select_mfs = app.add_subcommand("select-mfs", "Choose a panel type's macro-features on a reference image of the left camera");
  select_mfs->add_option("--image", o->mf_image, "Reference image of the left camera (with --from-scenario: where to write it)");
  select_mfs->add_option("--panel", o->mf_panel, "Panel type name (as in the configuration's panel_types)");
  select_mfs->add_option("--out", o->mf_out, "Panel type file to write")->required();
  select_mfs->add_option("--mf", o->mf_positions,
                         "Headless: an MF at X,Y pixels, or X,Y,corner / X,Y,hole for that kind, X,Y,unseen for one this station "
                         "cannot measure (repeat, in order)");
  select_mfs->add_option("--snap", o->mf_snap, "Snap each MF to the strongest Shi-Tomasi corner within this many pixels; an MF that would end farther from its click is refused")->check(CLI::Range(0, 20));
  select_mfs->add_option("--search-x", o->mf_search_x, "How far (px) a new panel may sit from the reference along x")->check(CLI::Range(0, 2000));
  select_mfs->add_option("--search-y", o->mf_search_y, "... and along y")->check(CLI::Range(0, 2000));
  select_mfs->add_option("--from-scenario", o->mf_scenario, "Take the MFs of a rig scenario's panel model instead (no image needed)");
  out.push_back({select_mfs, [o] {
                   if (o->mf_scenario.empty() && (o->mf_image.empty() || o->mf_panel.empty())) {
                     std::cerr << "markcell select-mfs: --image and --panel are needed (or --from-scenario)\n";
                     return kExitConfig;
                   }
                   return select_mfs_command(o->mf_image, o->mf_panel, o->mf_out, o->mf_positions, o->mf_scenario, o->mf_snap,
                                             o->mf_search_x, o->mf_search_y);
                 }});

  auto* bench = app.add_subcommand("bench", "Benchmarks");
  bench->require_subcommand(1);
  auto* loop = bench->add_subcommand("loop", "Control lane wake-up latency at 1 kHz vs cyclictest, same run");
  loop->add_option("--config,-c", o->bench_config, std::string("Cell configuration (its control lane's core and priority)") + kDefaultConfigHelp);
  loop->add_option("--seconds", o->loop.seconds, "Duration of each of the two measurements")->check(CLI::PositiveNumber);
  loop->add_option("--lane", o->loop.lane, "Which lane of the configuration to measure");
  loop->add_option("--json", o->loop.json_path, "Write the results as JSON to this file");
  loop->add_option("--cyclictest", o->loop.cyclictest, "The cyclictest executable");
  out.push_back({loop, [o] {
                   return with_config(o->bench_config, [&](const CellConfig& config) {
                     return bench_loop(config, o->loop);
                   });
                 }});
  auto* vision_bench = bench->add_subcommand("vision", "The vision task per stereo pair vs cv::buildOpticalFlowPyramid (the floor), one thread");
  vision_bench->add_option("--config,-c", o->bench_config, std::string("Cell configuration (calibration, panel types, tracker settings)") + kDefaultConfigHelp);
  vision_bench->add_option("--frames", o->vision.frames, "Stereo pairs to time (rendered first)")->check(CLI::Range(10, 100000));
  vision_bench->add_option("--scenario", o->vision.scenario, "Rig scenario whose frames are rendered");
  vision_bench->add_option("--json", o->vision.json_path, "Write the results as JSON to this file");
  out.push_back({vision_bench, [o] {
                   return with_config(o->bench_config, [&](const CellConfig& config) {
                     return bench_vision(config, o->vision);
                   });
                 }});
  auto* render_bench = bench->add_subcommand("render", "The rig's renderer per stereo pair, shipped door vs a 200k-triangle door, one core");
  render_bench->add_option("--config,-c", o->bench_config, std::string("Cell configuration (calibration, panel types)") + kDefaultConfigHelp);
  render_bench->add_option("--pairs", o->render.pairs, "Stereo pairs per mesh")->check(CLI::Range(5, 10000));
  render_bench->add_option("--json", o->render.json_path, "Write the results as JSON to this file");
  out.push_back({render_bench, [o] {
                   return with_config(o->bench_config, [&](const CellConfig& config) {
                     return bench_render(config, o->render);
                   });
                 }});
  auto* broker_bench = bench->add_subcommand(
      "broker", "The stations' broker under load: lines of 1 inspection + M marking stations as processes, one mosquitto");
  broker_bench->add_option("--config,-c", o->bench_config, std::string("Cell configuration (its panel types)") + kDefaultConfigHelp);
  broker_bench->add_option("--records", o->broker.records, "Records in all")->check(CLI::Range(1, 1'000'000));
  broker_bench->add_option("--lines", o->broker.lines, "Lines")->check(CLI::Range(1, 20));
  broker_bench->add_option("--marking", o->broker.marking_per_line, "Marking stations per line")->check(CLI::Range(1, 10));
  broker_bench->add_option("--rate", o->broker.rate_per_station, "Records a second from each inspection station")
      ->check(CLI::Range(1.0, 100000.0));
  broker_bench->add_option("--json", o->broker.json_path, "Write the results as JSON to this file");
  broker_bench->add_option("--work", o->broker.work, "The bench's folder (default: a fresh one under /tmp)");
  broker_bench->add_flag("--keep", o->broker.keep, "Keep the bench's folder (logs, results files)");
  for (auto* opt : {broker_bench->add_option("--station-role", o->broker.station_role),
                    broker_bench->add_option("--station-line", o->broker.station_line),
                    broker_bench->add_option("--station-name", o->broker.station_name),
                    broker_bench->add_option("--port", o->broker.port),
                    broker_bench->add_option("--station-count", o->broker.station_count)})
    opt->group("");  // (the bench's own station processes)
  out.push_back({broker_bench,
                 [o] {
                   o->broker.config_file = o->bench_config;
                   return with_config(o->bench_config, [&](const CellConfig& config) {
                     return bench_broker(config, o->broker);
                   });
                 },
                 true});
}

}  // namespace markcell::host
