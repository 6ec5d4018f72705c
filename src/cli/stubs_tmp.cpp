// TEMPORARY: replaced by run.cpp, demo.cpp, simulate.cpp as they land.
#include "commands.hpp"
namespace partloc::cli {
int command_run(const std::string&, const std::string&, int, std::uint64_t) { return 2; }
int command_demo(const std::string&, std::uint64_t, int) { return 2; }
int command_simulate(const std::string&, std::uint64_t) { return 2; }
}  // namespace partloc::cli
