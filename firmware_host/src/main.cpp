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
#include "markcell/host/bench.hpp"
#include "markcell/host/cell.hpp"
#include "markcell/host/config.hpp"
#include "markcell/vision/stereo_calibration.hpp"

namespace {

using namespace markcell;
using namespace markcell::host;

constexpr int kExitRuntime = 1;
constexpr int kExitConfig = 2;

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

void print_faults(control::FaultLog& log) {
  control::Fault f;
  int shown = 0;
  while (log.pop(f)) {
    if (shown++ == 0) std::cout << "\nfaults:\n";
    std::printf("  t=%.6f s  %-14s %-16s %s\n", to_seconds(f.time), std::string(control::to_string(f.code)).c_str(),
                f.source.c_str(), f.detail.c_str());
  }
  if (log.dropped() > 0) std::printf("  (%llu faults dropped: the log was full)\n", static_cast<unsigned long long>(log.dropped()));
}

int run_command(const std::string& file, const std::string& clock_name, double seconds) {
  CellConfig config;
  try {
    config = load_config(file, task_catalog());
  } catch (const ConfigInvalid& e) {
    for (const auto& err : e.errors()) std::cerr << err.to_string() << "\n";
    return kExitConfig;
  }
  const bool simulated = clock_name == "sim";
  sigset_t signals = stop_signals();

  Cell cell(config, simulated ? ClockKind::kSimulated : ClockKind::kReal);
  try {
    cell.start();
  } catch (const std::exception& e) {
    std::cerr << "markcell: start-up failed: " << e.what() << "\n";
    return kExitRuntime;
  }
  for (const auto& w : cell.privilege_warnings()) std::cerr << "<4>markcell: warning: " << w << "\n";
  std::fprintf(stderr, "<6>markcell: cell '%s' running on the %s clock", config.name.c_str(), simulated ? "simulated" : "real");
  if (seconds > 0) std::fprintf(stderr, " for %g s", seconds);
  std::fprintf(stderr, "\n");

  std::string stop_reason = "duration elapsed";
  if (simulated) {
    const Nanos end = cell.sim_clock()->global_now() + static_cast<Nanos>(seconds * 1e9);
    if (cell.sim_clock()->run_until(end) == control::SimClock::RunResult::kWedged) stop_reason = "simulation wedged";
  } else {
    const Nanos end = seconds > 0 ? monotonic_now() + static_cast<Nanos>(seconds * 1e9) : 0;
    for (;;) {
      // Bounded wait: wakes at once on a signal, at least every second otherwise.
      Nanos wait = seconds > 0 ? end - monotonic_now() : kNanosPerSecond;
      if (wait <= 0) break;
      if (wait > kNanosPerSecond) wait = kNanosPerSecond;
      const timespec ts = to_timespec(wait);
      const int sig = sigtimedwait(&signals, nullptr, &ts);
      if (sig == SIGTERM || sig == SIGINT) {
        stop_reason = sig == SIGTERM ? "SIGTERM" : "SIGINT";
        break;
      }
    }
  }
  cell.shutdown(control::FaultCode::kShutdown, "markcell", stop_reason);
  std::fprintf(stderr, "<6>markcell: stopped (%s)\n", stop_reason.c_str());
  std::cout << "\ntiming report (" << (simulated ? "simulated" : "real") << " clock):\n"
            << cell.executive().timing_report();
  print_faults(cell.faults());
  return 0;
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

}  // namespace

int main(int argc, char** argv) {
  const sigset_t signals = stop_signals();
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  CLI::App app{"markcell: controller of a robotic cell that tracks moving body panels and spray-marks their surface defects"};
  app.require_subcommand(1);
  app.set_help_all_flag("--help-all", "Show help for every subcommand");

  std::string check_file;
  auto* check = app.add_subcommand("check-config", "Validate a cell configuration; print every error and exit 2 if any");
  check->add_option("FILE", check_file, "Cell configuration (YAML)")->required();

  std::string run_file;
  std::string clock_name = "real";
  double run_seconds = 0;
  auto* run = app.add_subcommand("run", "Run the cell from its configuration until SIGTERM/SIGINT (or --seconds)");
  run->add_option("--config,-c", run_file, "Cell configuration (YAML)")->required();
  run->add_option("--clock", clock_name, "real: CLOCK_MONOTONIC; sim: simulated time, as fast as it computes")
      ->check(CLI::IsMember({"real", "sim"}));
  run->add_option("--seconds", run_seconds, "Stop after this long (0: until a signal; needed with --clock sim)")
      ->check(CLI::NonNegativeNumber);

  std::string cal_images, cal_board = "9x6", cal_out;
  double cal_square = 0.04;
  auto* calibrate = app.add_subcommand("calibrate-stereo", "Calibrate a stereo pair from chessboard image pairs (*left* / *right* names)");
  calibrate->add_option("--images", cal_images, "Folder of image pairs: NAMEleftX.png with NAMErightX.png")->required()->check(CLI::ExistingDirectory);
  calibrate->add_option("--board", cal_board, "Inner corners, COLSxROWS")->required();
  calibrate->add_option("--square", cal_square, "Square size in metres")->required()->check(CLI::PositiveNumber);
  calibrate->add_option("--out", cal_out, "Calibration file to write (OpenCV FileStorage YAML)")->required();

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

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : kExitConfig;
  }

  try {
    if (*check) return check_config_command(check_file);
    if (*calibrate) return calibrate_stereo_command(cal_images, cal_board, cal_square, cal_out);
    if (*run) {
      if (clock_name == "sim" && run_seconds <= 0) {
        std::cerr << "markcell run: --clock sim needs --seconds (simulated time has no signal to stop it)\n";
        return kExitConfig;
      }
      return run_command(run_file, clock_name, run_seconds);
    }
    if (*loop) {
      CellConfig config;
      try {
        config = load_config(bench_config, task_catalog());
      } catch (const ConfigInvalid& e) {
        for (const auto& err : e.errors()) std::cerr << err.to_string() << "\n";
        return kExitConfig;
      }
      return bench_loop(config, loop_options);
    }
  } catch (const std::exception& e) {
    std::cerr << "markcell: " << e.what() << "\n";
    return kExitRuntime;
  }
  return 0;
}
