#pragma once
// The line's word on which panel comes to the station next: from the panel-id source (the
// PLC over Modbus TCP, host/plc_link.hpp) to the marking task, through a triple buffer
// (the newest word; the PLC's registers hold one panel's identity at a time). A leaf, as
// msg/pose_estimate.hpp.
#include <cstdint>

#include "markcell/common/fixed_string.hpp"
#include "markcell/common/time.hpp"

namespace markcell::msg {

struct LineArrival {
  // The PLC's arrival counter: it changes once per panel announced (0: none yet). Two
  // panels with the same id are two counts.
  std::uint32_t counter = 0;
  FixedString<63> panel_id;
  FixedString<31> panel_type;
  // The cell's clock when the PLC last answered a poll (-1: never since the start).
  Nanos heard = -1;
};

}  // namespace markcell::msg
