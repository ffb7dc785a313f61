#include <fcntl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <iostream>
#include <sstream>
#include <thread>
#include <vector>

#include "markcell/tools/bench.hpp"
#include "markcell/host/cell.hpp"

namespace markcell::host {

namespace {

struct Latency {
  double p50 = 0, p99 = 0, p999 = 0, max = 0;  // microseconds
  unsigned long long samples = 0;
};

// cyclictest's histogram: one line "BUCKET COUNT" per microsecond, comments with '#'.
bool parse_cyclictest_histogram(const std::string& path, Latency& out, std::string& error) {
  std::ifstream in(path);
  if (!in) {
    error = "cannot read cyclictest's histogram " + path;
    return false;
  }
  std::vector<unsigned long long> buckets;
  unsigned long long overflows = 0;
  double max_us = -1;
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    if (line[0] == '#') {
      unsigned long long v = 0;
      if (std::sscanf(line.c_str(), "# Max Latencies: %llu", &v) == 1) max_us = static_cast<double>(v);
      if (std::sscanf(line.c_str(), "# Histogram Overflows: %llu", &v) == 1) overflows = v;
      continue;
    }
    unsigned long long bucket = 0, count = 0;
    if (std::sscanf(line.c_str(), "%llu %llu", &bucket, &count) != 2) continue;
    if (buckets.size() <= bucket) buckets.resize(bucket + 1, 0);
    buckets[bucket] += count;
  }
  unsigned long long total = overflows;
  for (auto c : buckets) total += c;
  if (total == 0) {
    error = "cyclictest's histogram " + path + " holds no sample";
    return false;
  }
  out.samples = total;
  // Bucket b holds latencies in [b, b+1) us; quote the upper edge, as the executive's
  // histogram quotes its bucket's upper edge.
  auto percentile = [&](double p) {
    const auto rank = static_cast<unsigned long long>(p * static_cast<double>(total) + 0.999999);
    unsigned long long seen = 0;
    for (std::size_t b = 0; b < buckets.size(); ++b) {
      seen += buckets[b];
      if (seen >= rank) return std::min(static_cast<double>(b + 1), max_us >= 0 ? max_us : 1e18);
    }
    return max_us;
  };
  out.p50 = percentile(0.5);
  out.p99 = percentile(0.99);
  out.p999 = percentile(0.999);
  out.max = max_us;
  return true;
}

nlohmann::ordered_json json_latency(const Latency& l) {
  return {{"p50", l.p50}, {"p99", l.p99}, {"p99_9", l.p999}, {"max", l.max}, {"samples", l.samples}};
}

}  // namespace

