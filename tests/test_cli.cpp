// The markcell executable as a user meets it: help, check-config, run.
#include <algorithm>
#include <catch2/catch.hpp>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>

#include "markcell/common/file_history.hpp"
#include "markcell/vision/calibration_io.hpp"
#include "markcell/vision/panel_tracker.hpp"

#include "test_files.hpp"

using markcell::test::run_command;
using markcell::test::source_path;

namespace {
const std::string kMarkcell = MARKCELL_BINARY;
}

TEST_CASE("every subcommand has --help") {
  for (const char* sub : {"check-config", "inspect", "run", "sim", "replay", "select-mfs", "calibrate-stereo", "calibrate-base", "calibrations", "capacity", "record", "bench", "bench loop", "bench vision"}) {
    const auto r = run_command(kMarkcell + " " + sub + " --help");
    INFO(sub << ": " << r.output);
    CHECK(r.exit_code == 0);
    CHECK(r.output.find("Usage:") != std::string::npos);
  }
  const auto none = run_command(kMarkcell);
  CHECK(none.exit_code == 2);
}

TEST_CASE("markcell --version: the project's version, the commit built from, the build type") {
  const auto r = run_command(kMarkcell + " --version");
  INFO(r.output);
  CHECK(r.exit_code == 0);
  // The references: CMakeLists.txt's project() line and git itself.
  const std::string lists = markcell::test::read_file(source_path("CMakeLists.txt"));
  const auto at = lists.find("project(markcell VERSION ");
  REQUIRE(at != std::string::npos);
  const std::string version = lists.substr(at + 25, lists.find(' ', at + 25) - at - 25);
  CHECK(r.output.rfind("markcell " + version + "\n", 0) == 0);
  const auto git = run_command("git -C " + source_path("") + " rev-parse --short=12 HEAD 2>/dev/null");
  if (git.exit_code == 0 && git.output.size() > 1)  // a checkout (a tarball says "unknown")
    CHECK(r.output.find("commit " + git.output.substr(0, git.output.size() - 1)) != std::string::npos);
  CHECK(r.output.find(std::string(", build type ") + MARKCELL_TEST_BUILD_TYPE + ", ") != std::string::npos);
}

TEST_CASE("an unknown subcommand: the one meant, or the known ones, and exit 2") {
  struct Case {
    const char* args;
    const char* said;
  };
  for (const Case c : {Case{"chek-config", "markcell: unknown subcommand 'chek-config'; did you mean check-config?"},
                       Case{"repaly --config x", "markcell: unknown subcommand 'repaly'; did you mean replay?"},
                       Case{"sel", "markcell: unknown subcommand 'sel'; did you mean select-mfs?"},
                       Case{"bench rendr", "markcell: unknown subcommand 'bench rendr'; did you mean bench render?"},
                       Case{"frobnicate", "markcell: unknown subcommand 'frobnicate' (known: check-config, config-schema, run, publish-record, inspect, "
                                          "calibrate-stereo, calibrate-base, calibrations, record, capacity, select-mfs, bench, sim, "
                                          "replay)"},
                       Case{"bench x", "markcell: unknown subcommand 'bench x' (known: loop, vision, render, broker)"}}) {
    const auto r = run_command(kMarkcell + " " + c.args);
    INFO(c.args << ": " << r.output);
    CHECK(r.exit_code == 2);
    CHECK(r.output == std::string(c.said) + "\n");
  }
}

