#pragma once
// An MQTT 5 client over libmosquitto (Debian's 2.0.11): TLS with the broker's CA and
// its name checked, a user and password, a persistent session (the broker keeps what
// the station missed), a retained last will, QoS 1. One thread drives it through
// loop(); publish() may be called from another (libmosquitto locks its queues).
//
// What it does not promise: libmosquitto acknowledges a QoS 1 message (PUBACK) before
// its callback has run (lib/handle_publish.c; eclipse/mosquitto#2884), so a station that
// dies inside the callback has acknowledged a message it never kept. markcell's topics
// are laid out so that this cannot lose a record (docs/line.md "Delivery"): records are
// retained on a topic of their own for their expiry, and a station that restarts gets
// every one of them again on subscribing.
#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <string_view>

#include "markcell/common/time.hpp"

struct mosquitto;
struct mosquitto_message;
struct mqtt5__property;

namespace markcell::drivers {

struct MqttClientConfig {
  std::string address;  // IPv4 (TLS checks the broker's certificate against it)
  int port = 8883;
  std::string client_id;
  std::string username;
  std::string password;  // never logged
  std::string ca_file;   // empty: plaintext (loopback tests of refusals only)
  Nanos keepalive = seconds(5);
  std::uint32_t session_expiry_s = 86'400;  // how long the broker keeps the session of a station that is away
  std::size_t max_message_bytes = 4u << 20;  // the broker sends nothing larger (CONNECT's maximum packet size)
  std::string will_topic, will_payload;      // retained, QoS 1 (empty topic: none)
  std::string will_schema;                   // the will's user property "schema" (empty: none)
};

struct MqttMessage {
  std::string_view topic;
  std::string_view payload;
  bool retained = false;
  // The MQTT 5 user property "schema" (the payload's format version), "" when absent.
  std::string_view schema;
};

class MqttClient {
 public:
  using OnMessage = std::function<void(const MqttMessage&)>;
  using OnConnect = std::function<void()>;
  explicit MqttClient(MqttClientConfig config);
  ~MqttClient();
  MqttClient(const MqttClient&) = delete;
  MqttClient& operator=(const MqttClient&) = delete;

  // Called inside loop()/connect(), on the thread that drives the client. on_connect runs
  // after every accepted CONNACK (subscribe there: a reconnect then gets the retained
  // messages again).
  void set_on_message(OnMessage f) { on_message_ = std::move(f); }
  void set_on_connect(OnConnect f) { on_connect_ = std::move(f); }

  // Connects and waits for the broker's answer at most `timeout`. False: why in error()
  // ("connect: Connection refused", "the broker refused: Bad user name or password",
  // "TLS: ...").
  bool connect(Nanos timeout);
  // One pass of the network, waiting at most `timeout` for traffic; a lost connection is
  // reconnected (at most once per `retry`). False: not connected (error() says why).
  bool loop(Nanos timeout, Nanos retry = seconds(1));
  bool connected() const { return connected_.load(std::memory_order_acquire); }
  // QoS 1 subscription (the broker's refusal comes later: error()).
  bool subscribe(const std::string& filter);
  // QoS 1. `expiry_s` > 0: the broker drops it (retained or queued) after that long.
  // `schema` non-empty: sent as the user property "schema", with `content_type`.
  bool publish(const std::string& topic, std::string_view payload, bool retain, std::uint32_t expiry_s = 0,
               const char* schema = nullptr, const char* content_type = nullptr);
  // Messages published and not yet acknowledged by the broker.
  std::size_t unacknowledged() const { return unacked_.load(std::memory_order_relaxed); }
  // Subscriptions the broker has not answered yet.
  int subscriptions_pending() const { return subs_pending_.load(std::memory_order_relaxed); }
  // Sends DISCONNECT (no last will) and closes the connection.
  void disconnect();
  std::string error() const;
  std::string peer() const { return config_.address + ":" + std::to_string(config_.port); }

 private:
  static void on_connect_cb(mosquitto*, void*, int, int, const mqtt5__property*);
  static void on_disconnect_cb(mosquitto*, void*, int, const mqtt5__property*);
  static void on_message_cb(mosquitto*, void*, const mosquitto_message*, const mqtt5__property*);
  static void on_publish_cb(mosquitto*, void*, int, int, const mqtt5__property*);
  static void on_subscribe_cb(mosquitto*, void*, int, int, const int*, const mqtt5__property*);
  void set_error(std::string e);
  MqttClientConfig config_;
  mosquitto* mosq_ = nullptr;
  OnMessage on_message_;
  OnConnect on_connect_;
  std::atomic<bool> connected_{false};
  std::atomic<std::size_t> unacked_{0};
  std::atomic<int> subs_pending_{0};
  int connack_ = -1;  // the last CONNACK's reason (-1: none yet)
  Nanos last_retry_ = -1;
  mutable std::mutex error_mutex_;
  std::string error_;
};

}  // namespace markcell::drivers
