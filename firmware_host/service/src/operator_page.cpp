#include "markcell/host/operator_page.hpp"

#include <arpa/inet.h>

#include <cerrno>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <initializer_list>
#include <stdexcept>

#include <httplib.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "markcell/host/build_version.hpp"
#include "markcell/host/cell.hpp"
#include "markcell/host/live_view.hpp"

namespace markcell::host {
namespace {

using Json = nlohmann::ordered_json;

double micros(Nanos n) { return static_cast<double>(n) * 1e-3; }
double round2(double v) { return std::round(v * 100.0) / 100.0; }

std::string_view defect_state(const control::DefectProgress& d, bool current) {
  if (d.sprayed) return "sprayed";
  if (d.skipped != control::SkipReason::kNone) return "skipped";
  return current ? "marking" : "pending";
}

// A label value in Prometheus's text format: backslash, quote and newline escaped.
std::string label(std::string_view v) {
  std::string out;
  for (const char c : v) {
    if (c == '\\' || c == '"') out += '\\';
    if (c == '\n') {
      out += "\\n";
      continue;
    }
    out += c;
  }
  return out;
}

void append(std::string& out, const char* fmt, ...) __attribute__((format(printf, 2, 3)));
void append(std::string& out, const char* fmt, ...) {
  char line[512];
  va_list args;
  va_start(args, fmt);
  const int n = std::vsnprintf(line, sizeof line, fmt, args);
  va_end(args);
  if (n > 0) out.append(line, static_cast<std::size_t>(std::min<int>(n, sizeof line - 1)));
}

void family(std::string& out, const char* name, const char* type, const char* help) {
  append(out, "# HELP %s %s\n# TYPE %s %s\n", name, help, name, type);
}

}  // namespace

bool parse_listen_address(const std::string& text, std::string& address, int& port, std::string& error) {
  const auto colon = text.rfind(':');
  if (colon == std::string::npos || colon == 0 || colon + 1 == text.size()) {
    error = "expected ADDRESS:PORT (e.g. 127.0.0.1:8089), got '" + text + "'";
    return false;
  }
  const std::string host = text.substr(0, colon), digits = text.substr(colon + 1);
  in_addr parsed{};
  if (inet_pton(AF_INET, host.c_str(), &parsed) != 1) {
    error = "'" + host + "' is not an IPv4 address (e.g. 127.0.0.1, or 0.0.0.0 for every interface)";
    return false;
  }
  if (digits.size() > 5 || digits.find_first_not_of("0123456789") != std::string::npos || std::stoi(digits) < 1 ||
      std::stoi(digits) > 65535) {
    error = "port '" + digits + "' is not a number from 1 to 65535";
    return false;
  }
  address = host;
  port = std::stoi(digits);
  return true;
}

struct OperatorPage::Server {
  httplib::Server http;
};

OperatorPage::OperatorPage(const std::string& listen, const std::string& cell_name, Cell& cell)
    : cell_(cell), cell_name_(cell_name), started_(monotonic_now()), server_(std::make_unique<Server>()) {
  std::string error;
  if (!parse_listen_address(listen, address_, port_, error)) throw std::invalid_argument("operator page: " + error);
  httplib::Server& http = server_->http;
  // Two workers: the page's poll and its view at once; a third request waits its turn.
  http.new_task_queue = [] { return new httplib::ThreadPool(2); };
  http.set_read_timeout(5);
  http.set_write_timeout(5);
  http.set_keep_alive_timeout(5);
  http.set_payload_max_length(4096);
  http.set_default_headers({{"Cache-Control", "no-store"},
                            {"X-Content-Type-Options", "nosniff"},
                            {"Content-Security-Policy",
                             "default-src 'none'; img-src 'self'; connect-src 'self'; script-src 'unsafe-inline'; "
                             "style-src 'unsafe-inline'"}});
  http.set_pre_routing_handler([](const httplib::Request& req, httplib::Response& res) {
    if (req.method == "GET" || req.method == "HEAD") return httplib::Server::HandlerResponse::Unhandled;
    res.status = 405;
    res.set_header("Allow", "GET, HEAD");
    res.set_content("markcell's operator page is read-only: GET and HEAD only\n", "text/plain");
    return httplib::Server::HandlerResponse::Handled;
  });
  http.Get("/", [](const httplib::Request&, httplib::Response& res) {
    res.set_content(kOperatorPageHtml, "text/html; charset=utf-8");
  });
  http.Get("/api/state", [this](const httplib::Request&, httplib::Response& res) {
    res.set_content(state_json(), "application/json");
  });
  http.Get("/metrics", [this](const httplib::Request&, httplib::Response& res) {
    res.set_content(metrics_text(), "text/plain; version=0.0.4; charset=utf-8");
  });
  http.Get("/view.jpg", [this](const httplib::Request&, httplib::Response& res) {
    std::vector<unsigned char> jpeg = view_jpeg();
    if (jpeg.empty()) {
      res.status = 503;
      res.set_header("Retry-After", "1");
      res.set_content("no tracked stereo pair yet\n", "text/plain");
      return;
    }
    res.set_content(reinterpret_cast<const char*>(jpeg.data()), jpeg.size(), "image/jpeg");
  });
  if (!http.bind_to_port(address_, port_)) {
    const int err = errno;
    throw std::runtime_error("operator page: cannot listen on " + listen + ": " +
                             (err != 0 ? std::strerror(err) : "the address is taken or not this machine's"));
  }
}

OperatorPage::~OperatorPage() {
  server_->http.stop();
  if (thread_.joinable()) thread_.join();
}

void OperatorPage::start() {
  if (thread_.joinable()) return;
  thread_ = std::thread([this] { server_->http.listen_after_bind(); });
}

OperatorState OperatorPage::copy_state() {
  std::lock_guard<std::mutex> lock(state_mutex_);
  return state_;
}

std::string OperatorPage::state_json() {
  const OperatorState s = copy_state();
  Json j;
  j["cell"] = cell_name_;
  j["version"] = build_version();
  j["commit"] = build_commit();
  j["uptime_s"] = round2(to_seconds(monotonic_now() - started_));
  j["status"] = s.status;
  j["safe_stop"] = {{"active", s.safe_stop}, {"code", s.stop_code}, {"source", s.stop_source}, {"detail", s.stop_detail}};
  if (s.has_marking) {
    const control::MarkingProgress& p = s.progress;
    Json defects = Json::array();
    for (int i = 0; i < p.defects.ssize(); ++i) {
      const control::DefectProgress& d = p.defects[static_cast<std::size_t>(i)];
      Json o{{"id", d.id}, {"state", defect_state(d, i == p.current)}};
      if (d.skipped != control::SkipReason::kNone) o["reason"] = control::to_string(d.skipped);
      defects.push_back(std::move(o));
    }
    j["marking"] = {{"state", control::to_string(p.state)},
                    {"on_panel", p.on_panel},
                    {"panel", p.panel_serial},
                    {"panel_id", p.panel_id.view()},
                    {"panel_type", p.panel_type.view()},
                    {"defects", std::move(defects)}};
  } else {
    j["marking"] = nullptr;
  }
  j["counts"] = {{"panels_done", s.panels_done},           {"panels_fault", s.panels_fault},
                 {"defects_sprayed", s.defects_sprayed},   {"defects_skipped", s.defects_skipped},
                 {"faults", s.faults_total},               {"records_accepted", s.records_accepted},
                 {"records_rejected", s.records_rejected}};
  if (const VisionStats* v = cell_.vision_stats())
    j["vision"] = {{"frames", v->frames.load()}, {"dropped", v->dropped.load()}, {"poses", v->poses.load()},
                   {"stalls", v->stalls.load()}};
  const control::Executive& exec = cell_.executive();
  const control::ExecutiveSpec& spec = exec.spec();
  Json tasks = Json::array(), lanes = Json::array();
  for (std::size_t i = 0; i < spec.tasks.size(); ++i) {
    const control::TaskSpec& t = spec.tasks[i];
    const control::TaskStats& st = exec.task_stats(static_cast<int>(i));
    const double budget = micros(t.budget);
    tasks.push_back({{"name", t.name},
                     {"lane", spec.lanes[static_cast<std::size_t>(t.lane)].name},
                     {"period_ms", round2(to_seconds(static_cast<Nanos>(t.period_ticks) * spec.tick) * 1e3)},
                     {"budget_us", round2(budget)},
                     {"runs", st.exec.count()},
                     {"p50_us", round2(micros(st.exec.percentile(0.5)))},
                     {"p99_us", round2(micros(st.exec.percentile(0.99)))},
                     {"max_us", round2(micros(st.exec.max()))},
                     {"use_pct", budget > 0 ? round2(100.0 * micros(st.exec.percentile(0.99)) / budget) : 0.0},
                     {"overruns", st.overruns.load()},
                     {"misses", st.deadline_misses.load()},
                     {"skipped", st.skipped.load()},
                     {"faults", st.faults.load()}});
  }
  for (std::size_t l = 0; l < spec.lanes.size(); ++l) {
    const control::LaneStats& ls = exec.lane_stats(static_cast<int>(l));
    lanes.push_back({{"name", spec.lanes[l].name},
                     {"ticks", ls.ticks.load()},
                     {"missed", ls.missed_ticks.load()},
                     {"wake_p50_us", round2(micros(ls.wake_latency.percentile(0.5)))},
                     {"wake_p99_us", round2(micros(ls.wake_latency.percentile(0.99)))},
                     {"wake_max_us", round2(micros(ls.wake_latency.max()))}});
  }
  j["timing"] = {{"tasks", std::move(tasks)}, {"lanes", std::move(lanes)}};
  Json results = Json::array();
  for (auto it = s.results.rbegin(); it != s.results.rend(); ++it) {
    Json r = Json::parse(*it, nullptr, false);  // the results file's own lines
    if (!r.is_discarded()) results.push_back(std::move(r));
  }
  j["results"] = std::move(results);  // newest first
  Json faults = Json::array();
  for (auto it = s.faults.rbegin(); it != s.faults.rend(); ++it)
    faults.push_back({{"t_s", round2(it->time_s)}, {"utc", it->utc}, {"code", it->code}, {"source", it->source}, {"detail", it->detail}});
  j["faults"] = std::move(faults);  // newest first
  // Strings from outside (panel ids, fault details) may hold anything: invalid UTF-8 is
  // replaced rather than refused, so the page always gets its state.
  return j.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

std::string OperatorPage::metrics_text() {
  const OperatorState s = copy_state();
  std::string out;
  out.reserve(8192);
  family(out, "markcell_build_info", "gauge", "the running build (value 1)");
  append(out, "markcell_build_info{version=\"%s\",commit=\"%s\",cell=\"%s\"} 1\n", label(build_version()).c_str(),
         label(build_commit()).c_str(), label(cell_name_).c_str());
  family(out, "markcell_uptime_seconds", "gauge", "seconds since the service started");
  append(out, "markcell_uptime_seconds %.3f\n", to_seconds(monotonic_now() - started_));
  family(out, "markcell_safe_stop", "gauge", "1 while the cell is in a safe stop (valve closed, arm held)");
  append(out, "markcell_safe_stop %d\n", s.safe_stop ? 1 : 0);
  if (s.has_marking) {
    family(out, "markcell_marking_state", "gauge", "the marking sequence's state (1 for the current one)");
    for (int i = 0; i <= static_cast<int>(control::MarkingState::kWaitRelease); ++i) {
      const auto st = static_cast<control::MarkingState>(i);
      append(out, "markcell_marking_state{state=\"%s\"} %d\n", std::string(control::to_string(st)).c_str(),
             st == s.progress.state ? 1 : 0);
    }
  }
  family(out, "markcell_panels_total", "counter", "panels finished since the start, by result");
  append(out, "markcell_panels_total{result=\"done\"} %llu\n", static_cast<unsigned long long>(s.panels_done));
  append(out, "markcell_panels_total{result=\"fault\"} %llu\n", static_cast<unsigned long long>(s.panels_fault));
  family(out, "markcell_defects_total", "counter", "defects of finished panels, by outcome");
  append(out, "markcell_defects_total{outcome=\"sprayed\"} %llu\n", static_cast<unsigned long long>(s.defects_sprayed));
  append(out, "markcell_defects_total{outcome=\"skipped\"} %llu\n", static_cast<unsigned long long>(s.defects_skipped));
  family(out, "markcell_records_total", "counter", "inspection records taken from the record folder, by verdict");
  append(out, "markcell_records_total{verdict=\"accepted\"} %llu\n", static_cast<unsigned long long>(s.records_accepted));
  append(out, "markcell_records_total{verdict=\"rejected\"} %llu\n", static_cast<unsigned long long>(s.records_rejected));
  family(out, "markcell_faults_total", "counter", "faults recorded since the start");
  append(out, "markcell_faults_total %llu\n", static_cast<unsigned long long>(s.faults_total));
  if (const VisionStats* v = cell_.vision_stats()) {
    family(out, "markcell_vision_frames_total", "counter", "stereo pairs the vision task received");
    append(out, "markcell_vision_frames_total %llu\n", static_cast<unsigned long long>(v->frames.load()));
    family(out, "markcell_vision_dropped_frames_total", "counter", "pairs the frame source could not deliver");
    append(out, "markcell_vision_dropped_frames_total %llu\n", static_cast<unsigned long long>(v->dropped.load()));
    family(out, "markcell_vision_poses_total", "counter", "pairs that gave the panel's pose");
    append(out, "markcell_vision_poses_total %llu\n", static_cast<unsigned long long>(v->poses.load()));
    family(out, "markcell_vision_stalls_total", "counter", "times no frame came within the source's timeout");
    append(out, "markcell_vision_stalls_total %llu\n", static_cast<unsigned long long>(v->stalls.load()));
  }
  const control::Executive& exec = cell_.executive();
  const control::ExecutiveSpec& spec = exec.spec();
  // A Prometheus summary of one histogram: its quantiles, sum and count, under one label.
  const auto summary = [&](const char* metric, const char* key, const std::string& value, const control::Histogram& h,
                           std::initializer_list<double> quantiles) {
    for (const double q : quantiles)
      append(out, "%s{%s=\"%s\",quantile=\"%g\"} %.9f\n", metric, key, value.c_str(), q, to_seconds(h.percentile(q)));
    append(out, "%s_sum{%s=\"%s\"} %.9f\n", metric, key, value.c_str(), h.mean() * 1e-9 * static_cast<double>(h.count()));
    append(out, "%s_count{%s=\"%s\"} %llu\n", metric, key, value.c_str(), static_cast<unsigned long long>(h.count()));
  };
  family(out, "markcell_task_exec_seconds", "summary", "CPU time per run of each task (log-linear histogram, within 6.25 %)");
  for (std::size_t i = 0; i < spec.tasks.size(); ++i)
    summary("markcell_task_exec_seconds", "task", label(spec.tasks[i].name), exec.task_stats(static_cast<int>(i)).exec,
            {0.5, 0.99});
  family(out, "markcell_task_budget_seconds", "gauge", "each task's execution budget");
  for (const control::TaskSpec& t : spec.tasks)
    append(out, "markcell_task_budget_seconds{task=\"%s\"} %.9f\n", label(t.name).c_str(), to_seconds(t.budget));
  const auto task_counter = [&](const char* name, const char* help, auto get) {
    family(out, name, "counter", help);
    for (std::size_t i = 0; i < spec.tasks.size(); ++i)
      append(out, "%s{task=\"%s\"} %llu\n", name, label(spec.tasks[i].name).c_str(),
             static_cast<unsigned long long>(get(exec.task_stats(static_cast<int>(i)))));
  };
  task_counter("markcell_task_overruns_total", "runs over their budget",
               [](const control::TaskStats& t) { return t.overruns.load(); });
  task_counter("markcell_task_deadline_misses_total", "runs that finished after their next release",
               [](const control::TaskStats& t) { return t.deadline_misses.load(); });
  task_counter("markcell_task_skipped_total", "releases not run (a degraded or late lane)",
               [](const control::TaskStats& t) { return t.skipped.load(); });
  task_counter("markcell_task_faults_total", "runs that reported a fault",
               [](const control::TaskStats& t) { return t.faults.load(); });
  family(out, "markcell_lane_wakeup_latency_seconds", "summary", "each lane's wake-up minus its scheduled release");
  for (std::size_t l = 0; l < spec.lanes.size(); ++l)
    summary("markcell_lane_wakeup_latency_seconds", "lane", label(spec.lanes[l].name),
            exec.lane_stats(static_cast<int>(l)).wake_latency, {0.5, 0.99, 0.999});
  family(out, "markcell_lane_missed_ticks_total", "counter", "releases a lane skipped because it was late");
  for (std::size_t l = 0; l < spec.lanes.size(); ++l)
    append(out, "markcell_lane_missed_ticks_total{lane=\"%s\"} %llu\n", label(spec.lanes[l].name).c_str(),
           static_cast<unsigned long long>(exec.lane_stats(static_cast<int>(l)).missed_ticks.load()));
  return out;
}

std::vector<unsigned char> OperatorPage::view_jpeg() {
  LiveViewChannel* channel = cell_.live_view();
  const vision::StereoRig* rig = cell_.stereo_rig();
  if (channel == nullptr || rig == nullptr) return {};
  channel->request();  // the next tracked pair for the next request
  control::MarkingProgress progress;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    progress = state_.progress;
  }
  std::lock_guard<std::mutex> lock(view_mutex_);
  const LiveView& v = channel->newest();
  if (v.copies == 0) return {};
  const int w = v.width, h = v.height;
  cv::Mat image(h, 2 * w, CV_8UC3);
  cv::Mat left(h, w, CV_8UC1, const_cast<std::uint8_t*>(v.left.data()));
  cv::Mat right(h, w, CV_8UC1, const_cast<std::uint8_t*>(v.right.data()));
  cv::cvtColor(left, image(cv::Rect(0, 0, w, h)), cv::COLOR_GRAY2BGR);
  cv::cvtColor(right, image(cv::Rect(w, 0, w, h)), cv::COLOR_GRAY2BGR);
  const double s = 1.0 / v.scale;
  const auto at = [&](const Eigen::Vector2d& px, int view) {
    return cv::Point2d(px.x() * s + view * w, px.y() * s);
  };
  // The macro-features: green where used for the pose, yellow where seen but not used.
  for (int i = 0; i < v.pose.mfs.ssize(); ++i) {
    const msg::MacroFeatureObservation& mf = v.pose.mfs[static_cast<std::size_t>(i)];
    if (!mf.valid) continue;
    const cv::Scalar colour = mf.inlier ? cv::Scalar(60, 220, 60) : cv::Scalar(0, 220, 255);
    for (int view = 0; view < 2; ++view) {
      const cv::Point2d p = at(view == 0 ? mf.left : mf.right, view);
      cv::circle(image, p, 6, colour, 2, cv::LINE_AA);
      cv::putText(image, std::to_string(i + 1), p + cv::Point2d(7, -7), cv::FONT_HERSHEY_SIMPLEX, 0.4, colour, 1, cv::LINE_AA);
    }
  }
  // The defects where the marking station places them: on this frame's pose of the P
  // their centres are in. Red pending, orange being marked, blue sprayed, grey skipped.
  if (v.pose.has_pose() && progress.reference_serial != 0 && progress.reference_serial == v.pose.reference_serial) {
    for (int i = 0; i < progress.defects.ssize(); ++i) {
      const control::DefectProgress& d = progress.defects[static_cast<std::size_t>(i)];
      if (!d.placed) continue;
      const std::string_view state = defect_state(d, i == progress.current);
      const cv::Scalar colour = state == "sprayed"   ? cv::Scalar(255, 140, 30)
                                : state == "skipped" ? cv::Scalar(150, 150, 150)
                                : state == "marking" ? cv::Scalar(0, 140, 255)
                                                     : cv::Scalar(40, 40, 230);
      const Eigen::Vector3d p_CamR = v.pose.X_CamR_P * d.centre_P;
      for (int view = 0; view < 2; ++view) {
        const cv::Point2d p = at(rig->project(view == 0 ? vision::Camera::kLeft : vision::Camera::kRight, p_CamR), view);
        cv::drawMarker(image, p, colour, cv::MARKER_TILTED_CROSS, 16, 2, cv::LINE_AA);
        char name[16];  // (not "D" + to_string: GCC 12 at -O3 warns of a memcpy overlap there, wrongly)
        std::snprintf(name, sizeof name, "D%d", d.id);
        cv::putText(image, name, p + cv::Point2d(9, 14), cv::FONT_HERSHEY_SIMPLEX, 0.45, colour, 1,
                    cv::LINE_AA);
      }
    }
  }
  char banner[160];
  std::snprintf(banner, sizeof banner, "frame %llu  %s  %d/%d MFs", static_cast<unsigned long long>(v.seq),
                std::string(msg::to_string(v.pose.status)).c_str(), v.pose.inliers, v.pose.mfs.ssize());
  cv::putText(image, banner, cv::Point(8, 18), cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
  std::vector<unsigned char> jpeg;
  cv::imencode(".jpg", image, jpeg, {cv::IMWRITE_JPEG_QUALITY, 80});
  return jpeg;
}

}  // namespace markcell::host
