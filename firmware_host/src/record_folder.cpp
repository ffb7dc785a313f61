#include "markcell/host/record_folder.hpp"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <stdexcept>

#include "markcell/host/inspection_record.hpp"

namespace markcell::host {

namespace fs = std::filesystem;

RecordFolder::RecordFolder(std::string folder, std::vector<PanelTypeConfig> panel_types)
    : folder_(std::move(folder)), panel_types_(std::move(panel_types)) {
  if (!fs::is_directory(folder_)) throw std::runtime_error("record folder '" + folder_ + "' does not exist");
  fs::create_directories(fs::path(folder_) / "accepted");
  fs::create_directories(fs::path(folder_) / "rejected");
}

std::optional<RecordEvent> RecordFolder::poll(const std::function<bool(const control::PanelJob&)>& offer) {
  // The first complete record by name (the station names them in the order it made them).
  std::optional<fs::path> first;
  for (const auto& e : fs::directory_iterator(folder_)) {
    if (!e.is_regular_file() || e.path().extension() != ".yaml") continue;
    if (!first || e.path().filename() < first->filename()) first = e.path();
  }
  if (!first) return std::nullopt;
  RecordEvent ev;
  const auto move_to = [&](const char* sub) {
    const fs::path to = fs::path(folder_) / sub / first->filename();
    fs::rename(*first, to);
    ev.file = to.string();
  };
  control::PanelJob job;
  try {
    job = read_inspection_record(first->string(), panel_types_);
    ev.panel_id = std::string(job.panel_id.view());
    if (std::find(recent_ids_.begin(), recent_ids_.end(), ev.panel_id) != recent_ids_.end())
      throw RecordInvalid(first->string() + ": panel_id: '" + ev.panel_id + "' was already received (a duplicate record)");
  } catch (const RecordInvalid& e) {
    ev.kind = RecordEvent::Kind::kRejected;
    ev.reason = e.what();
    move_to("rejected");
    std::ofstream(ev.file + ".reason") << ev.reason << "\n";
    return ev;
  }
  offering_ = (fs::path(folder_) / "accepted" / first->filename()).string();
  if (!offer(job)) return std::nullopt;  // the sequence still holds one: this waits
  remember(ev.panel_id);
  ev.kind = RecordEvent::Kind::kAccepted;
  move_to("accepted");
  return ev;
}

void RecordFolder::remember(const std::string& panel_id) {
  recent_ids_.push_back(panel_id);
  if (recent_ids_.size() > kRecentIds) recent_ids_.pop_front();
}

}  // namespace markcell::host
