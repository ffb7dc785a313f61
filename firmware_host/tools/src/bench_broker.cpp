// `markcell bench broker`: the stations' broker path under load (docs/broker.md). One
// mosquitto on 127.0.0.1 (TLS, a password per station, the ACL of docs/broker.md), L
// lines each with an inspection station and M marking stations, every station a process
// of its own (this binary again, in a hidden station mode). The inspection stations
// publish N records in all (each retained on its topic, QoS 1, acknowledged one by one);
// every marking station of the line keeps each record as the service does (BrokerLink:
// written, synced, renamed into the record folder) and accepts it at once (its accepted
// line appended and fdatasync'ed to its results file, the file moved to accepted/). The
// latency of a delivery is from just before the publish call to the accepted line synced,
// on CLOCK_MONOTONIC (one machine); lost and duplicated are counted from the results
// files' accepted lines.
#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <pwd.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "markcell/host/broker_link.hpp"
#include "markcell/host/exit_codes.hpp"
#include "markcell/host/results_file.hpp"
#include "markcell/tools/bench.hpp"
#include "sample_percentile.hpp"

extern char** environ;

namespace markcell::host {

namespace fs = std::filesystem;

namespace {

std::string station_name(const std::string& role, int line, int k) {
  return (role == "inspection" ? "insp-" : "mark-") + std::to_string(line) + "-" + std::to_string(k);
}

// A child process; its output to `log`.
pid_t spawn(const std::vector<std::string>& args, const fs::path& log) {
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 1, log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0640);
  posix_spawn_file_actions_adddup2(&actions, 1, 2);
  std::vector<char*> argv;
  for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  // The children start with no signal blocked (this process blocks SIGTERM for
  // sigtimedwait, and a blocked mask is inherited: mosquitto would not stop).
  posix_spawnattr_t attr;
  posix_spawnattr_init(&attr);
  sigset_t none;
  sigemptyset(&none);
  posix_spawnattr_setsigmask(&attr, &none);
  posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETSIGMASK);
  pid_t pid = -1;
  const int rc = posix_spawnp(&pid, argv[0], &actions, &attr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  posix_spawnattr_destroy(&attr);
  if (rc != 0) throw std::runtime_error(args[0] + ": cannot start: " + std::strerror(rc) +
                                        (args[0] == "mosquitto" ? " (apt install mosquitto)" : ""));
  return pid;
}

int run_to_end(const std::vector<std::string>& args, const fs::path& log) {
  const pid_t pid = spawn(args, log);
  int status = 0;
  waitpid(pid, &status, 0);
  return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
}

void must(const std::vector<std::string>& args, const fs::path& log) {
  if (const int rc = run_to_end(args, log); rc != 0)
    throw std::runtime_error(args[0] + " exited " + std::to_string(rc) + " (see " + log.string() + ")");
}

bool listening(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_port = htons(static_cast<std::uint16_t>(port));
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  const bool ok = ::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
  ::close(fd);
  return ok;
}

int free_port() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof a;
  if (::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 || ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) != 0)
    throw std::runtime_error(std::string("no free port: ") + std::strerror(errno));
  ::close(fd);
  return ntohs(a.sin_port);
}

BrokerConfig station_config(const fs::path& dir, int port, int line, const std::string& name) {
  BrokerConfig c;
  c.server = "127.0.0.1:" + std::to_string(port);
  c.line = "line-" + std::to_string(line);
  c.station = name;
  c.username = name;
  c.password_file = (dir / "secrets" / (name + ".password")).string();
  c.ca_file = (dir / "secrets" / "ca.crt").string();
  c.connect_timeout = seconds(10);
  return c;
}

// A record of the configuration's first panel type: its MF count, three defects of 40
// points (about the size of the rig's records), the publish time as a comment.
std::string bench_record(const PanelTypeConfig& panel, const std::string& id, Nanos published) {
  std::ostringstream s;
  s << "# published_ns: " << published << "\npanel_id: " << id << "\npanel_type: " << panel.name
    << "\nframe: CamL_SL\nunits: m\nmacro_features:\n";
  for (int i = 0; i < panel.macro_features; ++i)
    s << "  - [" << 0.1 * (i % 5) - 0.2 << ", " << 0.1 * (i / 5) - 0.2 << ", 2.0]\n";
  s << "defects:\n";
  for (int d = 1; d <= 3; ++d) {
    s << "  - id: " << d << "\n    points:\n";
    for (int p = 0; p < 40; ++p) s << "      - [" << 0.1 * d + 0.001 * p << ", " << 0.05 * d << ", 2.01]\n";
  }
  s << "...\n";
  return s.str();
}

