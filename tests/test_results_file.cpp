// The results file and the pose log against a disk that fills up, a crash's torn line, and a file removed
// or replaced while the cell runs. The disk is a real one: a 16 KiB tmpfs mounted for the
// test (as root; elsewhere a file-size limit, RLIMIT_FSIZE, refuses the writes the same
// way, halfway through a line). The reference is the file's bytes as a reader sees them.
#include <catch2/catch.hpp>

#include <signal.h>
#include <sys/mount.h>
#include <sys/resource.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "markcell/host/pose_log.hpp"
#include "markcell/host/results_file.hpp"
#include "test_files.hpp"

using namespace markcell;
using namespace markcell::host;

namespace {

// A small file system of its own, or (without the privilege to mount) a size limit on
// the files this process writes; either way writes past `bytes` fail part-way.
struct SmallDisk {
  explicit SmallDisk(std::size_t bytes) {
    dir = std::filesystem::temp_directory_path() / ("markcell-small-disk-" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir);
    const std::string options = "size=" + std::to_string(bytes);
    mounted = ::mount("tmpfs", dir.c_str(), "tmpfs", 0, options.c_str()) == 0;
    if (!mounted) {
      WARN("cannot mount a tmpfs here (not root): the file-size limit stands in for a full disk");
      ::signal(SIGXFSZ, SIG_IGN);
      ::getrlimit(RLIMIT_FSIZE, &saved);
      rlimit r = saved;
      r.rlim_cur = bytes;
      ::setrlimit(RLIMIT_FSIZE, &r);
    }
  }
  ~SmallDisk() {
    if (mounted) ::umount(dir.c_str());
    else ::setrlimit(RLIMIT_FSIZE, &saved);
    std::error_code ec;
    std::filesystem::remove_all(dir, ec);
  }
  std::filesystem::path dir;
  bool mounted = false;
  rlimit saved{};
};

std::string line_of(int i) {
  return "{\"cell\": \"c\", \"panel\": " + std::to_string(i) + ", \"panel_id\": \"p" + std::to_string(i) +
         "\", \"fault\": false, \"reason\": \"" + std::string(200, 'x') + "\"}";
}

}  // namespace

TEST_CASE("a full disk mid-line: the partial line is taken back, nothing glued onto it, the panel's result not counted") {
  SmallDisk disk(16 * 1024);
  const std::string path = (disk.dir / "results.jsonl").string();
  std::vector<std::string> written;
  {
    ResultsFile results(path);
    int failures = 0;
    for (int i = 1; i <= 200 && failures == 0; ++i) {
      results.append(ResultsFile::accepted_json("c", "2026-12-07T00:00:00.000Z", "r" + std::to_string(i), "p" + std::to_string(i)));
      try {
        results.append(line_of(i));
        written.push_back(line_of(i));
      } catch (const std::runtime_error& e) {
        ++failures;
        CHECK(std::string(e.what()).find(path + ": writing a result failed: ") == 0);
        CHECK(std::string(e.what()).find("(the result was not written)") != std::string::npos);
      }
    }
    REQUIRE(failures == 1);
    // The file ends at its last complete line: every line whole.
    const std::string text = test::read_file(path);
    REQUIRE_FALSE(text.empty());
    CHECK(text.back() == '\n');
    std::istringstream in(text);
    std::string line;
    int results_seen = 0;
    while (std::getline(in, line)) {
      CHECK(line.front() == '{');
      CHECK(line.back() == '}');
      results_seen += line.find("\"panel\": ") != std::string::npos ? 1 : 0;
    }
    CHECK(results_seen == static_cast<int>(written.size()));
    // The panel whose result did not fit is one accepted without a result.
    const ResultsFile::History h = results.history();
    REQUIRE(h.unfinished.size() == 1);
    CHECK(h.unfinished[0] == "p" + std::to_string(written.size() + 1));
  }
}

TEST_CASE("a torn line that a crash left and a restart ended is no panel's result") {
  test::TempDir dir;
  const std::string path = (dir.path() / "results.jsonl").string();
  {
    std::ofstream out(path);
    out << ResultsFile::accepted_json("c", "2026-12-07T00:00:00.000Z", "r1", "p1") << "\n";
    const std::string torn = line_of(1);
    out << torn.substr(0, torn.find("\"fault\"") + 14);  // cut after '"fault": false', mid-line
  }
  ResultsFile results(path);  // ends the torn line
  const std::string text = test::read_file(path);
  CHECK(text.back() == '\n');
  const ResultsFile::History h = results.history();
  REQUIRE(h.unfinished.size() == 1);  // p1's torn result counts for nothing
  CHECK(h.unfinished[0] == "p1");
  // One cut right after an inner '}' is not whole either.
  const std::string nested = "{\"cell\": \"c\", \"panel_id\": \"p2\", \"intercalibration\": {\"status\": \"ok\"}";
  results.append(ResultsFile::accepted_json("c", "2026-12-07T00:00:00.000Z", "r2", "p2"));
  { std::ofstream(path, std::ios::app) << nested << "\n"; }
  CHECK(results.history().unfinished.size() == 2);
}

