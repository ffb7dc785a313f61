// Catch2's implementation for test programs with their own main (they call
// markcell_run_catch); compiled without the project's warning flags, like catch_main.cpp.
#define CATCH_CONFIG_RUNNER
#include <catch2/catch.hpp>

int markcell_run_catch(int argc, char** argv) { return Catch::Session().run(argc, argv); }