// The marking station: keeps and accepts every record until `expected` are accepted or
// SIGTERM; writes DIR/NAME.latency (one `id ns` a line).
int marking_station(const CellConfig& config, const BrokerBenchOptions& o) {
  const fs::path dir = fs::path(o.work) / o.station_name;
  fs::create_directories(dir / "records" / "accepted");
  ResultsFile results((dir / "results.jsonl").string());
  std::vector<std::pair<std::string, Nanos>> latencies;
  latencies.reserve(static_cast<std::size_t>(o.station_count));
  std::atomic<int> accepted{0};
  BrokerLink link(station_config(o.work, o.port, o.station_line, o.station_name), BrokerLink::Role::kMarking,
                  (dir / "records").string(), config.panel_types, nullptr, [](void*) { return monotonic_now(); }, nullptr);
  link.set_on_kept([&](const std::string& id, const std::string& file, std::string_view payload) {
    static constexpr std::string_view kStamp = "# published_ns: ";
    Nanos published = 0;
    if (payload.substr(0, kStamp.size()) == kStamp)
      published = std::stoll(std::string(payload.substr(kStamp.size(), payload.find('\n') - kStamp.size())));
    const std::string to = (dir / "records" / "accepted" / fs::path(file).filename()).string();
    results.append(ResultsFile::accepted_json(o.station_name, "", to, id));
    const Nanos done = monotonic_now();
    fs::rename(file, to);
    link.answered(id);
    latencies.emplace_back(id, done - published);
    accepted.fetch_add(1);
  });
  link.connect();
  std::ofstream(dir / "ready") << "ready\n";
  sigset_t term;
  sigemptyset(&term);
  sigaddset(&term, SIGTERM);
  const timespec none{0, 0};
  while (accepted.load() < o.station_count && sigtimedwait(&term, nullptr, &none) < 0) link.poll(millis(50));
  link.stop("benchmark finished");
  std::ofstream out(dir / "latency");
  for (const auto& [id, ns] : latencies) out << id << " " << ns << "\n";
  for (const BrokerEvent& e : link.take_events()) std::cerr << "rejected: " << e.reason << "\n";
  return 0;
}

// The inspection station: `count` records, one every 1/rate s, each awaited.
int inspection_station(const CellConfig& config, const BrokerBenchOptions& o) {
  BrokerLink link(station_config(o.work, o.port, o.station_line, o.station_name), BrokerLink::Role::kInspection,
                  o.work, config.panel_types, nullptr, [](void*) { return monotonic_now(); }, nullptr);
  link.connect();
  const Nanos period = static_cast<Nanos>(1e9 / o.rate_per_station);
  Nanos next = monotonic_now();
  for (int i = 0; i < o.station_count; ++i) {
    const std::string id = o.station_name + "-" + std::to_string(i);
    const Nanos now = monotonic_now();
    if (now < next) {
      const timespec ts = to_timespec(next - now);
      nanosleep(&ts, nullptr);
    }
    next += period;
    if (!link.publish_record(bench_record(config.panel_types.front(), id, monotonic_now()), id, seconds(10))) {
      std::cerr << "publish " << id << ": " << link.error() << "\n";
      return kExitRuntime;
    }
  }
  link.stop("benchmark finished");
  return 0;
}

std::string self_exe() {
  std::error_code ec;
  const fs::path p = fs::read_symlink("/proc/self/exe", ec);
  return ec ? "markcell" : p.string();
}

}  // namespace

