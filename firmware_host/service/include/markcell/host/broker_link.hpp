#pragma once
// A station on the line's MQTT broker (docs/line.md "The broker"): its topics, the
// records it receives or publishes, the line's arrival messages, its retained state and
// its results.
//
//   markcell/<line>/<station>/record/<id>  an inspection station's record of panel <id>
//                                          (the drop folder's text), retained, QoS 1,
//                                          expiring after line.broker.record_retain_s
//   markcell/<line>/arrival                the line's tracking system: which panel comes
//                                          next (JSON, retained)
//   markcell/<line>/<station>/state        the station's state (JSON, retained; last will
//                                          "offline")
//   markcell/<line>/<station>/result       each line of the results file, as appended
//
// Records and results carry the MQTT 5 user property `schema` = kBrokerSchema (their
// format's version; a record with another one is rejected, one without it is taken as
// this version: a plain MQTT client may publish one).
//
// <id> is the panel id with every character but letters, digits and . _ - : written as
// %XX (an id may hold / # +, which MQTT reserves).
//
// A marking station keeps each record it receives as a file in the record folder
// (written, synced, renamed into place) before the folder's reader sees it: the record is
// then paired, accepted or rejected exactly as a file dropped there. A record for a panel
// already answered (accepted or rejected, this run or in the results file) is a
// redelivery and is dropped; so is one already held. A message that cannot be a record
// (the topic's id not valid or not the record's, over the size limit, no end marker, any
// field of the record wrong) is rejected with its reason, saved to rejected/ with it, and
// handed to the service's thread, which logs it, appends it to the results file and
// publishes it on the station's state.
//
// On the real clock a thread drives the client; on the simulated clock the service's loop
// calls poll() once per step.
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "markcell/common/triple_buffer.hpp"
#include "markcell/drivers/mqtt_client.hpp"
#include "markcell/host/config.hpp"
#include "markcell/host/plc_link.hpp"

namespace markcell::host {

inline constexpr const char* kBrokerSchema = "1";

// The topic level (and file-name part) of a panel id: see above.
std::string panel_id_topic_level(std::string_view panel_id);

struct BrokerTopics {
  std::string records;  // the filter a marking station subscribes to
  std::string arrival, state, result;
  std::string record_prefix;  // this station's records: prefix + level(id)
  BrokerTopics(const std::string& line, const std::string& station);
};

struct BrokerEvent {
  std::string topic;
  std::string panel_id;  // when it could be read
  std::string reason;    // what is wrong
  std::string file;      // where the payload was saved ("" when it was not: too large)
};

class BrokerLink {
 public:
  enum class Role { kMarking, kInspection };
  using Now = Nanos (*)(void*);
  static constexpr std::size_t kMaxPayloadBytes = 1 << 20;  // a record's limit (kMaxInspectionRecordBytes)
  static constexpr std::size_t kMaxPendingResults = 10'000;  // results unacknowledged before new ones are dropped
  static constexpr std::size_t kMaxEvents = 256;             // kept for the service's thread (older dropped, counted)
  static constexpr std::size_t kAnsweredIds = 4096;          // redeliveries are caught among these

  // Reads the password file. `spool_folder` (marking): where received records go;
  // `arrivals` (marking with panel_id_source: broker): the marking task's buffer.
  BrokerLink(const BrokerConfig& config, Role role, std::string spool_folder, std::vector<PanelTypeConfig> panel_types,
             TripleBuffer<msg::LineArrival>* arrivals, Now now, void* now_user);
  ~BrokerLink();
  BrokerLink(const BrokerLink&) = delete;
  BrokerLink& operator=(const BrokerLink&) = delete;

  // Connects (and subscribes: a marking station). Throws std::runtime_error naming the
  // broker and why it did not accept (refused, credentials, TLS, no answer).
  void connect();
  void poll(Nanos wait = 0);  // one pass of the network, waiting at most `wait` for traffic (the simulated clock: 0)
  void start_thread();
  // Publishes the state "offline" with `reason`, disconnects (no last will), joins.
  void stop(const std::string& reason);

  // The station's retained state (online, ready, marking, fault, offline); published only
  // when it or its reason changes.
  void publish_state(const std::string& state, const std::string& reason, const std::string& utc);
  // One results-file line on the result topic.
  void publish_result(const std::string& line);
  // An inspection station: the record (validated with the marking station's own reader
  // first: throws RecordInvalid) published retained; waits for the broker's acknowledgement
  // at most `timeout` (false: error()).
  bool publish_record(const std::string& text, const std::string& source, Nanos timeout);

  // Called on the link's thread with each record once it is kept in the folder (`bench
  // broker` accepts it there; the service leaves it to the folder's reader). Set before
  // connect().
  using OnKept = std::function<void(const std::string& panel_id, const std::string& file, std::string_view payload)>;
  void set_on_kept(OnKept f) { on_kept_ = std::move(f); }
  // A panel id answered (accepted or rejected): its record is not taken again.
  void answered(const std::string& panel_id);
  std::vector<BrokerEvent> take_events();
  LineWord word() const;  // the arrivals heard (panel_id_source: broker) and the connection's error
  std::string peer() const { return client_.peer(); }
  bool connected() const { return client_.connected(); }
  const BrokerTopics& topics() const { return topics_; }
  std::uint64_t redeliveries() const { return redeliveries_.load(std::memory_order_relaxed); }
  std::uint64_t results_dropped() const { return results_dropped_.load(std::memory_order_relaxed); }
  std::string error() const { return client_.error(); }

 private:
  void on_message(const drivers::MqttMessage& m);
  void on_record(std::string_view topic, std::string_view payload, std::string_view schema);
  void on_arrival(std::string_view payload);
  void reject(std::string_view topic, std::string_view payload, const std::string& panel_id, const std::string& reason);
  void beat();  // the connection alive: the arrival word heard now
  bool is_answered(const std::string& id) const;
  const BrokerConfig config_;
  const Role role_;
  const BrokerTopics topics_;
  const std::string spool_;
  const std::vector<PanelTypeConfig> panel_types_;
  TripleBuffer<msg::LineArrival>* arrivals_;
  Now now_;
  void* now_user_;
  drivers::MqttClient client_;
  OnKept on_kept_;
  std::atomic<std::uint64_t> redeliveries_{0}, results_dropped_{0};
  mutable std::mutex mutex_;  // what follows
  std::deque<std::string> answered_order_;
  std::set<std::string> answered_;
  std::vector<BrokerEvent> events_;
  std::uint64_t events_dropped_ = 0;
  LineWord word_;
  std::string state_shown_;
  msg::LineArrival last_;  // the link thread's
  std::thread thread_;
  std::mutex stop_mutex_;
  std::condition_variable stop_cv_;
  bool stopping_ = false;
};

}  // namespace markcell::host
