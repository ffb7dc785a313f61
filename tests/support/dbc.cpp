#include "dbc.hpp"

#include <fstream>
#include <cstdio>
#include <stdexcept>

namespace markcell::test {

Dbc Dbc::load(const std::string& path) {
  // sscanf rather than std::regex: GCC 12 warns falsely inside <regex> at -O1.
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot read " + path);
  Dbc dbc;
  std::string line;
  int number = 0;
  while (std::getline(in, line)) {
    ++number;
    const auto fail = [&] { throw std::runtime_error(path + ":" + std::to_string(number) + ": cannot read: " + line); };
    if (line.rfind("BO_ ", 0) == 0) {
      unsigned id = 0;
      int length = 0;
      char name[64] = {}, sender[64] = {};
      if (std::sscanf(line.c_str(), "BO_ %u %63[^: ]: %d %63s", &id, name, &length, sender) != 4) fail();
      dbc.messages_.push_back(DbcMessage{id, name, length, {}});
    } else if (line.rfind(" SG_ ", 0) == 0) {
      if (dbc.messages_.empty()) fail();
      DbcSignal sig;
      char name[64] = {}, unit[32] = {};
      char order = 0, sign = 0;
      const int n = std::sscanf(line.c_str(), " SG_ %63s : %d|%d@%c%c (%lf,%lf) [%*[^]]] \"%31[^\"]\"", name, &sig.start,
                                &sig.length, &order, &sign, &sig.factor, &sig.offset, unit);
      if (n < 7 || (order != '0' && order != '1') || (sign != '+' && sign != '-')) fail();
      sig.name = name;
      sig.little_endian = order == '1';
      sig.is_signed = sign == '-';
      sig.unit = unit;
      dbc.messages_.back().signals.push_back(sig);
    }
  }
  return dbc;
}

const DbcMessage* Dbc::find(std::uint32_t id) const {
  for (const auto& m : messages_)
    if (m.id == id) return &m;
  return nullptr;
}

const DbcMessage* Dbc::find(const std::string& name) const {
  for (const auto& m : messages_)
    if (m.name == name) return &m;
  return nullptr;
}

std::map<std::string, double> Dbc::decode(std::uint32_t id, const std::uint8_t* data, int length) const {
  const DbcMessage* msg = find(id);
  if (msg == nullptr) throw std::runtime_error("id " + std::to_string(id) + " is not in the catalogue");
  if (length != msg->length)
    throw std::runtime_error(msg->name + ": length " + std::to_string(length) + ", catalogue says " + std::to_string(msg->length));
  std::map<std::string, double> out;
  for (const auto& s : msg->signals) {
    if (!s.little_endian) throw std::runtime_error(s.name + ": big-endian signals are not supported here");
    std::uint64_t raw = 0;
    for (int bit = 0; bit < s.length; ++bit) {
      const int at = s.start + bit;
      if ((data[at / 8] >> (at % 8)) & 1) raw |= std::uint64_t{1} << bit;
    }
    double value = 0;
    if (s.is_signed && s.length < 64 && (raw >> (s.length - 1)) & 1)
      value = static_cast<double>(static_cast<std::int64_t>(raw) - (std::int64_t{1} << s.length));
    else
      value = static_cast<double>(raw);
    out[s.name] = value * s.factor + s.offset;
  }
  return out;
}

}  // namespace markcell::test
