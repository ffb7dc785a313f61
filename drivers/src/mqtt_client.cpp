#include "markcell/drivers/mqtt_client.hpp"

#include <mosquitto.h>
#include <mqtt_protocol.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <mutex>

namespace markcell::drivers {

namespace {
std::once_flag g_lib_init;

// libmosquitto's error number as words (its errno for MOSQ_ERR_ERRNO).
std::string mosq_error(int rc) {
  if (rc == MOSQ_ERR_ERRNO) return std::strerror(errno);
  return mosquitto_strerror(rc);
}

// The CONNECT's properties, freed with it.
struct Properties {
  mosquitto_property* p = nullptr;
  ~Properties() { mosquitto_property_free_all(&p); }
};
}  // namespace

MqttClient::MqttClient(MqttClientConfig config) : config_(std::move(config)) {
  std::call_once(g_lib_init, [] { mosquitto_lib_init(); });
  // clean_session false: the broker keeps the station's session (its subscriptions and the
  // QoS 1 messages it missed) for session_expiry_s.
  mosq_ = mosquitto_new(config_.client_id.c_str(), false, this);
  if (mosq_ == nullptr) throw std::runtime_error("MQTT: cannot make a client: " + std::string(std::strerror(errno)));
  // One thread drives the loop while another publishes: libmosquitto must know (without
  // this it takes single-threaded shortcuts that race; mosquitto.h, mosquitto_threaded_set).
  mosquitto_threaded_set(mosq_, true);
  mosquitto_int_option(mosq_, MOSQ_OPT_PROTOCOL_VERSION, MQTT_PROTOCOL_V5);
  mosquitto_int_option(mosq_, MOSQ_OPT_TCP_NODELAY, 1);
  mosquitto_connect_v5_callback_set(mosq_, &MqttClient::on_connect_cb);
  mosquitto_disconnect_v5_callback_set(mosq_, &MqttClient::on_disconnect_cb);
  mosquitto_message_v5_callback_set(mosq_, &MqttClient::on_message_cb);
  mosquitto_publish_v5_callback_set(mosq_, &MqttClient::on_publish_cb);
  mosquitto_subscribe_v5_callback_set(mosq_, &MqttClient::on_subscribe_cb);
  int rc = MOSQ_ERR_SUCCESS;
  if (!config_.username.empty())
    rc = mosquitto_username_pw_set(mosq_, config_.username.c_str(),
                                   config_.password.empty() ? nullptr : config_.password.c_str());
  if (rc == MOSQ_ERR_SUCCESS && !config_.ca_file.empty()) {
    rc = mosquitto_tls_set(mosq_, config_.ca_file.c_str(), nullptr, nullptr, nullptr, nullptr);
    // The broker's certificate must name the address connected to (no insecure mode).
    if (rc == MOSQ_ERR_SUCCESS) rc = mosquitto_tls_opts_set(mosq_, 1, "tlsv1.2", nullptr);
  }
  if (rc == MOSQ_ERR_SUCCESS && !config_.will_topic.empty()) {
    // (the will takes ownership of its properties when accepted)
    mosquitto_property* will_props = nullptr;
    if (!config_.will_schema.empty())
      mosquitto_property_add_string_pair(&will_props, MQTT_PROP_USER_PROPERTY, "schema", config_.will_schema.c_str());
    rc = mosquitto_will_set_v5(mosq_, config_.will_topic.c_str(), static_cast<int>(config_.will_payload.size()),
                               config_.will_payload.data(), 1, true, will_props);
    if (rc != MOSQ_ERR_SUCCESS) mosquitto_property_free_all(&will_props);
  }
  if (rc != MOSQ_ERR_SUCCESS) {
    const std::string why = mosq_error(rc);
    mosquitto_destroy(mosq_);
    throw std::runtime_error("MQTT: client set-up (" + config_.ca_file + "): " + why);
  }
}

MqttClient::~MqttClient() {
  if (mosq_ != nullptr) mosquitto_destroy(mosq_);
}

void MqttClient::set_error(std::string e) {
  std::lock_guard lock(error_mutex_);
  error_ = std::move(e);
}

std::string MqttClient::error() const {
  std::lock_guard lock(error_mutex_);
  return error_;
}

void MqttClient::on_connect_cb(mosquitto*, void* self_v, int rc, int, const mqtt5__property*) {
  auto* self = static_cast<MqttClient*>(self_v);
  self->connack_ = rc;
  if (rc != 0) {
    self->set_error("the broker refused the connection: " + std::string(mosquitto_reason_string(rc)));
    return;
  }
  self->connected_.store(true, std::memory_order_release);
  self->set_error("");
  if (self->on_connect_) self->on_connect_();
}

void MqttClient::on_disconnect_cb(mosquitto*, void* self_v, int rc, const mqtt5__property*) {
  auto* self = static_cast<MqttClient*>(self_v);
  self->connected_.store(false, std::memory_order_release);
  if (rc != 0 && self->error().empty())
    self->set_error("connection lost: " + std::string(rc == MOSQ_ERR_CONN_LOST ? "the broker went away"
                                                                               : mosquitto_reason_string(rc)));
}

void MqttClient::on_message_cb(mosquitto*, void* self_v, const mosquitto_message* m, const mqtt5__property* props) {
  auto* self = static_cast<MqttClient*>(self_v);
  if (!self->on_message_ || m == nullptr || m->topic == nullptr) return;
  // The user property "schema" (the first one so named; at most 8 looked at).
  std::string schema;
  bool skip = false;
  for (int i = 0; i < 8; ++i, skip = true) {
    char* name = nullptr;
    char* value = nullptr;
    const mosquitto_property* p = mosquitto_property_read_string_pair(props, MQTT_PROP_USER_PROPERTY, &name, &value, skip);
    const bool found = p != nullptr && name != nullptr && std::strcmp(name, "schema") == 0 && value != nullptr;
    if (found) schema = value;
    std::free(name);
    std::free(value);
    if (p == nullptr || found) break;
    props = p;
  }
  self->on_message_(MqttMessage{std::string_view(m->topic),
                                std::string_view(static_cast<const char*>(m->payload),
                                                 m->payload == nullptr ? 0 : static_cast<std::size_t>(m->payloadlen)),
                                m->retain, schema});
}

void MqttClient::on_publish_cb(mosquitto*, void* self_v, int, int rc, const mqtt5__property*) {
  auto* self = static_cast<MqttClient*>(self_v);
  if (self->unacked_.load(std::memory_order_relaxed) > 0) self->unacked_.fetch_sub(1, std::memory_order_relaxed);
  if (rc >= 0x80) self->set_error("the broker refused a message: " + std::string(mosquitto_reason_string(rc)));
}

void MqttClient::on_subscribe_cb(mosquitto*, void* self_v, int, int count, const int* granted, const mqtt5__property*) {
  auto* self = static_cast<MqttClient*>(self_v);
  if (self->subs_pending_.load(std::memory_order_relaxed) > 0) self->subs_pending_.fetch_sub(1, std::memory_order_relaxed);
  for (int i = 0; i < count; ++i)
    if (granted[i] >= 0x80)
      self->set_error("the broker refused a subscription: " + std::string(mosquitto_reason_string(granted[i])));
}

bool MqttClient::connect(Nanos timeout) {
  Properties props;
  mosquitto_property_add_int32(&props.p, MQTT_PROP_SESSION_EXPIRY_INTERVAL, config_.session_expiry_s);
  mosquitto_property_add_int32(&props.p, MQTT_PROP_MAXIMUM_PACKET_SIZE,
                               static_cast<std::uint32_t>(config_.max_message_bytes + 65'536));
  connack_ = -1;
  const int keepalive = static_cast<int>(std::max<Nanos>(config_.keepalive / seconds(1), 5));
  const int rc = mosquitto_connect_bind_v5(mosq_, config_.address.c_str(), config_.port, keepalive, nullptr, props.p);
  if (rc != MOSQ_ERR_SUCCESS) {
    set_error("connect (" + peer() + "): " + (rc == MOSQ_ERR_TLS ? "TLS handshake failed (is the broker's certificate "
                                                                  "signed by the CA file and issued for " +
                                                                      config_.address + "?)"
                                                                : mosq_error(rc)));
    return false;
  }
  const Nanos until = monotonic_now() + timeout;
  while (connack_ < 0 && monotonic_now() < until) {
    const int lrc = mosquitto_loop(mosq_, 10, 1);
    if (lrc != MOSQ_ERR_SUCCESS) {
      if (error().empty())
        set_error("connect (" + peer() + "): " +
                  (lrc == MOSQ_ERR_CONN_LOST ? "the broker closed the connection (TLS or protocol refused)"
                                             : mosq_error(lrc)));
      return false;
    }
  }
  if (connack_ < 0) {
    set_error("connect (" + peer() + "): no answer from the broker within " + std::to_string(timeout / millis(1)) +
              " ms");
    return false;
  }
  return connack_ == 0;
}

bool MqttClient::loop(Nanos timeout, Nanos retry) {
  const int rc = mosquitto_loop(mosq_, static_cast<int>(timeout / millis(1)), 1);
  if (rc == MOSQ_ERR_SUCCESS) return connected();
  connected_.store(false, std::memory_order_release);
  const Nanos now = monotonic_now();
  if (last_retry_ >= 0 && now - last_retry_ < retry) {
    if (timeout > 0) {
      const timespec ts = to_timespec(timeout);
      nanosleep(&ts, nullptr);  // (a dead socket returns at once: do not spin)
    }
    return false;
  }
  last_retry_ = now;
  if (error().empty()) set_error("connection lost: " + mosq_error(rc));
  const int rrc = mosquitto_reconnect(mosq_);
  if (rrc != MOSQ_ERR_SUCCESS) set_error("reconnect (" + peer() + "): " + mosq_error(rrc));
  return false;
}

bool MqttClient::subscribe(const std::string& filter) {
  subs_pending_.fetch_add(1, std::memory_order_relaxed);
  const int rc = mosquitto_subscribe_v5(mosq_, nullptr, filter.c_str(), 1, 0, nullptr);
  if (rc != MOSQ_ERR_SUCCESS) subs_pending_.fetch_sub(1, std::memory_order_relaxed);
  if (rc != MOSQ_ERR_SUCCESS) set_error("subscribe " + filter + ": " + mosq_error(rc));
  return rc == MOSQ_ERR_SUCCESS;
}

bool MqttClient::publish(const std::string& topic, std::string_view payload, bool retain, std::uint32_t expiry_s,
                         const char* schema, const char* content_type) {
  Properties props;
  if (expiry_s > 0) mosquitto_property_add_int32(&props.p, MQTT_PROP_MESSAGE_EXPIRY_INTERVAL, expiry_s);
  if (schema != nullptr) mosquitto_property_add_string_pair(&props.p, MQTT_PROP_USER_PROPERTY, "schema", schema);
  if (content_type != nullptr) mosquitto_property_add_string(&props.p, MQTT_PROP_CONTENT_TYPE, content_type);
  unacked_.fetch_add(1, std::memory_order_relaxed);
  const int rc = mosquitto_publish_v5(mosq_, nullptr, topic.c_str(), static_cast<int>(payload.size()), payload.data(), 1,
                                      retain, props.p);
  if (rc != MOSQ_ERR_SUCCESS) {
    unacked_.fetch_sub(1, std::memory_order_relaxed);
    set_error("publish " + topic + ": " + mosq_error(rc));
  }
  return rc == MOSQ_ERR_SUCCESS;
}

void MqttClient::disconnect() {
  mosquitto_disconnect_v5(mosq_, 0, nullptr);  // (reason 0: normal, the will is not sent)
  for (int i = 0; i < 10 && mosquitto_loop(mosq_, 10, 1) == MOSQ_ERR_SUCCESS; ++i) {
  }
  connected_.store(false, std::memory_order_release);
}

}  // namespace markcell::drivers
