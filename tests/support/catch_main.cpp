// main() of the test programs without their own: Catch2's runner, whose implementation
// is compiled once, in catch_runner.cpp (the heaviest file of the suite to compile).
int markcell_run_catch(int argc, char** argv);

int main(int argc, char** argv) { return markcell_run_catch(argc, argv); }
