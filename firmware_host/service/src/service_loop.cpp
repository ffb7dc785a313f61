#include "markcell/host/service_loop.hpp"

#include <algorithm>
#include <cstdio>
#include <iostream>
#include <limits>

#include "markcell/common/log_escape.hpp"

namespace markcell::host {
namespace {

// printf into a string (the service loop's thread: it may allocate).
template <typename... Args>
std::string format(const char* fmt, Args... args) {
  const int n = std::snprintf(nullptr, 0, fmt, args...);
  std::string out(static_cast<std::size_t>(n > 0 ? n : 0), '\0');
  std::snprintf(out.data(), out.size() + 1, fmt, args...);
  return out;
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

}  // namespace

void close_interrupted(ResultsFile& results, const std::string& cell, const std::string& utc, RecordFolder* records,
                       const Journal& journal, BrokerLink* broker) {
  const ResultsFile::History h = results.history();
  if (records != nullptr)
    for (const auto& id : h.panel_ids) records->remember(id);
  if (broker != nullptr)
    for (const auto& id : h.panel_ids) broker->answered(id);
  for (const auto& id : h.unfinished) {
    results.append(ResultsFile::interrupted_json(cell, utc, id));
    journal.log(3,
                format("markcell: panel=%s result=fault reason=\"interrupted: markcell stopped after accepting its record "
                       "and before its result\"",
                       escape_log(id).c_str()),
                {{"PANEL_ID", id}, {"PANEL_RESULT", "fault"}, {"REASON", "interrupted"}});
  }
}

std::string pairing_warning(const CellConfig& config) {
  const bool marks = std::any_of(config.executive.tasks.begin(), config.executive.tasks.end(),
                                 [](const control::TaskSpec& t) { return t.name == "marking"; });
  if (!marks || config.record_folder.empty() || config.line.panel_id_source != PanelIdSource::kNone) return {};
  return "line.panel_id_source is none: records pair with panels in the order they come, so a panel taken off the line "
         "between the inspection station and this cell shifts every later pairing by one and the next panel of the same "
         "type is marked with its predecessor's defects (the inter-calibration catches only another panel type); set "
         "line.panel_id_source: modbus or broker (docs/line.md)";
}

ServiceLoop::ServiceLoop(const CellConfig& config, Cell& cell, ServiceOptions options)
    : config_(config), cell_(cell), options_(std::move(options)), script_(options_.plc_events) {
  utc_.simulated = cell.sim_clock() != nullptr;
  if (!config.results_file.empty() && cell.marking() != nullptr) results_ = std::make_unique<ResultsFile>(config.results_file);
  if (!config.record_folder.empty() && cell.marking() != nullptr)
    records_ = std::make_unique<RecordFolder>(config.record_folder, config.panel_types);
  if (!config.line.broker.server.empty() && cell.marking() != nullptr && records_) {
    // Records through the broker, kept in the record folder until used (docs/line.md).
    broker_ = std::make_unique<BrokerLink>(
        config.line.broker, BrokerLink::Role::kMarking, config.record_folder, config.panel_types,
        config.line.panel_id_source == PanelIdSource::kBroker ? &cell.line_arrivals() : nullptr,
        [](void* self) { return static_cast<ServiceLoop*>(self)->now(); }, this);
  }
  if (results_) close_interrupted(*results_, config.name, utc_.at(now()), records_.get(), journal_, broker_.get());
  if (broker_) {
    // The broker must accept this station before anything moves: records come through it.
    try {
      broker_->connect();
    } catch (const std::exception& e) {
      throw std::runtime_error("the broker: " + std::string(e.what()));
    }
    broker_->publish_state("online", "starting", utc_.at(now()));
    if (results_) results_->mirror_to([this](const std::string& line) {
        if (broker_) broker_->publish_result(line);
      });
  }
  if (config.line.panel_id_source == PanelIdSource::kModbus && cell.marking() != nullptr) {
    // The PLC must answer before anything moves: a cell that cannot tell panels apart
    // does not start (systemd retries).
    line_ = std::make_unique<PlcLink>(
        config.line.modbus, cell.gpio_mirror(), cell.safe_stop(), cell.line_arrivals(),
        [](void* self) { return static_cast<ServiceLoop*>(self)->now(); }, this);
    if (!line_->poll()) throw std::runtime_error("the line's PLC: " + line_->word().error);
  }
  if (!options_.pose_log_folder.empty() && cell.vision_stats() != nullptr) {  // a cell with a vision task
    pose_log_ = std::make_unique<PoseLog>(options_.pose_log_folder, options_.pose_log_mode, options_.pose_log_rotate_bytes);
    cell.enable_pose_queue();  // (before start(), or already by whoever started the cell)
  }
  if (options_.operator_page && !config.operator_page.empty()) {
    if (cell.vision_stats() != nullptr) cell.enable_live_view();
    page_ = std::make_unique<OperatorPage>(config.operator_page, config.name, cell);  // bound now: a taken port stops the start
  }
}

ServiceLoop::~ServiceLoop() {
  try {
    write_poses();
  } catch (...) {  // (a log line that could not be made): the poses are on disk
  }
}

void ServiceLoop::write_poses() {
  PoseQueue* queue = cell_.pose_queue();
  if (!pose_log_ || queue == nullptr) return;
  // Bounded: at most what the queue can hold, the rest is the next step's.
  msg::PoseEstimate e;
  for (std::size_t i = 0; i < PoseQueue::capacity() && queue->pop(e); ++i) pose_log_->write(e);
  if (queue->dropped() != poses_dropped_seen_ || pose_log_->failed() != poses_failed_seen_) {
    log(4, format("markcell: pose log: %llu estimates not logged (queue full), %llu lost to write errors (%s)",
                  static_cast<unsigned long long>(queue->dropped()), static_cast<unsigned long long>(pose_log_->failed()),
                  escape_log(pose_log_->poses_path()).c_str()));
    poses_dropped_seen_ = queue->dropped();
    poses_failed_seen_ = pose_log_->failed();
  }
}

// Each finished panel: its result appended and synced, then acknowledged so that the
// marking sequence tells the PLC; one journald line per panel.
void ServiceLoop::collect() {
  control::MarkingSequence* m = cell_.marking();
  if (m == nullptr || m->panels_completed() == written_) return;
  m->results().update();
  const control::PanelResult& r = m->results().read();
  bool late = false;  // the PLC heard fault before the line reached the disk
  if (results_) {
    try {
      results_->append(ResultsFile::to_json(r, config_.name, utc_));
      if (!m->acknowledge_result(r.serial)) {
        late = true;
        results_->append(ResultsFile::late_json(config_.name, utc_.at(now()), r.serial, std::string(r.panel_id.view())));
      }
    } catch (const std::exception& e) {
      late = true;  // never acknowledged: the sequence's wait runs out, the PLC hears fault
      log(3, format("markcell: %s (the PLC gets fault)", escape_log(e.what()).c_str()),
                   {{"PANEL_ID", r.panel_id.view()}});
    }
  }
  // (not a structured binding: clang 14 cannot capture one in the page's lambda)
  const control::PanelResult::Tally tally = r.tally();
  const int sprayed = tally.sprayed, skipped = tally.skipped;
  const bool fault = r.fault || late;
  if (page_) {
    std::string line = ResultsFile::to_json(r, config_.name, utc_);
    while (!line.empty() && line.back() == '\n') line.pop_back();
    if (late) line = ResultsFile::late_json(config_.name, utc_.at(now()), r.serial, std::string(r.panel_id.view()));
    while (!line.empty() && line.back() == '\n') line.pop_back();
    page_->update([&](OperatorState& s) {
      s.results.push_back(std::move(line));
      if (s.results.size() > OperatorState::kKeptResults) s.results.pop_front();
      ++(fault ? s.panels_fault : s.panels_done);
      s.defects_sprayed += static_cast<std::uint64_t>(sprayed);
      s.defects_skipped += static_cast<std::uint64_t>(skipped);
    });
  }
  if (line_) {
    line_->report().panels_done.store(static_cast<std::uint32_t>(r.serial), std::memory_order_relaxed);
    line_->report().last_result.store(fault ? 2 : 1, std::memory_order_relaxed);
  }
  const std::string_view reason = late ? std::string_view("results file not written in time") : r.reason.view();
  const std::string sprayed_text = std::to_string(sprayed), skipped_text = std::to_string(skipped);
  log(fault ? 3 : 6,
               format("markcell: panel=%s result=%s sprayed=%d skipped=%d reason=\"%s\"", escape_log(r.panel_id.view()).c_str(),
                      fault ? "fault" : "done", sprayed, skipped, escape_log(reason).c_str()),
               {{"PANEL_ID", r.panel_id.view()},
                {"PANEL_RESULT", fault ? "fault" : "done"},
                {"SPRAYED", sprayed_text},
                {"SKIPPED", skipped_text},
                {"REASON", reason}});
  written_ = r.serial;
}

// Every fault as it is recorded: one journald line each (the stop's own are listed at the end).
void ServiceLoop::log_faults() {
  control::Fault f;
  while (cell_.faults().pop(f)) {
    if (page_)
      page_->update([&](OperatorState& s) {
        s.faults.push_back({to_seconds(f.time), utc_.at(f.time), std::string(control::to_string(f.code)), f.source.c_str(),
                            f.detail.c_str()});
        if (s.faults.size() > OperatorState::kKeptFaults) s.faults.pop_front();
        ++s.faults_total;
      });
    if (options_.on_fault) {
      options_.on_fault(f);
      continue;
    }
    const std::string code(control::to_string(f.code));
    const std::string utc = utc_.at(f.time);
    log(3,
        format("markcell: fault t=%.6f utc=%s code=%s source=%s detail=\"%s\"", to_seconds(f.time), utc.c_str(), code.c_str(),
               escape_log(f.source.view()).c_str(), escape_log(f.detail.view()).c_str()),
        {{"FAULT_CODE", code}, {"FAULT_SOURCE", f.source.view()}, {"FAULT_DETAIL", f.detail.view()}, {"FAULT_UTC", utc}});
  }
}

// Inspection records from the drop folder, one at a time into the marking sequence; a
// rejected one is logged and recorded in the results file with its reason.
void ServiceLoop::take_records(Nanos now) {
  if (!records_) return;
  std::vector<RecordEvent> events;
  try {
    const auto offer = [&](const control::PanelJob& job) {
      // The accepted line is on disk before the panel can start, so a crash from here
      // on leaves a trace the next start answers (close_interrupted).
      if (!cell_.marking()->can_offer()) return false;
      if (broker_) broker_->answered(std::string(job.panel_id.view()));  // (before the file leaves the folder)
      if (results_)
        results_->append(
            ResultsFile::accepted_json(config_.name, utc_.at(now), records_->offering(), std::string(job.panel_id.view())));
      return cell_.marking()->offer_job(job);
    };
    // Pairing by id: the record of the panel the line announced (nothing while its
    // block is not valid); else in order.
    if (line_ || config_.line.panel_id_source == PanelIdSource::kBroker)
      events = records_->poll_by_id(offer, line_word_.valid ? line_word_.arrival : msg::LineArrival{},
                                    config_.marking.record_expiry, now);
    else
      events = records_->poll(offer, now);
  } catch (const std::exception& e) {  // the folder itself (permissions, a full disk): the cell runs on
    log(3, format("markcell: record folder %s: %s", escape_log(records_->folder()).c_str(), escape_log(e.what()).c_str()),
                 {{"RECORD_FOLDER", records_->folder()}});
    return;
  }
  for (const RecordEvent& ev : events) {
    if (broker_ && !ev.panel_id.empty()) broker_->answered(ev.panel_id);  // (a redelivery of it is dropped)
    if (page_) page_->update([&](OperatorState& s) { ++(ev.kind == RecordEvent::Kind::kAccepted ? s.records_accepted : s.records_rejected); });
    if (ev.kind == RecordEvent::Kind::kAccepted) {
      log(6, format("markcell: record panel=%s accepted (%s)", escape_log(ev.panel_id).c_str(), escape_log(ev.file).c_str()),
                   {{"PANEL_ID", ev.panel_id}, {"RECORD_FILE", ev.file}});
      continue;
    }
    record_rejected(ev.file, ev.panel_id, ev.reason, " (moved to " + escape_log(ev.file) + ")",
                    {{"PANEL_ID", ev.panel_id}, {"RECORD_FILE", ev.file}, {"REJECT_REASON", ev.reason}}, now);
  }
}

void ServiceLoop::record_rejected(const std::string& record, const std::string& panel_id, const std::string& reason,
                                  const std::string& where, std::initializer_list<JournalField> fields, Nanos at) {
  log(3, "markcell: record rejected: " + escape_log(reason) + where, fields);
  if (line_) line_->report().records_rejected.fetch_add(1, std::memory_order_relaxed);
  if (!results_) return;
  try {
    results_->append(ResultsFile::rejected_json(config_.name, utc_.at(at), record, panel_id, reason));
  } catch (const std::exception& e) {
    log(3, "markcell: " + escape_log(e.what()));
  }
}

// The scripted PLC: every event due by `elapsed` (since the start) applied, in order.
void ServiceLoop::apply_plc_events(Nanos elapsed) {
  script_.apply_due(elapsed, [&](const sim::PlcEvent& ev) {
    if (options_.drive) options_.drive(ev.line, ev.level);
    else cell_.drive_sim_input(ev.line, ev.level);
    log(6, format("markcell: plc-script t=%.3f s %s=%d", to_seconds(ev.at), std::string(to_string(ev.line)).c_str(),
                           ev.level ? 1 : 0));
  });
}

void ServiceLoop::watch_line() {
  LineWord w;
  std::string peer;
  if (line_) {
    if (cell_.sim_clock() != nullptr) line_->poll();  // (the real clock: its own thread polls)
    w = line_->word();
    peer = line_->peer();
  } else if (broker_ && config_.line.panel_id_source == PanelIdSource::kBroker) {
    w = broker_->word();  // (the connection's losses are watch_broker's)
    if (w.valid) w.error.clear();
    peer = broker_->peer();
  } else {
    return;
  }
  if (!w.error.empty() && w.error != line_word_.error) {
    if (!w.valid)
      log(3, "markcell: line: the PLC's block is not valid, nothing announced: " + escape_log(w.error),
          {{"LINE_ERROR", w.error}});
    else if (!line_failing_)
      log(3, "markcell: line: the PLC does not answer (the cell stops after line.silent_ms): " + escape_log(w.error),
          {{"LINE_ERROR", w.error}});
  }
  if (w.error.empty() && line_failing_) log(6, "markcell: line: the PLC at " + peer + " answers again");
  line_failing_ = !w.error.empty() && w.valid;
  if (w.arrival.counter != line_word_.arrival.counter && w.arrival.counter != 0) {
    const std::string id(w.arrival.panel_id.view()), type(w.arrival.panel_type.view()), n = std::to_string(w.arrival.counter);
    log(6,
        format("markcell: line: panel %s%s%s announced (arrival %s)", escape_log(id).c_str(), type.empty() ? "" : " type ",
               escape_log(type).c_str(), n.c_str()),
        {{"PANEL_ID", id}, {"PANEL_TYPE", type}, {"LINE_ARRIVAL", n}});
  }
  line_word_ = std::move(w);
}

void ServiceLoop::watch_broker() {
  if (!broker_) return;
  if (cell_.sim_clock() != nullptr) broker_->poll();  // (the real clock: its own thread)
  const std::string error = broker_->error();
  const bool down = !broker_->connected();
  if (down && !broker_down_)
    log(3, "markcell: broker: " + escape_log(error.empty() ? "not connected" : error) +
               " (records wait at the broker; retrying)",
        {{"BROKER_ERROR", error}});
  if (!down && broker_down_) log(6, "markcell: broker: connected again to " + broker_->peer());
  broker_down_ = down;
  std::string last_reason;
  for (const BrokerEvent& ev : broker_->take_events()) {
    if (page_) page_->update([&](OperatorState& s) { ++s.records_rejected; });
    record_rejected(ev.file.empty() ? ev.topic : ev.file, ev.panel_id, ev.reason,
                    ev.file.empty() ? std::string() : " (saved to " + escape_log(ev.file) + ")",
                    {{"PANEL_ID", ev.panel_id}, {"RECORD_TOPIC", ev.topic}, {"REJECT_REASON", ev.reason}}, now());
    last_reason = "record rejected: " + ev.reason;
  }
  // The station's state for the line: fault (with the safe stop's reason), marking (a
  // panel in hand) or ready; a rejected message is said on it with the state as it is.
  const control::SafeStop& stop = cell_.safe_stop();
  const control::MarkingSequence* m = cell_.marking();
  std::string state = "ready", reason = last_reason;
  if (stop.done()) {
    state = "fault";
    const control::Fault& why = stop.reason();
    reason = std::string(control::to_string(why.code)) + " from " + std::string(why.source.view()) + ": " +
             std::string(why.detail.view());
  } else if (m != nullptr && m->state() != control::MarkingState::kIdle) {
    state = "marking";
  }
  if (!last_reason.empty() || state != broker_state_) {
    broker_->publish_state(state, reason, utc_.at(now()));
    broker_state_ = state;
  }
}

void ServiceLoop::log(int priority, std::string_view text, std::initializer_list<JournalField> fields) const {
  if (options_.journal) journal_.log(priority, text, fields);
}

Nanos ServiceLoop::now() const { return cell_.sim_clock() != nullptr ? cell_.sim_clock()->global_now() : monotonic_now(); }

Nanos ServiceLoop::elapsed() const { return now() - start_; }

// The service's state in systemd's status line, and the exit on a fault of the cell
// itself: a stop the PLC caused waits for its re-arm (docs/safety.md); any other stop
// (a lane stall, an overrun, a device or task fault) ends the process with exit 1,
// so that systemd's Restart=on-failure brings the cell up anew.
bool ServiceLoop::watch_safety() {
  control::SafeStop& stop = cell_.safe_stop();
  std::string status;
  if (stop.done()) {
    const control::Fault& why = stop.reason();
    status = "safe stop (" + std::string(control::to_string(why.code)) + ", " + why.source.c_str() + ": " + why.detail.c_str() +
             ")" + (stop.internal_fault() ? ": exiting for a restart"
                    : config_.safe_stop.rearm == RearmConfig::kNever ? ": restart the service to re-arm"
                    : stop.rearm_requested() ? ": re-arming, the arm going home"
                                             : ": waiting for the e-stop's release, then a cycle-enable edge");
  } else {
    const control::MarkingSequence* m = cell_.marking();
    status = "running";
    if (m != nullptr) status += ": marking " + std::string(control::to_string(m->state())) + ", " + std::to_string(m->panels_completed()) + " panel(s)";
  }
  if (status != status_shown_) {
    if (config_.watchdog.systemd) cell_.notifier().status(status);
    if (stop.done() || status_shown_.rfind("safe stop", 0) == 0)
      log(stop.done() ? 4 : 6, "markcell: " + escape_log(status), {{"CELL_STATE", status}});
    status_shown_ = status;
  }
  return stop.done() && stop.internal_fault();
}

void ServiceLoop::refresh_page() {
  if (!page_) return;
  control::SafeStop& stop = cell_.safe_stop();
  control::MarkingSequence* m = cell_.marking();
  if (m != nullptr) m->progress().update();  // (this thread is its one reader)
  page_->update([&](OperatorState& s) {
    s.status = status_shown_;
    s.safe_stop = stop.done();
    if (s.safe_stop) {
      const control::Fault& why = stop.reason();
      s.stop_code = control::to_string(why.code);
      s.stop_source = why.source.c_str();
      s.stop_detail = why.detail.c_str();
    } else {
      s.stop_code.clear();
      s.stop_source.clear();
      s.stop_detail.clear();
    }
    s.has_marking = m != nullptr;
    if (m != nullptr) s.progress = m->progress().read();
  });
}

LoopEnd ServiceLoop::supervise(const StopWait& wait) {
  const LoopEnd end = supervise_steps(wait);
  write_poses();
  return end;
}

LoopEnd ServiceLoop::supervise_steps(const StopWait& wait) {
  const bool simulated = cell_.sim_clock() != nullptr;
  const Nanos step = options_.step > 0 ? options_.step : simulated ? millis(100) : millis(50);
  constexpr Nanos kForever = std::numeric_limits<Nanos>::max() / 2;
  const Nanos duration = options_.duration > 0 ? options_.duration : kForever;
  start_ = now();
  apply_plc_events(0);
  for (;;) {
    // A step: to the next look at the cell, cut at the script's next event. In simulated
    // time the clock runs there; in real time the
    // lanes run on their own and the wait is the step (results are on disk within a step
    // of their panel's end, and a signal ends the wait at once).
    const Nanos from = elapsed();
    const Nanos to = std::min({duration, from + step, from + std::max<Nanos>(1, script_.until_next(from, kForever))});
    if (simulated) {
      // In pieces of 100 ms at most, so a stop is seen within 100 ms of simulated time.
      for (Nanos at = from; at < to;) {
        if ((signal_ = wait(0)) != 0) return LoopEnd::kSignal;
        at = std::min(to, at + millis(100));
        if (cell_.sim_clock()->run_until(start_ + at) == control::SimClock::RunResult::kWedged) return LoopEnd::kWedged;
      }
    } else if ((signal_ = wait(std::max<Nanos>(1, to - from))) != 0) {
      return LoopEnd::kSignal;
    }
    const Nanos t = elapsed();
    apply_plc_events(t);
    collect();
    log_faults();
    watch_line();
    watch_broker();
    take_records(now());
    write_poses();
    if (options_.on_step) options_.on_step(t);
    const bool cell_fault = watch_safety();
    refresh_page();
    if (cell_fault) return LoopEnd::kCellFault;
    if (options_.panels > 0 && cell_.marking() != nullptr && cell_.marking()->panels_completed() >= options_.panels)
      return LoopEnd::kPanels;
    if (t >= duration) return LoopEnd::kDuration;
  }
}

void ServiceLoop::start() {
  const bool simulated = options_.clock == ClockKind::kSimulated;
  cell_.start();
  for (const auto& w : cell_.privilege_warnings()) log(4, "markcell: warning: " + escape_log(w));
  if (const std::string warning = pairing_warning(config_); !warning.empty()) log(4, "markcell: warning: " + warning);
  if (line_) {
    if (!simulated) line_->start_thread();
    log(6, format("markcell: line: records pair with panels by the id the PLC at %s announces (Modbus TCP, unit %d)",
                  line_->peer().c_str(), config_.line.modbus.unit_id));
  }
  if (broker_) {
    if (!simulated) broker_->start_thread();
    log(6, format("markcell: broker: station %s on line %s at %s (TLS, user %s): records on %s%s",
                  config_.line.broker.station.c_str(), config_.line.broker.line.c_str(), broker_->peer().c_str(),
                  escape_log(config_.line.broker.username).c_str(), broker_->topics().records.c_str(),
                  config_.line.panel_id_source == PanelIdSource::kBroker
                      ? (", arrivals on " + broker_->topics().arrival).c_str()
                      : ""));
  }
  if (page_) {
    page_->start();
    log(6, format("markcell: operator page on http://%s:%d/ (read-only; Prometheus metrics at /metrics)",
                  page_->address().c_str(), page_->port()));
  }
  log(6, format("markcell: cell '%s' running on the %s clock", escape_log(config_.name).c_str(),
                         simulated ? "simulated" : "real") +
                      (options_.duration > 0 ? format(" for %g s", to_seconds(options_.duration)) : std::string()));
}

void ServiceLoop::reload() {
  cell_.notifier().reloading();
  log(6, "markcell: SIGHUP: reloading the panel types' recipes from " + escape_log(config_.file));
  if (results_) results_->reopen();
  std::vector<PanelTypeConfig> types;
  try {
    types = reload_recipes(config_, task_catalog());
  } catch (const ConfigInvalid& e) {
    for (const ConfigError& error : e.errors()) log(3, "markcell: reload: " + escape_log(error.to_string()));
    log(4, format("markcell: reload refused (%zu error(s)): the running configuration stays", e.errors().size()));
    cell_.notifier().ready();
    return;
  }
  CellConfig reloaded = config_;
  reloaded.panel_types = std::move(types);
  if (cell_.reload_recipes(reloaded)) {
    std::string changed;
    for (const PanelTypeConfig& p : reloaded.panel_types)
      if (p.has_recipe) changed += (changed.empty() ? "" : ", ") + p.name;
    log(6, format("markcell: reloaded the recipes of %zu panel type(s) (with a recipe: %s); panels whose record is "
                  "taken from now on use them, other changes take a restart",
                  reloaded.panel_types.size(), changed.empty() ? "none" : escape_log(changed).c_str()));
  } else {
    log(4, "markcell: reload: no marking task in the table; nothing to change");
  }
  cell_.notifier().ready();
}

int ServiceLoop::run(const sigset_t& signals) {
  const bool simulated = options_.clock == ClockKind::kSimulated;
  const LoopEnd end = supervise([&](Nanos timeout) {
    const timespec ts = to_timespec(timeout);
    const int sig = sigtimedwait(&signals, nullptr, &ts);
    if (sig == SIGHUP) reload();
    return sig == SIGTERM || sig == SIGINT ? sig : 0;
  });
  std::string stop_reason = "duration elapsed";
  int exit_code = kExitOk;
  switch (end) {
    case LoopEnd::kDuration:
    case LoopEnd::kPanels: break;
    case LoopEnd::kSignal: stop_reason = signal_ == SIGTERM ? "SIGTERM" : "SIGINT"; break;
    case LoopEnd::kWedged: stop_reason = "simulation wedged"; break;
    case LoopEnd::kCellFault:
      stop_reason = "a fault of the cell";
      exit_code = kExitRuntime;
      // A stalled lane may never finish its tick: the outputs are safe already (the
      // safe stop drove them), the results are written; the process ends here.
      if (!simulated && cell_.safe_stop().reason().code == control::FaultCode::kLaneStall) {
        log(3,
            format("markcell: stopped (lane stall: %s), exit 1 without waiting for the lanes",
                   escape_log(cell_.safe_stop().reason().detail.view()).c_str()),
            {{"FAULT_CODE", "lane_stall"}});
        std::fflush(stderr);
        std::_Exit(kExitRuntime);
      }
      break;
  }
  cell_.shutdown(control::FaultCode::kShutdown, "markcell", stop_reason);
  collect();
  if (line_) {  // the PLC's last word from this cell: its stop (then no more answers)
    line_->stop();
    line_->poll();
  }
  write_poses();
  if (results_) {
    try {
      close_interrupted(*results_, config_.name, utc_.at(now()), nullptr, journal_);
    } catch (const std::exception& e) {
      log(3, "markcell: " + escape_log(e.what()));
    }
  }
  if (broker_) broker_->stop(stop_reason);  // its last state: offline, with the reason
  log(6, "markcell: stopped (" + stop_reason + ")");
  std::cout << "\ntiming report (" << (simulated ? "simulated" : "real") << " clock):\n" << cell_.executive().timing_report();
  print_faults(cell_.faults());
  return exit_code;
}

}  // namespace markcell::host