TEST_CASE("calibrations: calibrate-base keeps the one it replaces, calibrations and check-config name the one in use") {
  // A copy of the example configuration, whose calibrations are the test's to replace.
  markcell::test::TempDir dir;
  const auto config_dir = dir.path() / "config";
  std::filesystem::copy(source_path("config"), config_dir, std::filesystem::copy_options::recursive);
  const std::string config = (config_dir / "cell.example.yaml").string();
  const std::string base = (config_dir / "calibration" / "base.yaml").string();
  const std::string shipped = markcell::test::read_file(base);
  // The shipped calibrations have no provenance: said, with the file's date.
  const auto before = run_command(kMarkcell + " calibrations -c " + config);
  INFO(before.output);
  REQUIRE(before.exit_code == 0);
  CHECK(before.output.find("base: " + base + " (in use)\n  no provenance (not written by markcell's calibrate tools), modified ") !=
        std::string::npos);
  CHECK(before.output.find("  no earlier versions in " + (config_dir / "calibration" / "history").string()) != std::string::npos);

  const auto first = run_command(kMarkcell + " calibrate-base -c " + config + " --out " + base);
  INFO(first.output);
  REQUIRE(first.exit_code == 0);
  const auto kept = markcell::file_history(base);
  REQUIRE(kept.size() == 1);
  CHECK(markcell::test::read_file(kept[0].string()) == shipped);  // the shipped one, byte for byte
  CHECK(first.output.find("kept the previous base.yaml as " + kept[0].string() + "\nwrote " + base + "\n") != std::string::npos);

  const auto listed = run_command(kMarkcell + " calibrations -c " + config);
  INFO(listed.output);
  REQUIRE(listed.exit_code == 0);
  const auto provenance = markcell::vision::load_provenance(base);
  REQUIRE(provenance);
  char rms[96];
  std::snprintf(rms, sizeof rms, "calibrate-base), RMS %.3f mm over 15 arm poses, cameras simulated and simulated\n", provenance->rms);
  CHECK(listed.output.find("base: " + base + " (in use)\n  calibrated " + provenance->calibrated_utc + " by markcell 0.1.0 (commit ") !=
        std::string::npos);
  CHECK(listed.output.find(rms) != std::string::npos);
  CHECK(listed.output.find("    pose 1  RMS ") != std::string::npos);
  CHECK(listed.output.find("  1 earlier version(s) in " + (config_dir / "calibration" / "history").string() + ", newest first:\n    " +
                           kept[0].filename().string() + ": no provenance") != std::string::npos);
  // check-config names the calibrations it would run with.
  const auto checked = run_command(kMarkcell + " check-config " + config);
  INFO(checked.output);
  CHECK(checked.exit_code == 0);
  CHECK(checked.output.find("base calibration " + base + ": calibrated " + provenance->calibrated_utc) != std::string::npos);
  CHECK(checked.output.find("stereo calibration " + (config_dir / "calibration" / "marking_stereo.yaml").string() +
                            ": no provenance") != std::string::npos);
}

TEST_CASE("check-config: valid file exits 0, a bad one prints every error and exits 2") {
  const auto ok = run_command(kMarkcell + " check-config " + source_path("config/cell.example.yaml"));
  CHECK(ok.exit_code == 0);
  CHECK(ok.output.find(": valid") != std::string::npos);

  markcell::test::TempDir dir;
  std::string text = markcell::test::read_file(source_path("config/cell.example.yaml"));
  text.replace(text.find("base_tick_us: 1000"), 18, "base_tick_us: 0");
  text.replace(text.find("baud: 115200"), 12, "baud: 115201");
  const std::string file = dir.write("cell.yaml", text);
  for (const char* cal : {"calibration/marking_stereo.yaml", "calibration/base.yaml", "panels/door.yaml", "panels/fender.yaml"})
    dir.write(cal, markcell::test::read_file(source_path(std::string("config/") + cal)));
  const auto bad = run_command(kMarkcell + " check-config " + file);
  INFO(bad.output);
  CHECK(bad.exit_code == 2);
  // Its line: counted in the file, as an editor shows it.
  const auto tick_line = 1 + std::count(text.begin(), text.begin() + static_cast<std::ptrdiff_t>(text.find("base_tick_us: 0")), '\n');
  CHECK(bad.output.find(file + ":" + std::to_string(tick_line) + ":17: executive.base_tick_us: expected an integer in [50, 1000000], got 0") !=
        std::string::npos);
  CHECK(bad.output.find("devices.arm.serial.baud: baud 115201 is not a termios rate") != std::string::npos);
  CHECK(bad.output.find("2 error(s) in " + file) != std::string::npos);
}

TEST_CASE("run on the simulated clock prints the timing report") {
  const auto r = run_command(kMarkcell + " run --config " + source_path("config/cell.example.yaml") +
                             " --clock sim --seconds 2");
  INFO(r.output);
  CHECK(r.exit_code == 0);
  CHECK(r.output.find("timing report (simulated clock)") != std::string::npos);
  // plc_io at 1 kHz for 2 simulated seconds: releases at 0..2000 ms inclusive.
  CHECK(r.output.find("plc_io             control        1.000        200      2001") != std::string::npos);
  CHECK(r.output.find("shutdown       markcell         duration elapsed") != std::string::npos);
}