int bench_loop(const CellConfig& config, const LoopBenchOptions& options) {
  // The cell's own control lane, alone: its tasks, its core and priority, on the real clock.
  CellConfig cfg = config;
  cfg.executive.trace = false;
  int lane = -1;
  for (std::size_t i = 0; i < cfg.executive.lanes.size(); ++i)
    if (cfg.executive.lanes[i].name == options.lane) lane = static_cast<int>(i);
  if (lane < 0) {
    std::cerr << "markcell bench loop: lane '" << options.lane << "' is not in " << config.file << "\n";
    return 2;
  }
  if (cfg.executive.tick != millis(1)) {
    std::cerr << "markcell bench loop: the benchmark runs at 1 kHz; " << config.file << " has base_tick_us "
              << cfg.executive.tick / kNanosPerMicro << "\n";
    return 2;
  }
  const control::LaneSpec lane_spec = cfg.executive.lanes[static_cast<std::size_t>(lane)];
  std::vector<control::TaskSpec> tasks;
  for (auto t : cfg.executive.tasks)
    if (t.lane == lane) {
      t.lane = 0;
      tasks.push_back(t);
    }
  cfg.executive.lanes = {lane_spec};
  cfg.executive.tasks = tasks;
  cfg.watchdog.systemd = false;
  cfg.watchdog.device.enabled = false;

  Latency ours;
  std::vector<std::string> warnings;
  {
    Cell cell(cfg, ClockKind::kReal);
    cell.start();
    std::this_thread::sleep_for(std::chrono::duration<double>(options.seconds));
    cell.shutdown(control::FaultCode::kShutdown, "bench", "benchmark finished");
    const auto& h = cell.executive().lane_stats(0).wake_latency;
    ours = Latency{to_micros(h.percentile(0.5)), to_micros(h.percentile(0.99)), to_micros(h.percentile(0.999)),
                   to_micros(h.max()), h.count()};
    warnings = cell.privilege_warnings();
  }
  for (const auto& w : warnings) std::cerr << "markcell: warning: " << w << "\n";

  // cyclictest at the same period, priority and core, for the same duration.
  char hist_template[] = "/tmp/markcell-cyclictest-XXXXXX";
  const int fd = mkstemp(hist_template);
  if (fd < 0) {
    std::perror("markcell bench loop: mkstemp");
    return 1;
  }
  close(fd);
  const std::string hist = hist_template;
  std::vector<std::string> args = {options.cyclictest, "-q", "-m", "-i", "1000",
                                   "-D", std::to_string(static_cast<long>(options.seconds + 0.5)) + "s",
                                   "-h", "20000", "--histfile=" + hist};
  if (lane_spec.priority > 0) {
    args.push_back("-p");
    args.push_back(std::to_string(lane_spec.priority));
  }
  if (lane_spec.core >= 0) args.push_back("-a" + std::to_string(lane_spec.core));
  std::string cmdline;
  for (const auto& a : args) cmdline += (cmdline.empty() ? "" : " ") + a;
  std::cout << "running: " << cmdline << std::endl;
  const pid_t pid = fork();
  if (pid == 0) {
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    const int devnull = ::open("/dev/null", O_WRONLY);
    if (devnull >= 0) dup2(devnull, STDOUT_FILENO);
    execvp(argv[0], argv.data());
    std::fprintf(stderr, "markcell bench loop: cannot run %s: %s (install rt-tests: toolchain/install-deps)\n",
                 argv[0], std::strerror(errno));
    _exit(127);
  }
  int status = 0;
  waitpid(pid, &status, 0);
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    std::cerr << "markcell bench loop: cyclictest failed (status " << status << ")\n";
    unlink(hist.c_str());
    return 1;
  }
  Latency ref;
  std::string error;
  const bool parsed = parse_cyclictest_histogram(hist, ref, error);
  unlink(hist.c_str());
  if (!parsed) {
    std::cerr << "markcell bench loop: " << error << "\n";
    return 1;
  }

  const double ratio = ref.p999 > 0 ? ours.p999 / ref.p999 : 0.0;
  char line[200];
  std::printf("wake-up latency at 1 kHz, lane '%s' (priority %d, core %d), %.0f s each\n", lane_spec.name.c_str(),
              lane_spec.priority, lane_spec.core, options.seconds);
  std::printf("%-12s %10s %10s %10s %10s %10s\n", "", "p50_us", "p99_us", "p99.9_us", "max_us", "samples");
  std::snprintf(line, sizeof line, "%-12s %10.1f %10.1f %10.1f %10.1f %10llu\n", "markcell", ours.p50, ours.p99,
                ours.p999, ours.max, ours.samples);
  std::fputs(line, stdout);
  std::snprintf(line, sizeof line, "%-12s %10.1f %10.1f %10.1f %10.1f %10llu\n", "cyclictest", ref.p50, ref.p99,
                ref.p999, ref.max, ref.samples);
  std::fputs(line, stdout);
  std::printf("p99.9 ratio markcell / cyclictest: %.2f\n", ratio);

  if (!options.json_path.empty()) {
    std::ofstream out(options.json_path);
    const nlohmann::ordered_json doc{{"benchmark", "loop"},
                                     {"period_us", 1000},
                                     {"seconds", options.seconds},
                                     {"lane", lane_spec.name},
                                     {"priority", lane_spec.priority},
                                     {"core", lane_spec.core},
                                     {"markcell_us", json_latency(ours)},
                                     {"cyclictest_us", json_latency(ref)},
                                     {"p99_9_ratio", ratio},
                                     {"privilege_warnings", warnings.size()}};
    out << doc.dump(2, ' ', false, nlohmann::ordered_json::error_handler_t::replace) << "\n";
    if (!out) {
      std::cerr << "markcell bench loop: cannot write " << options.json_path << "\n";
      return 1;
    }
    std::cout << "wrote " << options.json_path << "\n";
  }
  return 0;
}

}  // namespace markcell::host
