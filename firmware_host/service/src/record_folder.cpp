#include "markcell/host/record_folder.hpp"

#include <sys/stat.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <stdexcept>

#include "markcell/common/bounded_file.hpp"
#include "markcell/host/inspection_record.hpp"

namespace markcell::host {

namespace fs = std::filesystem;

namespace {
// YAML's end-of-document marker on the last line: the writer got to the end.
bool ends_with_marker(const std::string& text) {
  std::size_t end = text.size();
  while (end > 0 && (text[end - 1] == '\n' || text[end - 1] == '\r' || text[end - 1] == ' ')) --end;
  const std::size_t begin = text.rfind('\n', end == 0 ? 0 : end - 1);
  const std::size_t from = begin == std::string::npos ? 0 : begin + 1;
  return end >= from + 3 && text.compare(from, end - from, "...") == 0;
}
}  // namespace

RecordFolder::RecordFolder(std::string folder, std::vector<PanelTypeConfig> panel_types, Nanos incomplete_wait)
    : folder_(std::move(folder)), panel_types_(std::move(panel_types)), incomplete_wait_(incomplete_wait) {
  if (!fs::is_directory(folder_)) throw std::runtime_error("record folder '" + folder_ + "' does not exist");
  fs::create_directories(fs::path(folder_) / "accepted");
  fs::create_directories(fs::path(folder_) / "rejected");
}

std::string RecordFolder::unique_in(const char* sub, const std::string& name) const {
  // A name the station used before (its counter restarted) must not overwrite the earlier
  // record's copy: NAME.yaml, then NAME.1.yaml, NAME.2.yaml ... (bounded).
  const fs::path dir = fs::path(folder_) / sub;
  const std::string stem = fs::path(name).stem().string(), ext = fs::path(name).extension().string();
  fs::path to = dir / name;
  for (int k = 1; k <= 100'000 && fs::exists(fs::symlink_status(to)); ++k) to = dir / (stem + "." + std::to_string(k) + ext);
  return to.string();
}

RecordEvent RecordFolder::reject(const std::string& name, const std::string& reason, const std::string& panel_id) {
  RecordEvent ev;
  ev.kind = RecordEvent::Kind::kRejected;
  ev.reason = reason;
  ev.panel_id = panel_id;
  // rejected/ is made again if someone removed it: the queue must not stick behind a bad file.
  fs::create_directories(fs::path(folder_) / "rejected");
  const std::string to = unique_in("rejected", name);
  fs::rename(fs::path(folder_) / name, to);  // a symlink is moved as the link, a directory whole
  ev.file = to;
  std::ofstream(to + ".reason") << reason << "\n";
  if (parsed_of_ && parsed_of_->name == name) {
    parsed_of_.reset();
    parsed_.reset();
  }
  return ev;
}

std::vector<RecordEvent> RecordFolder::poll(const std::function<bool(const control::PanelJob&)>& offer, Nanos now) {
  std::vector<RecordEvent> events;
  // The candidates, in name order (the station names them in the order it made them).
  std::vector<std::string> names;
  std::size_t looked = 0;
  for (const auto& e : fs::directory_iterator(folder_)) {
    if (++looked > kMaxEntriesPerPoll) break;
    const std::string name = e.path().filename().string();
    if (name.size() > 5 && name.compare(name.size() - 5, 5, ".yaml") == 0) names.push_back(name);
  }
  std::sort(names.begin(), names.end());
  std::vector<Seen> seen_now;
  int rejects = 0;
  // Once a record waits (being written, or for the sequence), none after it is taken or
  // read: order is kept. The later ones are still looked at, so that they count as
  // unchanged at the next poll, and the ones that are no regular file are rejected.
  bool blocked = false;
  for (const std::string& name : names) {
    if (rejects >= kRejectsPerPoll) blocked = true;  // the rest next time (still looked at)
    const std::string path = (fs::path(folder_) / name).string();
    struct stat st {};
    if (::lstat(path.c_str(), &st) != 0) continue;  // gone meanwhile
    if (!S_ISREG(st.st_mode) && rejects < kRejectsPerPoll) {
      ++rejects;
      events.push_back(reject(name, path + ": " + std::string(file_kind(st.st_mode)) +
                                        ", not read (a record must be a regular file, renamed into the folder)"));
      continue;
    }
    if (!S_ISREG(st.st_mode)) continue;
    if (static_cast<std::size_t>(st.st_size) > kMaxRecordBytes && rejects < kRejectsPerPoll) {
      ++rejects;
      events.push_back(reject(name, path + ": " + std::to_string(st.st_size) + " bytes, more than the " +
                                        std::to_string(kMaxRecordBytes) + " allowed for an inspection record"));
      continue;
    }
    Seen cur{name, st.st_dev, st.st_ino, st.st_size,
             static_cast<long long>(st.st_mtim.tv_sec) * 1'000'000'000LL + st.st_mtim.tv_nsec, -1};
    const auto before = std::find(previous_.begin(), previous_.end(), cur);
    if (before != previous_.end()) cur.first_stable = before->first_stable;
    seen_now.push_back(cur);
    // Read only once unchanged since the last poll: a file still being written waits.
    if (blocked || before == previous_.end()) {
      blocked = true;
      continue;
    }
    if (!(parsed_of_ && *parsed_of_ == cur)) {
      parsed_.reset();
      parsed_of_.reset();
      std::string text;
      try {
        text = read_bounded_file(path, kMaxRecordBytes, "an inspection record", false);
      } catch (const FileRefused& e) {
        ++rejects;
        seen_now.pop_back();
        events.push_back(reject(name, e.what()));
        continue;
      }
      if (!ends_with_marker(text)) {
        if (cur.first_stable < 0) seen_now.back().first_stable = cur.first_stable = now;
        if (now - cur.first_stable < incomplete_wait_) {  // still being written, perhaps: it waits
          blocked = true;
          continue;
        }
        ++rejects;
        seen_now.pop_back();
        events.push_back(reject(name, path + ": incomplete: its last line is not YAML's end-of-document marker '...' (written in "
                                              "place and never finished? write NAME.yaml.part, then rename it)"));
        continue;
      }
      try {
        control::PanelJob job = parse_inspection_record(text, path, panel_types_);
        const std::string id(job.panel_id.view());
        if (std::find(recent_ids_.begin(), recent_ids_.end(), id) != recent_ids_.end())
          throw RecordInvalid(path + ": panel_id: '" + id + "' was already received (a duplicate record)");
        parsed_ = std::move(job);
        parsed_of_ = cur;
      } catch (const RecordInvalid& e) {
        ++rejects;
        seen_now.pop_back();
        events.push_back(reject(name, e.what()));
        continue;
      }
    }
    offering_ = unique_in("accepted", name);
    if (!offer(*parsed_)) {  // the sequence still holds one: this waits, parsed
      blocked = true;
      continue;
    }
    RecordEvent ev;
    ev.kind = RecordEvent::Kind::kAccepted;
    ev.panel_id = std::string(parsed_->panel_id.view());
    remember(ev.panel_id);
    fs::create_directories(fs::path(folder_) / "accepted");
    fs::rename(path, offering_);
    ev.file = offering_;
    events.push_back(ev);
    parsed_.reset();
    parsed_of_.reset();
    seen_now.pop_back();
    blocked = true;  // one record a poll
  }
  previous_ = std::move(seen_now);
  return events;
}

void RecordFolder::remember(const std::string& panel_id) {
  recent_ids_.push_back(panel_id);
  if (recent_ids_.size() > kRecentIds) recent_ids_.pop_front();
}

}  // namespace markcell::host