int bench_broker(const CellConfig& config, const BrokerBenchOptions& o) {
  if (config.panel_types.empty()) {
    std::cerr << "markcell bench broker: the configuration has no panel types\n";
    return kExitConfig;
  }
  try {
    if (o.station_role == "marking") return marking_station(config, o);
    if (o.station_role == "inspection") return inspection_station(config, o);
  } catch (const std::exception& e) {
    std::cerr << "markcell bench broker (" << o.station_name << "): " << e.what() << "\n";
    return kExitRuntime;
  }
  const fs::path work = o.work.empty() ? fs::temp_directory_path() / ("markcell-bench-broker-" + std::to_string(getpid()))
                                       : fs::path(o.work);
  std::vector<pid_t> children;
  pid_t broker = -1;
  const auto stop_all = [&] {
    for (pid_t c : children) kill(c, SIGTERM);
    for (pid_t c : children) waitpid(c, nullptr, 0);
    if (broker > 0) {
      kill(broker, SIGTERM);
      waitpid(broker, nullptr, 0);
    }
  };
  try {
    fs::remove_all(work);
    fs::create_directories(work / "secrets");
    const fs::path log = work / "setup.log", secrets = work / "secrets";
    // TLS: a CA and the broker's certificate for 127.0.0.1.
    must({"openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1", "-subj", "/CN=markcell bench CA",
          "-keyout", (secrets / "ca.key").string(), "-out", (secrets / "ca.crt").string()}, log);
    must({"openssl", "req", "-newkey", "rsa:2048", "-nodes", "-subj", "/CN=127.0.0.1", "-keyout",
          (secrets / "server.key").string(), "-out", (secrets / "server.csr").string()}, log);
    std::ofstream(secrets / "san.ext") << "subjectAltName=IP:127.0.0.1\n";
    must({"openssl", "x509", "-req", "-in", (secrets / "server.csr").string(), "-CA", (secrets / "ca.crt").string(),
          "-CAkey", (secrets / "ca.key").string(), "-CAcreateserial", "-days", "1", "-extfile",
          (secrets / "san.ext").string(), "-out", (secrets / "server.crt").string()}, log);
    // A user per station and the ACL of docs/broker.md.
    std::ofstream acl(secrets / "acl");
    bool first = true;
    for (int line = 1; line <= o.lines; ++line) {
      const std::string l = "markcell/line-" + std::to_string(line) + "/";
      for (int k = 0; k <= o.marking_per_line; ++k) {
        const std::string name = k == 0 ? station_name("inspection", line, 1) : station_name("marking", line, k);
        const std::string password = "bench-" + name + "-" + std::to_string(getpid());
        std::vector<std::string> args{"mosquitto_passwd", "-b"};
        if (first) args.push_back("-c");
        first = false;
        for (const auto& a : {(secrets / "passwords").string(), name, password}) args.push_back(a);
        must(args, log);
        const fs::path file = secrets / (name + ".password");
        std::ofstream(file) << password << "\n";
        fs::permissions(file, fs::perms::owner_read | fs::perms::owner_write);
        acl << "user " << name << "\n";
        if (k == 0) acl << "topic write " << l << name << "/record/#\n";
        else acl << "topic read " << l << "+/record/#\ntopic write " << l << name << "/result\n";
        acl << "topic readwrite " << l << name << "/state\n\n";
      }
    }
    acl.close();
    const int port = free_port();
    std::ofstream conf(work / "mosquitto.conf");
    const passwd* me = getpwuid(geteuid());
    conf << "user " << (me != nullptr ? me->pw_name : "root") << "\nper_listener_settings false\nallow_anonymous false\n"
         << "password_file " << (secrets / "passwords").string() << "\nacl_file " << (secrets / "acl").string()
         << "\npersistence true\npersistence_location " << (work / "persistence").string() << "/\n"
         << "max_queued_messages 100000\nlistener " << port << " 127.0.0.1\ncafile " << (secrets / "ca.crt").string()
         << "\ncertfile " << (secrets / "server.crt").string() << "\nkeyfile " << (secrets / "server.key").string()
         << "\ntls_version tlsv1.2\n";
    conf.close();
    fs::create_directories(work / "persistence");
    broker = spawn({"mosquitto", "-c", (work / "mosquitto.conf").string()}, work / "mosquitto.log");
    for (int i = 0; i < 500 && !listening(port); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
    if (!listening(port)) throw std::runtime_error("mosquitto is not listening (see " + (work / "mosquitto.log").string() + ")");

    // Each line's share: N / L, the first N mod L lines one more.
    const auto per_line = [&](int line) { return o.records / o.lines + (line <= o.records % o.lines ? 1 : 0); };
    const std::string exe = self_exe();
    const auto station = [&](const std::string& role, int line, int k, int count) {
      std::vector<std::string> args{exe, "bench", "broker", "--work", work.string(), "--station-role", role,
                                    "--station-line", std::to_string(line), "--station-name",
                                    station_name(role, line, k), "--port", std::to_string(port), "--station-count",
                                    std::to_string(count), "--rate", std::to_string(o.rate_per_station)};
      if (!o.config_file.empty()) {
        args.insert(args.begin() + 3, o.config_file);
        args.insert(args.begin() + 3, "--config");
      }
      children.push_back(spawn(args, work / (station_name(role, line, k) + ".log")));
    };
    for (int line = 1; line <= o.lines; ++line)
      for (int k = 1; k <= o.marking_per_line; ++k) station("marking", line, k, per_line(line));
    for (int line = 1; line <= o.lines; ++line)
      for (int k = 1; k <= o.marking_per_line; ++k)
        for (int i = 0; i < 1000 && !fs::exists(work / station_name("marking", line, k) / "ready"); ++i)
          std::this_thread::sleep_for(std::chrono::milliseconds(10));
    const std::size_t marking_count = children.size();
    for (int line = 1; line <= o.lines; ++line) station("inspection", line, 1, per_line(line));
    // The inspection stations end after their last acknowledgement; the marking ones when
    // they have every record, or at the timeout after that.
    int failed = 0;
    for (std::size_t i = marking_count; i < children.size(); ++i) {
      int status = 0;
      waitpid(children[i], &status, 0);
      if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) ++failed;
      children[i] = -1;
    }
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(o.drain_seconds);
    for (std::size_t i = 0; i < marking_count; ++i) {
      while (std::chrono::steady_clock::now() < deadline && waitpid(children[i], nullptr, WNOHANG) == 0)
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
      if (waitpid(children[i], nullptr, WNOHANG) == 0) {
        kill(children[i], SIGTERM);
        waitpid(children[i], nullptr, 0);
      }
      children[i] = -1;
    }
    children.clear();
    kill(broker, SIGTERM);
    waitpid(broker, nullptr, 0);
    broker = -1;
    if (failed > 0) throw std::runtime_error(std::to_string(failed) + " inspection station(s) failed (see their logs in " +
                                             work.string() + ")");

    // Every delivery: each record of a line at each of its marking stations.
    std::vector<double> latency_ms;
    long lost = 0, duplicated = 0;
    for (int line = 1; line <= o.lines; ++line)
      for (int k = 1; k <= o.marking_per_line; ++k) {
        const fs::path dir = work / station_name("marking", line, k);
        std::map<std::string, int> seen;
        std::ifstream results(dir / "results.jsonl");
        for (std::string l; std::getline(results, l);) {
          const auto j = nlohmann::json::parse(l, nullptr, false);
          if (!j.is_discarded() && j.value("accepted", false)) ++seen[j.value("panel_id", "")];
        }
        for (int i = 0; i < per_line(line); ++i) {
          const auto it = seen.find(station_name("inspection", line, 1) + "-" + std::to_string(i));
          if (it == seen.end()) ++lost;
          else duplicated += it->second - 1;
        }
        std::ifstream lat(dir / "latency");
        std::string id;
        long long ns = 0;
        while (lat >> id >> ns) latency_ms.push_back(static_cast<double>(ns) * 1e-6);
      }
    const int records = o.records;
    if (latency_ms.empty()) throw std::runtime_error("no record was accepted (see the logs in " + work.string() + ")");
    const double p50 = sample_percentile(latency_ms, 0.5), p99 = sample_percentile(latency_ms, 0.99),
                 max = sample_percentile(latency_ms, 1.0);
    std::printf("broker: %d line(s) x (1 inspection + %d marking stations), %d records, %zu deliveries accepted\n",
                o.lines, o.marking_per_line, records, latency_ms.size());
    std::printf("  lost %ld, duplicated %ld\n  publish to accepted (ms): p50 %.2f  p99 %.2f  max %.2f\n", lost, duplicated,
                p50, p99, max);
    if (!o.json_path.empty()) {
      nlohmann::json j{{"records", records},
                       {"deliveries", latency_ms.size()},
                       {"lines", o.lines},
                       {"marking_per_line", o.marking_per_line},
                       {"rate_per_station", o.rate_per_station},
                       {"lost", lost},
                       {"duplicated", duplicated},
                       {"latency_ms", {{"p50", p50}, {"p99", p99}, {"max", max}}}};
      std::ofstream(o.json_path) << j.dump(2) << "\n";
    }
    if (!o.keep) fs::remove_all(work);
    return lost == 0 && duplicated == 0 ? 0 : kExitRuntime;
  } catch (const std::exception& e) {
    stop_all();
    std::cerr << "markcell bench broker: " << e.what() << "\n";
    return kExitRuntime;
  }
}

}  // namespace markcell::host
