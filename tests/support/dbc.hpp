#pragma once
// A small reader of DBC files (the CAN message catalogue format) for tests: BO_ and
// SG_ lines, little-endian signals, factor and offset. Independent of the codec, so a
// frame the codec encodes is checked against the published catalogue.
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace markcell::test {

struct DbcSignal {
  std::string name;
  int start = 0;
  int length = 0;
  bool little_endian = true;
  bool is_signed = false;
  double factor = 1;
  double offset = 0;
  std::string unit;
};

struct DbcMessage {
  std::uint32_t id = 0;
  std::string name;
  int length = 0;
  std::vector<DbcSignal> signals;
};

class Dbc {
 public:
  static Dbc load(const std::string& path);  // throws on a line it cannot read
  const DbcMessage* find(std::uint32_t id) const;
  const DbcMessage* find(const std::string& name) const;
  // Physical values of every signal of message `id` in `data`.
  std::map<std::string, double> decode(std::uint32_t id, const std::uint8_t* data, int length) const;
  const std::vector<DbcMessage>& messages() const { return messages_; }

 private:
  std::vector<DbcMessage> messages_;
};

}  // namespace markcell::test
