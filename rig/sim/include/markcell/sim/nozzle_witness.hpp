#pragma once
// The simulated world's nozzle: what the valve did and where the simulated arm's nozzle
// truly was then. The cell's simulated world (Cell::SimWorld) and the rig's peer behind
// real devices (rig::HilPeer) observe it every tick; the rig scores the sprays it kept.
#include <algorithm>
#include <array>
#include <cstddef>

#include "markcell/common/time.hpp"
#include "markcell/drivers/arm.hpp"
#include "markcell/sim/command_log.hpp"

namespace markcell::sim {

// What the simulated arm's nozzle did at each valve opening: the rig scores these.
struct SimSpray {
  Nanos time = 0;
  drivers::ToolPose tool;  // X_Base_Tool as the arm's mechanics had it, not as reported
  Nanos open_for = -1;     // how long the valve stayed open; -1 while it still is
};

// The simulated world's view of the nozzle, one tick at a time: each opening of the valve
// with the arm's true tool pose then, and each edge of the valve into the command log. The
// same for the world inside the cell (simulated time) and the rig's peer behind the real
// devices (rig::HilPeer). Every opening is counted, the newest kCapacity kept: spray(i)
// for i in [total() - kept(), total()), oldest first. Allocates nothing.
class NozzleWitness {
 public:
  static constexpr std::size_t kCapacity = 256;
  void observe(Nanos now, bool valve_open, const drivers::ToolPose& tool, CommandLog& log) noexcept {
    if (valve_open && !was_open_) sprays_[total_++ % kCapacity] = SimSpray{now, tool, -1};
    if (!valve_open && was_open_ && total_ > 0) {
      SimSpray& last = sprays_[(total_ - 1) % kCapacity];
      last.open_for = now - last.time;
    }
    if (valve_open != was_open_) log.valve(now, valve_open);
    was_open_ = valve_open;
  }
  std::size_t total() const { return total_; }
  std::size_t kept() const { return std::min(total_, kCapacity); }
  const SimSpray& spray(std::size_t i) const { return sprays_[i % kCapacity]; }

 private:
  bool was_open_ = false;
  std::array<SimSpray, kCapacity> sprays_{};
  std::size_t total_ = 0;
};

}  // namespace markcell::sim
