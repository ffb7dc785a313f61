#pragma once
// Temporary files and folders for tests, removed when the object goes.
#include <filesystem>
#include <string>

#include <nlohmann/json.hpp>
#include <utility>
#include <vector>

namespace markcell::test {

class TempDir {
 public:
  TempDir();
  ~TempDir();
  const std::filesystem::path& path() const { return path_; }
  // Writes `text` to `name` inside the folder and returns the full path.
  std::string write(const std::string& name, const std::string& text) const;

 private:
  std::filesystem::path path_;
};

std::string read_file(const std::string& path);
std::string source_path(const std::string& relative);  // inside the source tree

// Runs a command through /bin/sh, capturing stdout and stderr together.
struct CommandResult {
  int exit_code = -1;
  std::string output;
};
CommandResult run_command(const std::string& command);

// A JSON text parsed (nlohmann-json, keys in their order); a test failure when it does not parse.
nlohmann::ordered_json parse_json(const std::string& text);
// In a JSON text, the first member named SECTION in document order (the rig's report.json
// lists its predictors' runs in order: the first run's), and in it KEY (in a list of
// objects, the first that has KEY; SECTION itself when KEY names it and it is a value); a
// test failure when either is missing or the value is not a number.
double json_number(const std::string& json, const std::string& section, const std::string& key);

// Replaces the first `from` in `text` by `to`; a test failure naming `from` when absent.
void replace_once(std::string& text, const std::string& from, const std::string& to);

// config/cell.example.yaml with each `from` replaced by its `to`, and its calibration and
// panel files named by absolute paths (so that the text works from any folder).
std::string example_config_text(const std::vector<std::pair<std::string, std::string>>& edits);

}  // namespace markcell::test
