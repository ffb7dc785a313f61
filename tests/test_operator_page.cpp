// The operator page's parts in-process: its listen address, the live view's reduction
// (against OpenCV's own nearest-neighbour resize) and hand-over (nothing copied unless
// asked, nothing allocated on the vision lane), and what /metrics and /api/state say of
// a simulated cell (against the executive's own statistics). The page over HTTP, in a
// real browser and scraped by a real Prometheus, is tests/operator_page_test.py.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <map>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "alloc_guard.hpp"
#include "markcell/host/cell.hpp"
#include "markcell/host/live_view.hpp"
#include "markcell/host/operator_page.hpp"
#include "test_files.hpp"

using namespace markcell;
using namespace markcell::host;

namespace {

struct Parsed {
  bool ok;
  std::string address;
  int port;
  std::string error;
};

Parsed parse(const std::string& text) {
  Parsed p{false, "", 0, ""};
  p.ok = parse_listen_address(text, p.address, p.port, p.error);
  return p;
}

// A listening socket on a port the kernel picks: a port the page cannot take.
struct TakenPort {
  TakenPort() {
    fd = ::socket(AF_INET, SOCK_STREAM, 0);
    REQUIRE(fd >= 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    REQUIRE(::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
    REQUIRE(::listen(fd, 1) == 0);
    socklen_t n = sizeof a;
    REQUIRE(::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &n) == 0);
    port = ntohs(a.sin_port);
  }
  ~TakenPort() { ::close(fd); }
  int fd = -1;
  int port = 0;
};

// Prometheus's text format as name{labels} -> value (the families' HELP and TYPE lines
// left out).
std::map<std::string, std::string> samples(const std::string& text) {
  std::map<std::string, std::string> out;
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    const auto space = line.rfind(' ');
    REQUIRE(space != std::string::npos);
    out[line.substr(0, space)] = line.substr(space + 1);
  }
  return out;
}

struct SimCell {
  SimCell() : config(load_config(test::source_path("config/cell.example.yaml"), task_catalog())), cell(config, ClockKind::kSimulated) {}
  ~SimCell() {
    if (started) cell.shutdown(control::FaultCode::kShutdown, "test", "end of test");
  }
  void start() {
    cell.start();
    started = true;
  }
  CellConfig config;
  Cell cell;
  bool started = false;
};

}  // namespace

TEST_CASE("cell.operator_page: ADDRESS:PORT with an IPv4 address and a port from 1 to 65535") {
  const Parsed ok = parse("127.0.0.1:8089");
  CHECK(ok.ok);
  CHECK(ok.address == "127.0.0.1");
  CHECK(ok.port == 8089);
  CHECK(parse("0.0.0.0:65535").ok);
  CHECK(parse("10.1.2.3:1").port == 1);
  CHECK(parse("8089").error == "expected ADDRESS:PORT (e.g. 127.0.0.1:8089), got '8089'");
  CHECK(parse(":8089").error == "expected ADDRESS:PORT (e.g. 127.0.0.1:8089), got ':8089'");
  CHECK(parse("127.0.0.1:").error == "expected ADDRESS:PORT (e.g. 127.0.0.1:8089), got '127.0.0.1:'");
  CHECK(parse("localhost:8089").error == "'localhost' is not an IPv4 address (e.g. 127.0.0.1, or 0.0.0.0 for every interface)");
  CHECK(parse("127.0.0.256:8089").error == "'127.0.0.256' is not an IPv4 address (e.g. 127.0.0.1, or 0.0.0.0 for every interface)");
  CHECK(parse("127.0.0.1:0").error == "port '0' is not a number from 1 to 65535");
  CHECK(parse("127.0.0.1:65536").error == "port '65536' is not a number from 1 to 65535");
  CHECK(parse("127.0.0.1:80a").error == "port '80a' is not a number from 1 to 65535");
  CHECK(parse("127.0.0.1:-80").error == "port '-80' is not a number from 1 to 65535");
  CHECK(parse("127.0.0.1:99999999999").error == "port '99999999999' is not a number from 1 to 65535");
}

