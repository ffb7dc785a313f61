#pragma once
// A path named inside a file that came from outside (a recording's index and manifest, a
// panel-type file's mesh), confined to the folder it is relative to: relative, no "..",
// and, resolved through any symbolic links, still inside the folder. Start-up only.
#include <algorithm>
#include <filesystem>
#include <string>
#include <string_view>

namespace markcell {

// "" when `rel` stays inside `folder`, else why not: `folder_name` names the folder in
// the words ("the recording folder"), `relative_rule` says what paths are relative to.
inline std::string confined_problem(const std::filesystem::path& folder, const std::string& rel, std::string_view folder_name,
                                    std::string_view relative_rule) {
  namespace fs = std::filesystem;
  const fs::path p(rel);
  if (p.is_absolute()) return "is an absolute path (" + std::string(relative_rule) + ")";
  for (const auto& part : p)
    if (part == "..") return "leaves " + std::string(folder_name) + " (..)";
  std::error_code ec;
  const fs::path root = fs::weakly_canonical(folder, ec);
  const fs::path full = fs::weakly_canonical(folder / p, ec);
  if (ec) return "cannot be resolved";
  const auto mismatch = std::mismatch(root.begin(), root.end(), full.begin(), full.end());
  if (mismatch.first != root.end()) return "leads out of " + std::string(folder_name) + " (through a symbolic link)";
  return "";
}

}  // namespace markcell
