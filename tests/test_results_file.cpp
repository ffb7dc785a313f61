// The results file against a disk that fills up, a crash's torn line, and a file removed
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
      results.append(ResultsFile::accepted_json("c", "r" + std::to_string(i), "p" + std::to_string(i)));
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
    out << ResultsFile::accepted_json("c", "r1", "p1") << "\n";
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
  results.append(ResultsFile::accepted_json("c", "r2", "p2"));
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
  const auto line = ResultsFile::to_json(r, "cell-a");
  CHECK(line.find('\n') == std::string::npos);  // one line
  const auto j = test::parse_json(line);
  CHECK(j["cell"] == "cell-a");
  CHECK(j["panel"] == 7);
  CHECK(j["started_s"] == 12.3457);
  CHECK(j["reason"] == "quote \" backslash \\ tab \t newline \n");
  CHECK(j["defects"][0] == nlohmann::ordered_json{{"id", 4}, {"sprayed", true}, {"spray_s", 13.0}});
  const auto rejected = test::parse_json(ResultsFile::rejected_json("cell-a", "/drop/bad\xff\xfe.yaml", "", "not UTF-8 \x01"));
  CHECK(rejected["record"] == "/drop/bad\xEF\xBF\xBD\xEF\xBF\xBD.yaml");  // each bad byte U+FFFD
  CHECK(rejected["rejected"] == "not UTF-8 \x01");
}