TEST_CASE("the live view: every scale-th pixel as OpenCV's nearest-neighbour resize takes it, green of a colour frame") {
  cv::RNG rng(7);
  for (const cv::Size size : {cv::Size(640, 480), cv::Size(1392, 1040), cv::Size(2048, 1536), cv::Size(641, 100)}) {
    cv::Mat grey(size, CV_8UC1);
    rng.fill(grey, cv::RNG::UNIFORM, 0, 256);
    std::vector<std::uint8_t> out(LiveView::kMaxWidth * LiveView::kMaxHeight, 0);
    int w = 0, h = 0, s = 0;
    REQUIRE(reduce_frame(grey, out.data(), w, h, s));
    INFO(size.width << "x" << size.height << " -> " << w << "x" << h << " scale " << s);
    CHECK(w <= LiveView::kMaxWidth);
    CHECK(h <= LiveView::kMaxHeight);
    CHECK(s == std::max(1, std::max((size.width + 639) / 640, (size.height + 511) / 512)));
    CHECK(w == size.width / s);
    CHECK(h == size.height / s);
    // The reference: OpenCV's INTER_NEAREST of the whole-scale part of the frame, which
    // takes source pixel floor(x * scale) for output pixel x.
    cv::Mat expected;
    cv::resize(grey(cv::Rect(0, 0, w * s, h * s)), expected, cv::Size(w, h), 0, 0, cv::INTER_NEAREST);
    CHECK(cv::countNonZero(cv::Mat(h, w, CV_8UC1, out.data()) != expected) == 0);
    cv::Mat colour(size, CV_8UC3);
    rng.fill(colour, cv::RNG::UNIFORM, 0, 256);
    REQUIRE(reduce_frame(colour, out.data(), w, h, s));
    cv::Mat green;
    cv::extractChannel(colour, green, 1);
    cv::resize(green(cv::Rect(0, 0, w * s, h * s)), expected, cv::Size(w, h), 0, 0, cv::INTER_NEAREST);
    CHECK(cv::countNonZero(cv::Mat(h, w, CV_8UC1, out.data()) != expected) == 0);
  }
  std::vector<std::uint8_t> out(16, 0);
  int w = -1, h = -1, s = -1;
  CHECK_FALSE(reduce_frame(cv::Mat(), out.data(), w, h, s));
  CHECK_FALSE(reduce_frame(cv::Mat(4, 4, CV_16UC1, cv::Scalar(1)), out.data(), w, h, s));
  CHECK_FALSE(reduce_frame(cv::Mat(4, 4, CV_32FC1, cv::Scalar(1)), out.data(), w, h, s));
  CHECK(w == -1);  // nothing written
}

TEST_CASE("the live view channel: a pair copied only when asked, once per request, without an allocation on the lane") {
  auto channel = std::make_unique<LiveViewChannel>();
  cv::Mat left(1040, 1392, CV_8UC1), right(1040, 1392, CV_8UC1);
  cv::randu(left, 0, 256);
  cv::randu(right, 0, 256);
  msg::PoseEstimate estimate;
  estimate.seq = 41;
  std::size_t allocations = 0;
  {
    test::AllocationGuard guard;
    channel->offer(1, millis(10), left, right, estimate);  // nobody asked: nothing copied
    allocations = guard.allocations();
  }
  CHECK(allocations == 0);
  CHECK(channel->newest().copies == 0);
  channel->request();
  {
    test::AllocationGuard guard;
    channel->offer(2, millis(43), left, right, estimate);
    channel->offer(3, millis(76), left, right, estimate);  // one request: one copy
    allocations = guard.allocations();
  }
  CHECK(allocations == 0);
  const LiveView& v = channel->newest();
  CHECK(v.copies == 1);
  CHECK(v.seq == 2);
  CHECK(v.time == millis(43));
  CHECK(v.pose.seq == 41);
  CHECK(v.scale == 3);
  CHECK(v.width == 464);
  CHECK(v.height == 346);
  CHECK(v.left[0] == left.at<std::uint8_t>(0, 0));
  CHECK(v.left[345 * 464 + 463] == left.at<std::uint8_t>(345 * 3, 463 * 3));
  CHECK(v.right[100 * 464 + 200] == right.at<std::uint8_t>(300, 600));
  // A pair of two sizes is not shown (the newest stays the last good one).
  channel->request();
  channel->offer(4, millis(109), left, right(cv::Rect(0, 0, 640, 480)), estimate);
  CHECK(channel->newest().seq == 2);
}

