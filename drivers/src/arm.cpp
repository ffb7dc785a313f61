#include "markcell/drivers/arm.hpp"

namespace markcell::drivers {

std::string_view to_string(ArmMode mode) {
  switch (mode) {
    case ArmMode::kHold: return "hold";
    case ArmMode::kMove: return "move";
    case ArmMode::kHome: return "home";
    case ArmMode::kStop: return "stop";
  }
  return "unknown";
}

std::string_view to_string(ArmLinkStatus status) {
  switch (status) {
    case ArmLinkStatus::kInactive: return "inactive";
    case ArmLinkStatus::kConnecting: return "connecting";
    case ArmLinkStatus::kOk: return "ok";
    case ArmLinkStatus::kHeartbeatLost: return "heartbeat_lost";
    case ArmLinkStatus::kRefused: return "refused";
    case ArmLinkStatus::kArmFault: return "arm_fault";
    case ArmLinkStatus::kNoAck: return "no_ack";
    case ArmLinkStatus::kBusOff: return "bus_off";
    case ArmLinkStatus::kIoError: return "io_error";
  }
  return "unknown";
}

}  // namespace markcell::drivers
