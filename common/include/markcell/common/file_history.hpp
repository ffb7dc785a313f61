#pragma once
// Files the cell keeps as state and must never lose to a crash or a careless rerun: the
// calibrations (`markcell calibrate-stereo`, `calibrate-base`). Each is replaced
// atomically, and the file it replaces is kept in a dated, bounded history beside it.
#include <cstdint>
#include <ctime>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

namespace markcell {

// `t` (seconds since the epoch) in UTC: 2026-12-07T03:40:12Z.
std::string utc_iso8601(std::time_t t);
// ... and as a file name's part, which sorts by time: 20261207T034012Z.
std::string utc_compact(std::time_t t);
// `ns` (nanoseconds since the epoch) in UTC to the millisecond, rounded down:
// 2026-12-07T03:40:12.345Z (the results file's times, docs/operation.md "Time").
std::string utc_iso8601_ms(std::int64_t ns);

// The history of `path`: its earlier versions, in `history/` beside it, named
// NAME.YYYYMMDDTHHMMSSZ.EXT (with -02, -03 ... for more than one in a second).
inline constexpr int kHistoryKept = 10;        // the newest versions kept per file
inline constexpr int kHistoryScanLimit = 4096;  // entries read from a history folder at most
std::filesystem::path history_folder(const std::filesystem::path& path);
// Its entries, newest first (at most kHistoryScanLimit folder entries looked at).
std::vector<std::filesystem::path> file_history(const std::filesystem::path& path);

struct FileReplacement {
  std::filesystem::path kept;                 // where the previous version went; empty: there was none
  std::vector<std::filesystem::path> pruned;  // history entries removed beyond `keep`
};

// Replaces `path` with what `write(temporary)` writes into a temporary file beside it
// (with the same extension, so a writer that picks a format by it picks the same), so
// that a crash or a power cut at any moment leaves `path` whole, the old version or the
// new one: the temporary file is fsynced, the previous version hard-linked into the
// history (named by its modification time), the temporary file renamed over `path`, and
// both folders fsynced. Then the history is pruned to the newest `keep` versions. A
// `write` that throws leaves `path` and the history untouched (the temporary file
// removed) and the exception goes on. Throws std::runtime_error naming the file, the
// step and the system's reason.
FileReplacement replace_file_keeping_history(const std::filesystem::path& path,
                                             const std::function<void(const std::string& temporary)>& write,
                                             int keep = kHistoryKept);

}  // namespace markcell