TEST_CASE("the operator page refuses a taken port at once, naming it") {
  SimCell s;
  TakenPort taken;
  const std::string listen = "127.0.0.1:" + std::to_string(taken.port);
  CHECK_THROWS_WITH(OperatorPage(listen, "cell", s.cell), "operator page: cannot listen on " + listen + ": Address already in use");
  CHECK_THROWS_WITH(OperatorPage("localhost:80", "cell", s.cell),
                    "operator page: 'localhost' is not an IPv4 address (e.g. 127.0.0.1, or 0.0.0.0 for every interface)");
}

TEST_CASE("/metrics and /api/state say what the executive and the service loop counted") {
  SimCell s;
  s.cell.enable_live_view();
  int port = 0;
  {
    const TakenPort free;  // a port the kernel picked, free again once closed
    port = free.port;
  }
  OperatorPage page("127.0.0.1:" + std::to_string(port), "line 3 \"east\"\nend", s.cell);
  CHECK(page.port() == port);
  s.start();
  REQUIRE(s.cell.sim_clock()->run_until(millis(500)) == control::SimClock::RunResult::kReached);
  page.update([](OperatorState& st) {
    st.status = "ready: waiting for a panel";
    st.results.push_back(R"({"cell":"c","panel":1,"panel_id":"P-1","fault":false,"defects":[{"id":1,"sprayed":true}]})");
    st.faults.push_back({1.25, "1970-01-01T00:00:01.250Z", "arm_link", "arm", "no state for 150 ms"});
    st.panels_done = 1;
    st.defects_sprayed = 1;
    st.faults_total = 1;
    st.records_accepted = 2;
  });
  const auto m = samples(page.metrics_text());
  const control::Executive& exec = s.cell.executive();
  const control::ExecutiveSpec& spec = exec.spec();
  REQUIRE(spec.tasks.size() >= 5);
  for (std::size_t i = 0; i < spec.tasks.size(); ++i) {
    const std::string task = spec.tasks[i].name;
    INFO(task);
    CHECK(m.at("markcell_task_exec_seconds_count{task=\"" + task + "\"}") ==
          std::to_string(exec.task_stats(static_cast<int>(i)).exec.count()));
    CHECK(std::stod(m.at("markcell_task_budget_seconds{task=\"" + task + "\"}")) == Approx(to_seconds(spec.tasks[i].budget)));
    CHECK(m.at("markcell_task_overruns_total{task=\"" + task + "\"}") ==
          std::to_string(exec.task_stats(static_cast<int>(i)).overruns.load()));
  }
  CHECK(m.at("markcell_task_exec_seconds_count{task=\"plc_io\"}") == "501");  // the 1 ms task, 0 to 500 ms
  CHECK(m.at("markcell_panels_total{result=\"done\"}") == "1");
  CHECK(m.at("markcell_panels_total{result=\"fault\"}") == "0");
  CHECK(m.at("markcell_defects_total{outcome=\"sprayed\"}") == "1");
  CHECK(m.at("markcell_records_total{verdict=\"accepted\"}") == "2");
  CHECK(m.at("markcell_faults_total") == "1");
  CHECK(m.at("markcell_safe_stop") == "0");
  // The cell's name in a label: its quote, backslash and newline escaped as the format says.
  bool named = false;
  for (const auto& [key, value] : m)
    if (key.rfind("markcell_build_info{", 0) == 0) {
      named = key.find(R"(cell="line 3 \"east\"\nend")") != std::string::npos && value == "1";
    }
  CHECK(named);

  const auto j = nlohmann::json::parse(page.state_json());
  CHECK(j.at("cell") == "line 3 \"east\"\nend");
  CHECK(j.at("status") == "ready: waiting for a panel");
  CHECK(j.at("results").size() == 1);
  CHECK(j.at("results")[0].at("panel_id") == "P-1");
  CHECK(j.at("faults")[0].at("code") == "arm_link");
  CHECK(j.at("faults")[0].at("detail") == "no state for 150 ms");
  CHECK(j.at("faults")[0].at("utc") == "1970-01-01T00:00:01.250Z");
  CHECK(j.at("counts").at("panels_done") == 1);
  CHECK(j.at("counts").at("records_accepted") == 2);
  CHECK(j.at("timing").at("tasks").size() == spec.tasks.size());
  CHECK(j.at("safe_stop").at("active") == false);
}