TEST_CASE("run stops cleanly on SIGTERM and on SIGINT, outputs safe, report printed") {
  // On the simulated clock too: a day of simulated time is never waited out.
  for (const std::string clock : {"real", "simulated"}) {
    const std::string args = clock == "real" ? "" : " --clock sim --seconds 86400";
    for (const char* sig : {"TERM", "INT"}) {
      // The shell starts the cell, waits (up to 30 s) until it says it runs, signals it,
      // and reports its exit status.
      markcell::test::TempDir dir;
      const std::string log = (dir.path() / "log").string();
      const auto r = run_command("( " + kMarkcell + " run --config " + source_path("config/cell.example.yaml") + args + " > " +
                                 log + " 2>&1 & pid=$!; for i in $(seq 300); do grep -q 'running on the " + clock + " clock' " +
                                 log + " && break; sleep 0.1; done; kill -" + sig + " $pid; wait $pid; echo \"exit=$?\"; cat " +
                                 log + " )");
      INFO(clock << " clock, SIG" << sig << ": " << r.output);
      CHECK(r.output.find("exit=0") != std::string::npos);
      CHECK(r.output.find(std::string("stopped (SIG") + sig + ")") != std::string::npos);
      CHECK(r.output.find("timing report (" + clock + " clock)") != std::string::npos);
      CHECK(r.output.find(std::string("shutdown       markcell         SIG") + sig) != std::string::npos);
    }
  }
}

TEST_CASE("sim and replay stop on SIGTERM and SIGINT at their next step, their partial output marked") {
  markcell::test::TempDir dir;
  const std::string cd = "cd " + source_path("") + " && ";
  // The shell waits (up to 60 s) for LINE in the log, signals, and reports the exit status
  // and the milliseconds from the signal to the exit.
  const auto signalled = [&](const std::string& command, const std::string& line, const char* sig) {
    const std::string log = (dir.path() / "log").string();
    return run_command("( " + cd + command + " > " + log + " 2>&1 & pid=$!; for i in $(seq 600); do grep -q '" + line + "' " + log +
                       " && break; sleep 0.1; done; t0=$(date +%s%N); kill -" + sig + " $pid; wait $pid; rc=$?; t1=$(date +%s%N); "
                       "echo \"exit=$rc ms=$(( (t1 - t0) / 1000000 ))\"; cat " + log + " )");
  };
  const auto stop_ms = [](const std::string& output) {
    const auto at = output.find(" ms=");
    return at == std::string::npos ? -1 : std::stoi(output.substr(at + 4));
  };
  // Rendering: stopped before the next frame; no recording.yaml, so the folder is no
  // recording (a replay of it says so), and nothing is replayed.
  const auto render = signalled(kMarkcell + " sim paper-door --out " + (dir.path() / "a").string(), "rendering paper-door", "TERM");
  INFO(render.output);
  CHECK(render.output.find("exit=143 ") != std::string::npos);
  CHECK(render.output.find("/recording: rendering stopped by SIGTERM after ") != std::string::npos);
  CHECK(render.output.find("the folder is not a recording (no recording.yaml)") != std::string::npos);
  CHECK(render.output.find("not stopped in time") == std::string::npos);  // the backstop did not act
  CHECK(!std::filesystem::exists(dir.path() / "a" / "recording" / "recording.yaml"));
  CHECK(!std::filesystem::exists(dir.path() / "a" / "report.json"));
  const int render_ms = stop_ms(render.output);
  CHECK(render_ms >= 0);
  CHECK(render_ms < 5000);  // at the next frame (about 0.1 s here, measured; 10 s is the backstop)

  // Replaying: stopped within 100 ms of simulated time; report.json written, marked
  // stopped, and the other predictor's run not begun.
  const auto whole = run_command(cd + kMarkcell + " sim paper-door --seconds 2 --one-predictor -q --out " + (dir.path() / "b").string());
  REQUIRE(whole.exit_code == 0);
  const auto replay = signalled(kMarkcell + " replay " + (dir.path() / "b" / "recording").string() + " --out " +
                                    (dir.path() / "r").string(), "\\[kalman\\] t=", "INT");
  INFO(replay.output);
  CHECK(replay.output.find("exit=130 ") != std::string::npos);
  CHECK(replay.output.find("STOPPED by SIGINT at t=") != std::string::npos);
  CHECK(replay.output.find("not stopped in time") == std::string::npos);
  const std::string report = markcell::test::read_file((dir.path() / "r" / "report.json").string());
  CHECK(report.find("\"stopped\": \"SIGINT at t=") != std::string::npos);
  CHECK(report.find("\"two-frame\": {") == std::string::npos);
  const int replay_ms = stop_ms(replay.output);
  CHECK(replay_ms >= 0);
  CHECK(replay_ms < 5000);  // report and plots written meanwhile
}

