#include "markcell/control/marking.hpp"

int a; int b;  // a line with semicolons, which CMake lists split on
#include "markcell/vision/panel_tracker.hpp"
