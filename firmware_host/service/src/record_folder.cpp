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

std::vector<std::string> RecordFolder::candidates() const {
  std::vector<std::string> names;
  std::size_t looked = 0;
  for (const auto& e : fs::directory_iterator(folder_)) {
    if (++looked > kMaxEntriesPerPoll) break;
    const std::string name = e.path().filename().string();
    if (name.size() > 5 && name.compare(name.size() - 5, 5, ".yaml") == 0) names.push_back(name);
  }
  std::sort(names.begin(), names.end());
  return names;
}

RecordFolder::Look RecordFolder::look(const std::string& name, Seen& cur, bool may_reject, std::vector<RecordEvent>& events) {
  const std::string path = (fs::path(folder_) / name).string();
  struct stat st {};
  if (::lstat(path.c_str(), &st) != 0) return Look::kGone;  // gone meanwhile
  if (!S_ISREG(st.st_mode)) {
    if (!may_reject) return Look::kSkipped;
    events.push_back(reject(name, path + ": " + std::string(file_kind(st.st_mode)) +
                                      ", not read (a record must be a regular file, renamed into the folder)"));
    return Look::kRejected;
  }
  if (static_cast<std::size_t>(st.st_size) > kMaxRecordBytes) {
    if (!may_reject) return Look::kSkipped;
    events.push_back(reject(name, path + ": " + std::to_string(st.st_size) + " bytes, more than the " +
                                      std::to_string(kMaxRecordBytes) + " allowed for an inspection record"));
    return Look::kRejected;
  }
  cur = Seen{name, st.st_dev, st.st_ino, st.st_size,
             static_cast<long long>(st.st_mtim.tv_sec) * 1'000'000'000LL + st.st_mtim.tv_nsec, -1};
  const auto before = std::find(previous_.begin(), previous_.end(), cur);
  if (before == previous_.end()) return Look::kNew;  // read only once unchanged since the last poll
  cur.first_stable = before->first_stable;
  return Look::kStable;
}

RecordFolder::Read RecordFolder::read(const std::string& name, Seen& cur, Nanos now, control::PanelJob& job,
                                      std::vector<RecordEvent>& events, const std::vector<std::string>& also_taken) {
  const std::string path = (fs::path(folder_) / name).string();
  std::string text;
  try {
    text = read_bounded_file(path, kMaxRecordBytes, "an inspection record", false);
  } catch (const FileRefused& e) {
    events.push_back(reject(name, e.what()));
    return Read::kRejected;
  }
  if (!ends_with_end_marker(text)) {
    if (cur.first_stable < 0) cur.first_stable = now;
    if (now - cur.first_stable < incomplete_wait_) return Read::kWait;  // still being written, perhaps
    events.push_back(reject(name, path + ": incomplete: its last line is not YAML's end-of-document marker '...' (written in "
                                          "place and never finished? write NAME.yaml.part, then rename it)"));
    return Read::kRejected;
  }
  try {
    job = parse_inspection_record(text, path, panel_types_);
    const std::string id(job.panel_id.view());
    if (std::find(recent_ids_.begin(), recent_ids_.end(), id) != recent_ids_.end() ||
        std::find(also_taken.begin(), also_taken.end(), id) != also_taken.end()) {
      // (its id in the rejected line: the results file then names the panel it repeats)
      events.push_back(reject(name, path + ": panel_id: '" + id + "' was already received (a duplicate record)", id));
      return Read::kRejected;
    }
  } catch (const RecordInvalid& e) {
    events.push_back(reject(name, e.what()));
    return Read::kRejected;
  }
  return Read::kOk;
}

RecordEvent RecordFolder::accept(const std::string& name, const control::PanelJob& job) {
  RecordEvent ev;
  ev.kind = RecordEvent::Kind::kAccepted;
  ev.panel_id = std::string(job.panel_id.view());
  remember(ev.panel_id);
  fs::create_directories(fs::path(folder_) / "accepted");
  fs::rename(fs::path(folder_) / name, offering_);
  ev.file = offering_;
  return ev;
}

std::vector<RecordEvent> RecordFolder::poll(const std::function<bool(const control::PanelJob&)>& offer, Nanos now) {
  std::vector<RecordEvent> events;
  // The candidates, in name order (the station names them in the order it made them).
  std::vector<Seen> seen_now;
  int rejects = 0;
  // Once a record waits (being written, or for the sequence), none after it is taken or
  // read: order is kept. The later ones are still looked at, so that they count as
  // unchanged at the next poll, and the ones that are no regular file are rejected.
  bool blocked = false;
  for (const std::string& name : candidates()) {
    if (rejects >= kRejectsPerPoll) blocked = true;  // the rest next time (still looked at)
    Seen cur;
    const Look l = look(name, cur, rejects < kRejectsPerPoll, events);
    if (l == Look::kRejected) ++rejects;
    if (l == Look::kGone || l == Look::kRejected || l == Look::kSkipped) continue;
    seen_now.push_back(cur);
    if (blocked || l == Look::kNew) {
      blocked = true;
      continue;
    }
    if (!(parsed_of_ && *parsed_of_ == cur)) {
      parsed_.reset();
      parsed_of_.reset();
      control::PanelJob job;
      const Read r = read(name, seen_now.back(), now, job, events);
      if (r == Read::kRejected) {
        ++rejects;
        seen_now.pop_back();
        continue;
      }
      if (r == Read::kWait) {
        blocked = true;
        continue;
      }
      parsed_ = std::move(job);
      parsed_of_ = cur;
    }
    offering_ = unique_in("accepted", name);
    if (!offer(*parsed_)) {  // the sequence still holds one: this waits, parsed
      blocked = true;
      continue;
    }
    events.push_back(accept(name, *parsed_));
    parsed_.reset();
    parsed_of_.reset();
    seen_now.pop_back();
    blocked = true;  // one record a poll
  }
  previous_ = std::move(seen_now);
  return events;
}

std::vector<RecordEvent> RecordFolder::poll_by_id(const std::function<bool(const control::PanelJob&)>& offer,
                                                  const msg::LineArrival& wanted, Nanos expiry, Nanos now) {
  std::vector<RecordEvent> events;
  std::vector<Seen> seen_now;
  std::vector<Pooled> kept;  // the pool's records still in the folder, unchanged
  std::vector<std::string> pooled_ids;
  int rejects = 0;
  for (const std::string& name : candidates()) {
    Seen cur;
    const Look l = look(name, cur, rejects < kRejectsPerPoll, events);
    if (l == Look::kRejected) ++rejects;
    if (l == Look::kGone || l == Look::kRejected || l == Look::kSkipped) continue;
    seen_now.push_back(cur);
    if (l == Look::kNew) continue;
    const auto in_pool = std::find_if(pool_.begin(), pool_.end(), [&](const Pooled& p) { return p.seen == cur; });
    if (in_pool != pool_.end()) {
      pooled_ids.emplace_back(in_pool->job->panel_id.view());
      kept.push_back(std::move(*in_pool));
      continue;
    }
    if (kept.size() >= kMaxPool || rejects >= kRejectsPerPoll) continue;  // read at a later poll
    auto job = std::make_unique<control::PanelJob>();
    const Read r = read(name, seen_now.back(), now, *job, events, pooled_ids);
    if (r == Read::kRejected) {
      ++rejects;
      seen_now.pop_back();
      continue;
    }
    if (r == Read::kWait) continue;
    pooled_ids.emplace_back(job->panel_id.view());
    kept.push_back(Pooled{cur, std::move(job), now});
  }
  pool_ = std::move(kept);
  const auto drop = [&](std::size_t i) {
    const std::string name = pool_[i].seen.name;
    seen_now.erase(std::remove_if(seen_now.begin(), seen_now.end(), [&](const Seen& s) { return s.name == name; }),
                   seen_now.end());
    pool_.erase(pool_.begin() + static_cast<std::ptrdiff_t>(i));
  };
  // Expired: their panel was never announced within the expiry (taken off the line).
  for (std::size_t i = 0; i < pool_.size();) {
    if (now - pool_[i].read_at <= expiry) {
      ++i;
      continue;
    }
    const std::string id(pool_[i].job->panel_id.view());
    events.push_back(reject(pool_[i].seen.name,
                            (fs::path(folder_) / pool_[i].seen.name).string() + ": expired: the line announced no panel '" +
                                id + "' within " + std::to_string(expiry / seconds(1)) + " s (marking.record_expiry_s)",
                            id));
    drop(i);
  }
  // The announced panel's record, once per announcement.
  if (wanted.counter != 0 && wanted.counter != offered_counter_) {
    const auto it = std::find_if(pool_.begin(), pool_.end(),
                                 [&](const Pooled& p) { return p.job->panel_id.view() == wanted.panel_id.view(); });
    if (it != pool_.end()) {
      const std::size_t i = static_cast<std::size_t>(it - pool_.begin());
      const control::PanelJob& job = *it->job;
      if (!wanted.panel_type.empty() && wanted.panel_type.view() != job.panel_type.view()) {
        offered_counter_ = wanted.counter;
        events.push_back(reject(it->seen.name,
                                (fs::path(folder_) / it->seen.name).string() + ": panel_type: '" +
                                    std::string(job.panel_type.view()) + "', but the line announced panel '" +
                                    std::string(wanted.panel_id.view()) + "' as '" + std::string(wanted.panel_type.view()) + "'",
                                std::string(job.panel_id.view())));
        drop(i);
      } else {
        offering_ = unique_in("accepted", it->seen.name);
        it->job->announced = wanted.counter;  // (the sequence answers it if the line moves on)
        if (offer(job)) {  // (false: the sequence still holds one; the next poll tries again)
          offered_counter_ = wanted.counter;
          events.push_back(accept(it->seen.name, job));
          drop(i);
        }
      }
    }
  }
  previous_ = std::move(seen_now);
  return events;
}

void RecordFolder::remember(const std::string& panel_id) {
  recent_ids_.push_back(panel_id);
  if (recent_ids_.size() > kRecentIds) recent_ids_.pop_front();
}

}  // namespace markcell::host
