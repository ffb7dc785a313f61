#include "markcell/host/broker_link.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "markcell/common/bounded_file.hpp"
#include "markcell/host/inspection_record.hpp"
#include "markcell/host/json.hpp"
#include "markcell/host/operator_page.hpp"

namespace markcell::host {

namespace fs = std::filesystem;

std::string panel_id_topic_level(std::string_view id) {
  static constexpr char kHex[] = "0123456789ABCDEF";
  std::string out;
  for (const char c : id) {
    const auto u = static_cast<unsigned char>(c);
    if (std::isalnum(u) || c == '.' || c == '_' || c == '-' || c == ':') {
      out += c;
    } else {
      out += '%';
      out += kHex[u >> 4];
      out += kHex[u & 15];
    }
  }
  return out;
}

BrokerTopics::BrokerTopics(const std::string& line, const std::string& station)
    : records("markcell/" + line + "/+/record/+"),
      arrival("markcell/" + line + "/arrival"),
      state("markcell/" + line + "/" + station + "/state"),
      result("markcell/" + line + "/" + station + "/result"),
      record_prefix("markcell/" + line + "/" + station + "/record/") {}

namespace {

std::string state_json(const BrokerConfig& c, BrokerLink::Role role, const std::string& state, const std::string& reason,
                       const std::string& utc) {
  std::string s = "{\"schema\":1,\"station\":" + json_quote(c.station) +
                  ",\"role\":" + json_quote(role == BrokerLink::Role::kMarking ? "marking" : "inspection") +
                  ",\"state\":" + json_quote(state) + ",\"reason\":" + json_quote(reason);
  if (!utc.empty()) s += ",\"utc\":" + json_quote(utc);
  return s + "}";
}

drivers::MqttClientConfig client_config(const BrokerConfig& c, BrokerLink::Role role) {
  drivers::MqttClientConfig d;
  std::string error;
  if (!parse_listen_address(c.server, d.address, d.port, error))
    throw std::invalid_argument("line.broker.server: " + error);  // (the loader has said so already)
  d.client_id = c.station;
  d.username = c.username;
  // The first line of the password file (never logged).
  std::string text = read_bounded_file(c.password_file, 1024, "a broker password file");
  if (const std::size_t nl = text.find_first_of("\r\n"); nl != std::string::npos) text.resize(nl);
  if (text.empty()) throw std::runtime_error(c.password_file + ": the password file's first line is empty");
  d.password = std::move(text);
  d.ca_file = c.ca_file;
  d.keepalive = c.keepalive;
  d.will_topic = BrokerTopics(c.line, c.station).state;
  d.will_payload = state_json(c, role, "offline", "the connection was lost", "");
  d.will_schema = kBrokerSchema;
  return d;
}

// Written next to its final name, synced, renamed into place, the folder synced: once
// the name exists the content is on disk.
void write_synced(const fs::path& to, std::string_view text) {
  const std::string part = to.string() + ".part";
  const int fd = ::open(part.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC | O_NOFOLLOW, 0640);
  if (fd < 0) throw std::runtime_error(part + ": cannot write: " + std::strerror(errno));
  std::size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const int err = errno;
      ::close(fd);
      throw std::runtime_error(part + ": cannot write: " + std::strerror(err));
    }
    done += static_cast<std::size_t>(n);
  }
  const bool synced = ::fsync(fd) == 0;
  ::close(fd);
  if (!synced) throw std::runtime_error(part + ": fsync: " + std::strerror(errno));
  fs::rename(part, to);
  if (const int dfd = ::open(to.parent_path().c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC); dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
}

}  // namespace

