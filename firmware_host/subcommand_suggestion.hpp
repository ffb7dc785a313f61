#pragma once
// What to tell a user whose subcommand does not exist ("chek-config"): the subcommand
// they most likely meant, so a typo costs one look rather than a trip through --help.
#include <CLI/CLI.hpp>
#include <optional>
#include <string>

namespace markcell::host {

// The edit distance between a and b counting an insertion, a deletion, a substitution
// and a swap of two neighbouring characters as one edit each (optimal string alignment).
std::size_t edit_distance(const std::string& a, const std::string& b);

// When argv names a subcommand that `app` (or the subcommand it descends into) does not
// have, the line to print, e.g. "unknown subcommand 'chek-config'; did you mean
// check-config?" or, with nothing close, "unknown subcommand 'x' (known: a, b, c)".
// Only tokens before the first one that is not a subcommand are looked at: the apps
// with subcommands (markcell, bench) take no option with a value, so every other token
// there is a flag. nullopt when every subcommand in argv exists.
std::optional<std::string> unknown_subcommand(const CLI::App& app, int argc, const char* const* argv);

}  // namespace markcell::host
