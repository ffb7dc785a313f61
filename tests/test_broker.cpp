// The broker link's pieces that need no broker: the panel id as a topic level (against
// the percent-encoding written out by hand), the topics, and what a station is told when
// the broker is not there or its password file is missing. The broker itself is tested
// against a real mosquitto by line_broker_test.py.
#include <catch2/catch.hpp>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <filesystem>

#include "markcell/drivers/mqtt_client.hpp"
#include "markcell/host/broker_link.hpp"
#include "test_files.hpp"

using namespace markcell;
using namespace markcell::host;

TEST_CASE("a panel id as a topic level: MQTT's separators and wildcards and the escape itself as %XX") {
  CHECK(panel_id_topic_level("paper-door-1") == "paper-door-1");
  CHECK(panel_id_topic_level("VIN:WVW.123_4") == "VIN:WVW.123_4");
  CHECK(panel_id_topic_level("door/0001") == "door%2F0001");
  CHECK(panel_id_topic_level("a#b+c%d") == "a%23b%2Bc%25d");
  CHECK(panel_id_topic_level(std::string("\x7f\xff", 2)) == "%7F%FF");
}

TEST_CASE("a station's topics: its line, its name, the records of every station of the line") {
  const BrokerTopics t("line-1", "mark-2");
  CHECK(t.records == "markcell/line-1/+/record/+");
  CHECK(t.arrival == "markcell/line-1/arrival");
  CHECK(t.state == "markcell/line-1/mark-2/state");
  CHECK(t.result == "markcell/line-1/mark-2/result");
  CHECK(t.record_prefix == "markcell/line-1/mark-2/record/");
}

TEST_CASE("no broker listening: connect says where and why") {
  // A port nothing listens on: bound and closed again.
  int port = 0;
  {
    const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    REQUIRE(::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0);
    socklen_t len = sizeof a;
    REQUIRE(::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) == 0);
    port = ntohs(a.sin_port);
    ::close(fd);
  }
  drivers::MqttClientConfig c;
  c.address = "127.0.0.1";
  c.port = port;
  c.client_id = "test";
  drivers::MqttClient client(c);
  CHECK_FALSE(client.connect(seconds(1)));
  CHECK(client.error() == "connect (127.0.0.1:" + std::to_string(port) + "): Connection refused");
  CHECK_FALSE(client.connected());
}

TEST_CASE("a station whose password file is missing does not start, naming the file") {
  test::TempDir dir;
  BrokerConfig c;
  c.server = "127.0.0.1:8883";
  c.line = "line-1";
  c.station = "mark-1";
  c.username = "mark-1";
  c.password_file = (dir.path() / "none.password").string();
  c.ca_file = (dir.path() / "ca.crt").string();
  CHECK_THROWS_WITH(BrokerLink(c, BrokerLink::Role::kMarking, dir.path().string(), {}, nullptr,
                               [](void*) { return Nanos{0}; }, nullptr),
                    c.password_file + ": cannot open: No such file or directory");
  dir.write("empty.password", "\nsecond line\n");
  c.password_file = (dir.path() / "empty.password").string();
  CHECK_THROWS_WITH(BrokerLink(c, BrokerLink::Role::kMarking, dir.path().string(), {}, nullptr,
                               [](void*) { return Nanos{0}; }, nullptr),
                    c.password_file + ": the password file's first line is empty");
}
