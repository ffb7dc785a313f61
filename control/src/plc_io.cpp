#include "markcell/control/plc_io.hpp"

namespace markcell::control {

TaskResult PlcIo::step(const TaskContext& ctx) noexcept {
  // Edges first: a panel-present pulse shorter than a tick is still seen, with its time.
  const int n = lines_.read_events(events_, 0);
  for (int i = 0; i < n; ++i) {
    const auto& e = events_[static_cast<std::size_t>(i)];
    if (e.line == map_.panel_present && e.active) inputs_.panel_present_since = e.time;
  }
  auto read = [&](int line, bool& out) {
    if (line < 0) return;
    if (lines_.get(line, out) != drivers::GpioStatus::kOk) ++io_errors_;
  };
  read(map_.panel_present, inputs_.panel_present);
  read(map_.cycle_enable, inputs_.cycle_enable);
  read(map_.estop, inputs_.estop);

  if (inputs_.estop && !safe_stop_.active())
    safe_stop_.trigger(ctx.now(), FaultCode::kOperatorStop, "plc_estop", "e-stop input active");
  const bool stopped = safe_stop_.active();
  auto write = [&](int line, bool value) {
    if (line >= 0 && lines_.set(line, value) != drivers::GpioStatus::kOk) ++io_errors_;
  };
  write(map_.ready, inputs_.cycle_enable && !stopped);
  if (stopped) write(map_.fault, true);
  return TaskResult::kOk;
}

}  // namespace markcell::control