TEST_CASE("sim and replay: an unknown scenario and a folder without a recording are errors that say what to fix") {
  markcell::test::TempDir dir;
  const auto unknown = run_command("cd " + source_path("") + " && " + kMarkcell + " sim paper-dor --out " + dir.path().string());
  CHECK(unknown.exit_code == 2);
  CHECK(unknown.output.find("unknown scenario 'paper-dor': no config/scenarios/paper-dor.yaml (known: calibration-board, "
                            "frame-drops, line-fast, nine-defects, occlusion-person, paper-curved, paper-door, "
                            "paper-fender)") != std::string::npos);
  // A scenario file of one's own, by its path: its name is the file's stem, its defects
  // are its own; an error in it names the file, the line and the key, and nothing runs.
  std::string door = markcell::test::read_file(source_path("config/scenarios/paper-door.yaml"));
  const std::string three = "  - {id: 3, x: 0.38, y: -0.25, radius: 0.012}\n";
  REQUIRE(door.find(three) != std::string::npos);
  door.erase(door.find(three), three.size());
  const std::string mine = dir.write("two-dings.yaml", door);
  const auto ran = run_command("cd " + source_path("") + " && " + kMarkcell + " sim " + mine +
                               " --seconds 1 --fps 5 --one-predictor -q --out " + (dir.path() / "mine").string());
  INFO(ran.output);
  REQUIRE(ran.exit_code == 0);
  const std::string report = markcell::test::read_file((dir.path() / "mine" / "report.json").string());
  CHECK(report.find("\"scenario\": \"two-dings\"") != std::string::npos);
  const std::string truth = markcell::test::read_file((dir.path() / "mine" / "recording" / "truth.csv").string());
  CHECK(truth.size() > 0);
  door.replace(door.find("fps: 30"), 7, "fps: 30\nfsp: 30");
  const std::string bad = dir.write("bad.yaml", door);
  const auto refused = run_command("cd " + source_path("") + " && " + kMarkcell + " sim " + bad + " --out " +
                                   (dir.path() / "bad").string());
  CHECK(refused.exit_code == 2);
  CHECK(refused.output.find(bad + ":7: fsp: unknown key (known: kind, panel_type") != std::string::npos);
  CHECK_FALSE(std::filesystem::exists(dir.path() / "bad"));
  std::string off = markcell::test::read_file(source_path("config/scenarios/paper-door.yaml"));
  off.replace(off.find("x: 0.12,"), 8, "x: 3.0,");
  const std::string off_file = dir.write("off-panel.yaml", off);
  const auto off_panel = run_command("cd " + source_path("") + " && " + kMarkcell + " sim " + off_file + " --out " +
                                     (dir.path() / "off").string());
  CHECK(off_panel.exit_code == 2);
  CHECK(off_panel.output.find(off_file + ": defects[0] (id 1) at x 3.000000 m, y -0.120000 m is not on the door's "
                              "surface") != std::string::npos);
  const auto empty = run_command("cd " + source_path("") + " && " + kMarkcell + " replay " + dir.path().string() +
                                 " --out " + (dir.path() / "out").string());
  INFO(empty.output);
  CHECK(empty.exit_code == 1);
  CHECK(empty.output.find(dir.path().string() + "/recording.yaml") != std::string::npos);
}

