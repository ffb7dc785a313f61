#include "markcell/host/build_version.hpp"

#include "markcell/build_info.hpp"  // generated: firmware_host/cmake/build_info.cmake

namespace markcell::host {

const char* build_version() { return MARKCELL_VERSION; }
const char* build_commit() { return MARKCELL_GIT_COMMIT; }

}  // namespace markcell::host
