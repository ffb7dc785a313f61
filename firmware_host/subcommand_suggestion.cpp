#include "subcommand_suggestion.hpp"

#include <algorithm>
#include <array>
#include <vector>

namespace markcell::host {

std::size_t edit_distance(const std::string& a, const std::string& b) {
  // Three rows of the dynamic programme (the swap looks two rows back). Start-up code on
  // a command line of a few words: allocation is fine here.
  const std::size_t n = b.size();
  std::vector<std::size_t> two_back(n + 1), back(n + 1), row(n + 1);
  for (std::size_t j = 0; j <= n; ++j) back[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    row[0] = i;
    for (std::size_t j = 1; j <= n; ++j) {
      const std::size_t substitution = back[j - 1] + (a[i - 1] == b[j - 1] ? 0 : 1);
      row[j] = std::min({back[j] + 1, row[j - 1] + 1, substitution});
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1])
        row[j] = std::min(row[j], two_back[j - 2] + 1);
    }
    std::swap(two_back, back);
    std::swap(back, row);
  }
  return back[n];
}

namespace {

// `path`: the subcommands above `app` as typed ("bench "), so the line names the whole
// command the user meant.
std::string suggestion(const CLI::App& app, const std::string& path, const std::string& given) {
  std::vector<std::string> names;
  for (const CLI::App* sub : app.get_subcommands([](const CLI::App*) { return true; })) names.push_back(sub->get_name());
  // Close enough to be a typo: one edit per three letters typed, at least one ("sel" is
  // two edits from "sim", and is not a typo of it).
  std::string best;
  std::size_t best_distance = std::max<std::size_t>(1, given.size() / 3) + 1;
  for (const std::string& name : names) {
    const std::size_t d = edit_distance(given, name);
    if (d < best_distance) best_distance = d, best = name;
  }
  // A prefix of exactly one name ("calib" is not: two names start so) counts too.
  if (best.empty()) {
    std::vector<std::string> starting;
    for (const std::string& name : names)
      if (name.rfind(given, 0) == 0) starting.push_back(name);
    if (starting.size() == 1) best = starting.front();
  }
  if (!best.empty()) return "unknown subcommand '" + path + given + "'; did you mean " + path + best + "?";
  std::string known;
  for (const std::string& name : names) known += (known.empty() ? "" : ", ") + name;
  return "unknown subcommand '" + path + given + "' (known: " + known + ")";
}

}  // namespace

std::optional<std::string> unknown_subcommand(const CLI::App& app, int argc, const char* const* argv) {
  const CLI::App* at = &app;
  std::string path;
  for (int i = 1; i < argc; ++i) {
    const std::string token = argv[i];
    if (token.empty() || token.front() == '-') continue;  // a flag (--help, --version)
    const auto subs = at->get_subcommands([](const CLI::App*) { return true; });
    if (subs.empty()) return std::nullopt;  // a leaf's argument: its own parser judges it
    const auto match = std::find_if(subs.begin(), subs.end(), [&](const CLI::App* s) { return s->check_name(token); });
    if (match == subs.end()) return suggestion(*at, path, token);
    at = *match;
    path += token + " ";
  }
  return std::nullopt;
}

}  // namespace markcell::host