TEST_CASE("the results file removed or replaced by a folder while running: a fault, not results into a deleted file") {
  test::TempDir dir;
  const std::string path = (dir.path() / "results.jsonl").string();
  ResultsFile results(path);
  results.append(line_of(1));
  std::filesystem::remove(path);
  REQUIRE_THROWS_WITH(results.append(line_of(2)),
                      path + ": the results file was removed while the cell ran (results are not written until it is back)");
  std::filesystem::create_directories(path);
  REQUIRE_THROWS_WITH(results.append(line_of(3)), path + ": the results file was replaced by a directory");
  std::filesystem::remove(path);
  // Rotated: a new regular file at the path takes the results from then on.
  { std::ofstream(path) << ""; }
  results.append(line_of(4));
  CHECK(test::read_file(path) == line_of(4) + "\n");
}

// Each line is JSON a standard parser reads (nlohmann-json's, as any consumer's would):
// the panel's result with its defects, and text the cell did not make (a record's file
// name in the drop folder may hold any bytes, a reason any characters) escaped or
// replaced, never a line that does not parse and never a result lost to its text.
TEST_CASE("results lines parse as JSON whatever bytes their text holds") {
  control::PanelResult r;
  r.serial = 7;
  r.panel_id.assign("door-7");
  r.started = seconds(12) + micros(345'678);  // 12.3457 s at the file's 0.1 ms
  r.fault = true;
  r.reason.assign("quote \" backslash \\ tab \t newline \n");
  control::DefectResult* d = r.defects.emplace_back();
  REQUIRE(d != nullptr);
  d->id = 4;
  d->sprayed = true;
  d->spray_requested = seconds(13);
  r.finished = seconds(14) + millis(2);
  const auto line = ResultsFile::to_json(r, "cell-a", host::UtcClock{true});  // simulated: 0 s is the epoch
  CHECK(line.find('\n') == std::string::npos);  // one line
  const auto j = test::parse_json(line);
  CHECK(j["cell"] == "cell-a");
  CHECK(j["panel"] == 7);
  CHECK(j["started_s"] == 12.3457);
  CHECK(j["started_utc"] == "1970-01-01T00:00:12.345Z");  // to the millisecond, rounded down
  CHECK(j["finished_utc"] == "1970-01-01T00:00:14.002Z");
  CHECK(j["reason"] == "quote \" backslash \\ tab \t newline \n");
  CHECK(j["defects"][0] ==
        nlohmann::ordered_json{{"id", 4}, {"sprayed", true}, {"spray_s", 13.0}, {"spray_utc", "1970-01-01T00:00:13.000Z"}});
  const auto rejected =
      test::parse_json(ResultsFile::rejected_json("cell-a", "1970-01-01T00:00:15.000Z", "/drop/bad\xff\xfe.yaml", "", "not UTF-8 \x01"));
  CHECK(rejected["utc"] == "1970-01-01T00:00:15.000Z");
  CHECK(rejected["record"] == "/drop/bad\xEF\xBF\xBD\xEF\xBF\xBD.yaml");  // each bad byte U+FFFD
  CHECK(rejected["rejected"] == "not UTF-8 \x01");
}

namespace {
std::vector<std::string> file_lines(const std::filesystem::path& p) {
  std::vector<std::string> out;
  std::ifstream in(p);
  for (std::string l; std::getline(in, l);) out.push_back(l);
  return out;
}
msg::PoseEstimate estimate(std::uint64_t seq) {
  msg::PoseEstimate e;
  e.seq = seq;
  e.time = static_cast<Nanos>(seq) * 100'000'000;
  e.status = msg::TrackStatus::kTracking;
  e.reference_time = 0;
  // A turn of 0.3 rad about z and a shift: the quaternion is (cos 0.15, 0, 0, sin 0.15).
  e.X_CamR_P = Eigen::Translation3d(0.1, -0.02, 3.1) * Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ());
  e.tracked = 2;
  e.inliers = 1;
  e.rms = 0.00012346;
  msg::MacroFeatureObservation seen;
  seen.valid = seen.inlier = true;
  seen.left = {100.25, 200.5};
  seen.right = {80.125, 200.75};
  msg::MacroFeatureObservation outlier = seen;
  outlier.inlier = false;
  e.mfs.push_back(seen);
  e.mfs.push_back(outlier);
  e.mfs.push_back(msg::MacroFeatureObservation{});  // unseen
  return e;
}
}  // namespace