TEST_CASE("select-mfs: the window under Xvfb, driven by mouse and keys, writes the MFs the engineer chose") {
  // The reference image and the door's MFs where the panel model puts them (the truth).
  markcell::test::TempDir dir;
  const std::string image = (dir.path() / "door.png").string(), truth_file = (dir.path() / "truth.yaml").string();
  const auto made = run_command("cd " + source_path("") + " && " + kMarkcell + " select-mfs --from-scenario paper-door --image " +
                                image + " --out " + truth_file);
  REQUIRE(made.exit_code == 0);
  const auto truth = markcell::vision::load_panel_type(truth_file);
  REQUIRE(truth.count() == 10);
  const auto near = [&](int mf, int dx, int dy) {  // an engineer's click, a few pixels off MF `mf` (1-based)
    const auto& p = truth.mfs[static_cast<std::size_t>(mf - 1)].reference_px;
    return std::to_string(std::lround(p.x()) + dx) + "," + std::to_string(std::lround(p.y()) + dy);
  };
  // Headless, the MFs on the command line: each one's move from its click is printed (the
  // test's own distance from the click to the truth), and a click whose corner is beyond
  // --snap is refused with the MF's index and both positions.
  {
    const std::string given = (dir.path() / "given.yaml").string();
    const auto ok = run_command(kMarkcell + " select-mfs --image " + image + " --panel door --out " + given + " --mf " +
                                near(1, 3, -2) + " --mf " + near(2, 2, 3) + " --mf " + near(3, -3, 1));
    INFO(ok.output);
    REQUIRE(ok.exit_code == 0);
    const std::array<std::array<int, 3>, 3> clicks{{{1, 3, -2}, {2, 2, 3}, {3, -3, 1}}};
    for (const auto& [mf, dx, dy] : clicks) {
      const auto& t = truth.mfs[static_cast<std::size_t>(mf - 1)].reference_px;
      const Eigen::Vector2d click(std::lround(t.x()) + dx, std::lround(t.y()) + dy);
      char from[64];
      std::snprintf(from, sizeof from, " px from (%.2f, %.2f)", click.x(), click.y());
      const std::size_t at = ok.output.find(from);
      REQUIRE(at != std::string::npos);
      const std::size_t number = ok.output.rfind(", ", at);
      CHECK(std::stod(ok.output.substr(number + 2, at - number - 2)) == Approx((t - click).norm()).margin(0.05));
    }
    const auto far = run_command(kMarkcell + " select-mfs --image " + image + " --panel door --out " + given +
                                 " --snap 2 --mf " + near(1, 4, 0) + " --mf " + near(2, 0, 0) + " --mf " + near(3, 0, 0));
    INFO(far.output);
    CHECK(far.exit_code == 2);
    const auto& t = truth.mfs[0].reference_px;
    const Eigen::Vector2d click(std::lround(t.x()) + 4, std::lround(t.y()));
    const std::string lead = "macro-feature 1: the corner found is ";
    const std::size_t at = far.output.find(lead);
    REQUIRE(at != std::string::npos);
    double moved = 0, cx = 0, cy = 0, x = 0, y = 0;
    REQUIRE(std::sscanf(far.output.c_str() + at + lead.size(), "%lf px from the click at (%lf, %lf), at (%lf, %lf)", &moved, &cx,
                        &cy, &x, &y) == 5);
    CHECK(moved == Approx((t - click).norm()).margin(0.05));
    CHECK(Eigen::Vector2d(cx, cy) == click);
    CHECK((Eigen::Vector2d(x, y) - t).norm() < 0.05);
    CHECK(far.output.find("): beyond the snap radius of 2 px") != std::string::npos);
    // A kind asked for: a hole where the door has a corner is refused with why; a kind
    // that is neither is refused before anything is read.
    const auto no_hole = run_command(kMarkcell + " select-mfs --image " + image + " --panel door --out " + given + " --mf " +
                                     near(1, 0, 0) + ",hole --mf " + near(2, 0, 0) + ",corner --mf " + near(3, 0, 0));
    INFO(no_hole.output);
    CHECK(no_hole.exit_code == 2);
    CHECK(no_hole.output.find("macro-feature 1: no hole at (") != std::string::npos);
    CHECK(no_hole.output.find("rays met an edge)") != std::string::npos);
    const auto bad_kind = run_command(kMarkcell + " select-mfs --image " + image + " --panel door --out " + given + " --mf " +
                                      near(1, 0, 0) + ",ring --mf " + near(2, 0, 0) + " --mf " + near(3, 0, 0));
    INFO(bad_kind.output);
    CHECK(bad_kind.exit_code == 2);
    CHECK(bad_kind.output.find("--mf '" + near(1, 0, 0) + ",ring': expected X,Y or X,Y,corner or X,Y,hole or X,Y,unseen in pixels") !=
          std::string::npos);
    // The kinds printed: the door's are all corners.
    CHECK(ok.output.find("MF  1 corner at (") != std::string::npos);
  }

  // Add MF 1, 2, 3 and 5; a click near the border adds nothing; drag the fourth
  // (MF 5) onto MF 6; add MF 7 and delete it again; save.
  const std::string out = (dir.path() / "door.yaml").string(), log = (dir.path() / "window.log").string();
  const auto r = run_command(source_path("tests/drive_select_mfs.sh") + " " + kMarkcell + " " + image + " door " + out + " " + log +
                             " click:" + near(1, 3, -2) + " click:" + near(2, 2, 3) + " click:" + near(3, -3, 1) +
                             " click:" + near(5, 1, 2) + " click:12,470 drag:" + near(5, 0, 0) + "," + near(6, 2, 2) +
                             " click:" + near(7, -2, -2) + " key:d key:s");
  INFO(r.output);
  REQUIRE(r.output.find("exit=0") != std::string::npos);
  CHECK(r.output.find("MF 4 (corner) added at") != std::string::npos);
  // Plain background by the border: the sensor's noise there is no corner.
  CHECK(r.output.find("no corner near (12.00, 470.00): the strongest there scores ") != std::string::npos);
  CHECK(r.output.find("a corner needs 20 (Shi-Tomasi, grey^2 per pixel): not added") != std::string::npos);
  CHECK(r.output.find("MF 4 (corner) moved to") != std::string::npos);
  CHECK(r.output.find("MF 5 deleted; 4 left") != std::string::npos);
  CHECK(r.output.find("saved 4 macro-features") != std::string::npos);
  const auto chosen = markcell::vision::load_panel_type(out);
  CHECK(chosen.name == "door");
  REQUIRE(chosen.count() == 4);
  const std::array<int, 4> expected{1, 2, 3, 6};
  for (std::size_t i = 0; i < 4; ++i) {
    CAPTURE(i, expected[i]);
    const Eigen::Vector2d d = chosen.mfs[i].reference_px - truth.mfs[static_cast<std::size_t>(expected[i] - 1)].reference_px;
    CHECK(d.norm() < 0.3);
  }

  // Quitting saves nothing; without a display the command says what to do instead.
  const std::string none = (dir.path() / "none.yaml").string();
  const auto quit = run_command(source_path("tests/drive_select_mfs.sh") + " " + kMarkcell + " " + image + " door " + none + " " + log +
                                " click:" + near(1, 0, 0) + " key:q");
  INFO(quit.output);
  CHECK(quit.output.find("exit=1") != std::string::npos);
  CHECK(quit.output.find("closed without saving; " + none + " not written") != std::string::npos);
  CHECK_FALSE(std::filesystem::exists(none));
  const auto headless = run_command("env -u DISPLAY " + kMarkcell + " select-mfs --image " + image + " --panel door --out " + none);
  CHECK(headless.exit_code == 1);
  CHECK(headless.output.find("no display to open the window on (DISPLAY is not set)") != std::string::npos);

  // The window is a program of its own (package markcell-select-mfs): a markcell without
  // it beside says so and writes nothing; given the MFs it needs no window.
  const auto alone = dir.path() / "alone";
  std::filesystem::create_directory(alone);
  std::filesystem::copy_file(kMarkcell, alone / "markcell");
  std::filesystem::permissions(alone / "markcell", std::filesystem::perms::owner_exec, std::filesystem::perm_options::add);
  const auto missing = run_command((alone / "markcell").string() + " select-mfs --image " + image + " --panel door --out " + none);
  INFO(missing.output);
  CHECK(missing.exit_code == 1);
  CHECK(missing.output.find("markcell select-mfs: the window is the program " + (alone / "markcell-select-mfs").string() +
                            ", which is not installed (Debian: the markcell-select-mfs package); without it give the "
                            "macro-features as --mf X,Y (3 or more)") != std::string::npos);
  CHECK_FALSE(std::filesystem::exists(none));
  const auto without_window = run_command((alone / "markcell").string() + " select-mfs --image " + image +
                                          " --panel door --out " + none + " --mf " + near(1, 0, 0) + " --mf " +
                                          near(2, 0, 0) + " --mf " + near(3, 0, 0));
  INFO(without_window.output);
  CHECK(without_window.exit_code == 0);
  CHECK(markcell::vision::load_panel_type(none).count() == 3);
}
