#include "test_files.hpp"

#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <catch2/catch.hpp>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace markcell::test {

TempDir::TempDir() {
  std::string tmpl = (std::filesystem::temp_directory_path() / "markcell-test-XXXXXX").string();
  if (mkdtemp(tmpl.data()) == nullptr) throw std::runtime_error("mkdtemp failed");
  path_ = tmpl;
}

TempDir::~TempDir() {
  std::error_code ec;
  std::filesystem::remove_all(path_, ec);
}

std::string TempDir::write(const std::string& name, const std::string& text) const {
  const auto p = path_ / name;
  std::filesystem::create_directories(p.parent_path());
  std::ofstream out(p);
  out << text;
  return p.string();
}

std::string read_file(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot read " + path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::string source_path(const std::string& relative) { return std::string(MARKCELL_SOURCE_DIR) + "/" + relative; }

CommandResult run_command(const std::string& command) {
  CommandResult r;
  FILE* pipe = popen((command + " 2>&1").c_str(), "r");
  if (pipe == nullptr) throw std::runtime_error("popen failed: " + command);
  std::array<char, 4096> buffer{};
  std::size_t n = 0;
  while ((n = fread(buffer.data(), 1, buffer.size(), pipe)) > 0) r.output.append(buffer.data(), n);
  const int status = pclose(pipe);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

void replace_once(std::string& text, const std::string& from, const std::string& to) {
  const auto at = text.find(from);
  INFO("looking for: " << from);
  REQUIRE(at != std::string::npos);
  text.replace(at, from.size(), to);
}

std::string example_config_text(const std::vector<std::pair<std::string, std::string>>& edits) {
  std::string text = read_file(source_path("config/cell.example.yaml"));
  for (const auto& [from, to] : edits) replace_once(text, from, to);
  for (const std::string file : {"calibration/marking_stereo.yaml", "calibration/base.yaml", "panels/door.yaml", "panels/fender.yaml"})
    replace_once(text, " " + file, " " + source_path("config/" + file));
  return text;
}

nlohmann::ordered_json parse_json(const std::string& text) {
  nlohmann::ordered_json j = nlohmann::ordered_json::parse(text, nullptr, false);
  INFO(text.substr(0, 2000));
  REQUIRE_FALSE(j.is_discarded());
  return j;
}

namespace {
// Depth first, in document order: the first member named `name`.
const nlohmann::ordered_json* first_member(const nlohmann::ordered_json& j, const std::string& name) {
  if (j.is_object()) {
    for (auto it = j.begin(); it != j.end(); ++it) {
      if (it.key() == name) return &it.value();
      if (const auto* found = first_member(it.value(), name)) return found;
    }
  } else if (j.is_array()) {
    for (const auto& e : j)
      if (const auto* found = first_member(e, name)) return found;
  }
  return nullptr;
}
}  // namespace

double json_number(const std::string& json, const std::string& section, const std::string& key) {
  const nlohmann::ordered_json doc = parse_json(json);
  const nlohmann::ordered_json* s = first_member(doc, section);
  INFO("section " << section << ", key " << key);
  REQUIRE(s != nullptr);
  // SECTION an object: its KEY; a list of objects: the first one's KEY that has one; a
  // value: itself, when KEY names it.
  const nlohmann::ordered_json* v = key == section && !s->is_structured() ? s : nullptr;
  if (s->is_object() && s->contains(key)) v = &(*s)[key];
  if (s->is_array())
    for (const auto& e : *s)
      if (e.is_object() && e.contains(key)) {
        v = &e[key];
        break;
      }
  REQUIRE(v != nullptr);
  REQUIRE(v->is_number());
  return v->get<double>();
}

}  // namespace markcell::test