TEST_CASE("the pose log: rows as specified, appended across restarts, rotated at its size, a full disk counted") {
  test::TempDir dir;
  {
    PoseLog log(dir.path().string(), PoseLog::Mode::kAppend, 0);
    CHECK(log.write(estimate(1)));
    msg::PoseEstimate searching;
    searching.seq = 2;
    searching.time = 200'000'000;
    searching.status = msg::TrackStatus::kSearching;
    searching.reason = "no \"panel\" here";
    CHECK(log.write(searching));
  }
  auto poses = file_lines(dir.path() / "poses.csv");
  REQUIRE(poses.size() == 3);
  CHECK(poses[0] + "\n" == PoseLog::kPosesHeader);
  CHECK(poses[1] == "1,100000000,tracking,0,0.100000,-0.020000,3.100000," + std::string("0.988771078,0.000000000,0.000000000,0.149438132") +
                        ",2,1,0.0001235,\"\"");
  CHECK(std::abs(0.988771078 - std::cos(0.15)) < 1e-9);  // the reference for the digits above
  CHECK(std::abs(0.149438132 - std::sin(0.15)) < 1e-9);
  CHECK(poses[2] == "2,200000000,searching,,,,,,,,,0,0,,\"no \"\"panel\"\" here\"");
  auto tracks = file_lines(dir.path() / "mf_tracks.csv");
  REQUIRE(tracks.size() == 4);  // the searching estimate has no MFs
  CHECK(tracks[0] + "\n" == PoseLog::kTracksHeader);
  CHECK(tracks[1] == "1,100000000,0,inlier,100.250,200.500,80.125,200.750");
  CHECK(tracks[2] == "1,100000000,1,outlier,100.250,200.500,80.125,200.750");
  CHECK(tracks[3] == "1,100000000,2,unseen,,,,");

  // Reopened in append mode (the service restarted): no second header. Rotated once past
  // 1 KiB: FILE.1 holds what came before, FILE starts with its header again.
  {
    PoseLog log(dir.path().string(), PoseLog::Mode::kAppend, 1024);
    for (std::uint64_t s = 3; s < 20; ++s) log.write(estimate(s));
    CHECK(log.rotations() >= 2);  // both files passed 1 KiB
    CHECK(log.failed() == 0);
  }
  const auto old = file_lines(dir.path() / "poses.csv.1");
  poses = file_lines(dir.path() / "poses.csv");
  CHECK(old[0] + "\n" == PoseLog::kPosesHeader);
  CHECK(std::count(old.begin(), old.end(), old[0]) == 1);
  CHECK(poses[0] + "\n" == PoseLog::kPosesHeader);
  // The last rotation's .1 and the file after it: consecutive frames, none lost, to the last.
  REQUIRE(old.size() > 1);
  REQUIRE(poses.size() > 1);
  CHECK(std::stoi(poses[1]) == std::stoi(old.back()) + 1);
  CHECK(std::stoi(poses.back()) == 19);
  CHECK(std::filesystem::file_size(dir.path() / "poses.csv.1") >= 1024);

  // A link where the file should be is refused, naming it.
  test::TempDir linked;
  std::filesystem::create_symlink("/etc/passwd", linked.path() / "poses.csv");
  CHECK_THROWS_WITH(PoseLog(linked.path().string(), PoseLog::Mode::kAppend, 0),
                    Catch::Contains((linked.path() / "poses.csv").string() + ": cannot open the pose log"));

  // A full disk: the rows that do not fit are counted, the log goes on.
  SmallDisk disk(16 * 1024);
  PoseLog full(disk.dir.string(), PoseLog::Mode::kTruncate, 0);
  std::uint64_t refused = 0;
  for (std::uint64_t s = 0; s < 400; ++s) {
    if (!full.write(estimate(s))) ++refused;
  }
  CHECK(refused > 0);
  CHECK(full.failed() == refused);
  CHECK(full.rows() + full.failed() == 400);
}