BrokerLink::BrokerLink(const BrokerConfig& config, Role role, std::string spool_folder,
                       std::vector<PanelTypeConfig> panel_types, TripleBuffer<msg::LineArrival>* arrivals, Now now,
                       void* now_user)
    : config_(config),
      role_(role),
      topics_(config.line, config.station),
      spool_(std::move(spool_folder)),
      panel_types_(std::move(panel_types)),
      arrivals_(arrivals),
      now_(now),
      now_user_(now_user),
      client_(client_config(config, role)) {
  client_.set_on_message([this](const drivers::MqttMessage& m) { on_message(m); });
  client_.set_on_connect([this] {
    // Every (re)connect subscribes again: the broker then sends every retained record,
    // which is what brings back a record acknowledged but not kept (see the header).
    if (role_ != Role::kMarking) return;
    client_.subscribe(topics_.records);
    if (arrivals_ != nullptr) client_.subscribe(topics_.arrival);
  });
}

BrokerLink::~BrokerLink() {
  {
    std::lock_guard lock(stop_mutex_);
    stopping_ = true;
  }
  stop_cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void BrokerLink::connect() {
  if (!client_.connect(config_.connect_timeout)) throw std::runtime_error(client_.error());
  // The subscriptions' answers: a refusal is an error at start (the broker's ACL is wrong).
  const Nanos until = monotonic_now() + config_.connect_timeout;
  while (client_.subscriptions_pending() > 0 && client_.error().empty() && monotonic_now() < until)
    if (!client_.loop(millis(10))) break;
  if (!client_.error().empty()) throw std::runtime_error(client_.error());
  if (client_.subscriptions_pending() > 0)
    throw std::runtime_error("subscribe (" + client_.peer() + "): no answer from the broker within " +
                             std::to_string(config_.connect_timeout / millis(1)) + " ms");
  beat();
}

void BrokerLink::beat() {
  if (!client_.connected()) return;
  const Nanos now = now_(now_user_);
  if (arrivals_ != nullptr) {
    last_.heard = now;
    arrivals_->write(last_);
  }
  std::lock_guard lock(mutex_);
  word_.arrival.heard = now;
}

void BrokerLink::poll(Nanos wait) {
  client_.loop(wait);
  beat();
  if (!client_.connected()) {
    std::lock_guard lock(mutex_);
    word_.error = client_.error().empty() ? "not connected" : client_.error();
  } else if (word_.valid) {
    std::lock_guard lock(mutex_);
    word_.error.clear();
  }
}

void BrokerLink::start_thread() {
  thread_ = std::thread([this] {
    std::unique_lock lock(stop_mutex_);
    while (!stopping_) {
      lock.unlock();
      client_.loop(millis(10));
      beat();
      {
        std::lock_guard word_lock(mutex_);
        if (!client_.connected()) word_.error = client_.error().empty() ? "not connected" : client_.error();
        else if (word_.valid) word_.error.clear();
      }
      lock.lock();
    }
  });
}

void BrokerLink::stop(const std::string& reason) {
  {
    std::lock_guard lock(stop_mutex_);
    stopping_ = true;
  }
  stop_cv_.notify_all();
  if (thread_.joinable()) thread_.join();
  if (client_.connected()) {
    client_.publish(topics_.state, state_json(config_, role_, "offline", reason, ""), true, 0, kBrokerSchema,
                    "application/json");
    for (int i = 0; i < 50 && client_.unacknowledged() > 0 && client_.loop(millis(10)); ++i) {
    }
  }
  client_.disconnect();
}

void BrokerLink::publish_state(const std::string& state, const std::string& reason, const std::string& utc) {
  {
    std::lock_guard lock(mutex_);
    const std::string key = state + "\n" + reason;
    if (key == state_shown_) return;
    state_shown_ = key;
  }
  client_.publish(topics_.state, state_json(config_, role_, state, reason, utc), true, 0, kBrokerSchema,
                  "application/json");
}

void BrokerLink::publish_result(const std::string& line) {
  if (client_.unacknowledged() >= kMaxPendingResults) {  // (the results file has it)
    results_dropped_.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  client_.publish(topics_.result, line, false, 0, kBrokerSchema, "application/json");
}

bool BrokerLink::publish_record(const std::string& text, const std::string& source, Nanos timeout) {
  if (text.size() > kMaxPayloadBytes)
    throw RecordInvalid(source + ": " + std::to_string(text.size()) + " bytes, more than the " +
                        std::to_string(kMaxPayloadBytes) + " allowed for an inspection record");
  if (!ends_with_end_marker(text))
    throw RecordInvalid(source + ": its last line is not YAML's end-of-document marker '...'");
  const control::PanelJob job = parse_inspection_record(text, source, panel_types_);
  const std::string topic = topics_.record_prefix + panel_id_topic_level(job.panel_id.view());
  const auto expiry = static_cast<std::uint32_t>(config_.record_retain / seconds(1));
  if (!client_.publish(topic, text, true, expiry, kBrokerSchema, "application/yaml")) return false;
  const Nanos until = monotonic_now() + timeout;
  while (client_.unacknowledged() > 0 && monotonic_now() < until) client_.loop(millis(10));
  return client_.unacknowledged() == 0 && client_.error().empty();
}

void BrokerLink::answered(const std::string& id) {
  std::lock_guard lock(mutex_);
  if (!answered_.insert(id).second) return;
  answered_order_.push_back(id);
  if (answered_order_.size() > kAnsweredIds) {
    answered_.erase(answered_order_.front());
    answered_order_.pop_front();
  }
}

bool BrokerLink::is_answered(const std::string& id) const {
  std::lock_guard lock(mutex_);
  return answered_.count(id) != 0;
}

std::vector<BrokerEvent> BrokerLink::take_events() {
  std::lock_guard lock(mutex_);
  std::vector<BrokerEvent> out;
  out.swap(events_);
  return out;
}

LineWord BrokerLink::word() const {
  std::lock_guard lock(mutex_);
  return word_;
}

void BrokerLink::on_message(const drivers::MqttMessage& m) {
  if (role_ != Role::kMarking) return;
  if (m.topic == topics_.arrival) return on_arrival(m.payload);
  on_record(m.topic, m.payload, m.schema);
}

void BrokerLink::reject(std::string_view topic, std::string_view payload, const std::string& panel_id,
                        const std::string& reason) {
  BrokerEvent ev{std::string(topic), panel_id, reason, ""};
  // The payload kept beside its reason, as a rejected file is (not when it is too large).
  if (payload.size() <= kMaxPayloadBytes) {
    try {
      const fs::path dir = fs::path(spool_) / "rejected";
      fs::create_directories(dir);
      const std::string stem = "mqtt-" + panel_id_topic_level(panel_id.empty() ? "unknown" : panel_id);
      fs::path to = dir / (stem + ".yaml");
      for (int k = 1; k <= 100'000 && fs::exists(fs::symlink_status(to)); ++k)
        to = dir / (stem + "." + std::to_string(k) + ".yaml");
      write_synced(to, payload);
      std::ofstream(to.string() + ".reason") << reason << "\n";
      ev.file = to.string();
    } catch (const std::exception& e) {
      ev.reason += " (not saved: " + std::string(e.what()) + ")";
    }
  }
  std::lock_guard lock(mutex_);
  if (events_.size() >= kMaxEvents) {
    ++events_dropped_;
    return;
  }
  events_.push_back(std::move(ev));
}

void BrokerLink::on_record(std::string_view topic, std::string_view payload, std::string_view schema) {
  if (payload.empty()) return;  // a retained record cleared
  const std::string where = "MQTT " + std::string(topic);
  const std::size_t slash = topic.rfind('/');
  const std::string level(topic.substr(slash + 1));
  if (!schema.empty() && schema != kBrokerSchema)
    return reject(topic, payload, "",
                  where + ": schema '" + std::string(schema.substr(0, 32)) + "' is not one this station reads (" +
                      kBrokerSchema + ")");
  if (payload.size() > kMaxPayloadBytes)
    return reject(topic, payload, "",
                  where + ": " + std::to_string(payload.size()) + " bytes, more than the " +
                      std::to_string(kMaxPayloadBytes) + " allowed for an inspection record");
  if (!ends_with_end_marker(payload))
    return reject(topic, payload, "",
                  where + ": its last line is not YAML's end-of-document marker '...' (a record is the drop folder's text)");
  control::PanelJob job;
  try {
    job = parse_inspection_record(std::string(payload), where, panel_types_);
  } catch (const std::exception& e) {
    return reject(topic, payload, "", e.what());
  }
  const std::string id(job.panel_id.view());
  if (panel_id_topic_level(id) != level)
    return reject(topic, payload, id,
                  where + ": panel_id '" + id + "' is not the topic's ('" + level + "'; the topic's level is the id with " +
                      "all but letters, digits and . _ - : as %XX)");
  if (is_answered(id)) {  // a redelivery (a reconnect, a restart): its panel was answered
    redeliveries_.fetch_add(1, std::memory_order_relaxed);
    return;
  }
  const fs::path to = fs::path(spool_) / ("mqtt-" + level + ".yaml");
  std::error_code ec;
  if (fs::exists(fs::symlink_status(to, ec))) {  // held already: the same record again, or another one
    std::string held;
    try {
      held = read_bounded_file(to.string(), kMaxPayloadBytes, "an inspection record", false);
    } catch (const std::exception&) {
    }
    if (held == payload) {
      redeliveries_.fetch_add(1, std::memory_order_relaxed);
      return;
    }
    return reject(topic, payload, id,
                  where + ": panel_id '" + id + "' has another record waiting in the record folder (" + to.string() + ")");
  }
  try {
    write_synced(to, payload);
  } catch (const std::exception& e) {  // (a full disk: the record stays retained at the broker)
    return reject(topic, payload, id, where + ": not kept: " + std::string(e.what()));
  }
  if (on_kept_) on_kept_(id, to.string(), payload);
}

void BrokerLink::on_arrival(std::string_view payload) {
  std::string error;
  msg::LineArrival a = last_;
  if (payload.size() > 4096) {
    error = "the arrival message is " + std::to_string(payload.size()) + " bytes, more than 4096";
  } else {
    const nlohmann::json j = nlohmann::json::parse(payload, nullptr, false);
    const auto field = [&](const char* key) -> const nlohmann::json* {
      return j.is_object() && j.contains(key) ? &j[key] : nullptr;
    };
    if (j.is_discarded() || !j.is_object()) {
      error = "the arrival message is not a JSON object";
    } else if (const auto* s = field("schema"); s == nullptr || !s->is_number_integer() || *s != 1) {
      error = "the arrival message's schema must be 1";
    } else if (const auto* c = field("counter");
               c == nullptr || !c->is_number_unsigned() || c->get<std::uint64_t>() == 0 ||
               c->get<std::uint64_t>() > 0xffffffffu) {
      error = "the arrival message's counter must be an integer from 1 to 4294967295";
    } else if (const auto* id = field("panel_id"); id == nullptr || !id->is_string()) {
      error = "the arrival message has no panel_id (a string)";
    } else if (const std::string why = panel_id_problem(id->get<std::string>()); !why.empty()) {
      error = "the arrival message's panel_id is not valid: " + why;
    } else {
      const auto* t = field("panel_type");
      std::string type = t != nullptr && t->is_string() ? t->get<std::string>() : "";
      if (t != nullptr && !t->is_string()) error = "the arrival message's panel_type must be a string";
      else if (type.size() > 31 || std::any_of(type.begin(), type.end(), [](char ch) { return ch < 0x21 || ch > 0x7e; }))
        error = "the arrival message's panel_type must be at most 31 printable characters";
      else {
        a.counter = static_cast<std::uint32_t>(c->get<std::uint64_t>());
        a.panel_id.assign(id->get<std::string>());
        a.panel_type.assign(type);
      }
    }
  }
  if (error.empty()) {
    last_ = a;
    if (arrivals_ != nullptr) {
      last_.heard = now_(now_user_);
      arrivals_->write(last_);
    }
  }
  {
    std::lock_guard lock(mutex_);
    word_.arrival = last_;
    word_.valid = error.empty();
    word_.error = error;
    ++word_.answers;
  }
  if (!error.empty()) reject(topics_.arrival, payload, "", "MQTT " + topics_.arrival + ": " + error);
}

}  // namespace markcell::host
