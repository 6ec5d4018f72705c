// TEMPORARY: removed when cli/demo.cpp and cli/simulate.cpp land.
#include "commands.hpp"
namespace partloc::cli {
int command_demo(const std::string&, std::uint64_t, int) { return 2; }
int command_simulate(const std::string&, std::uint64_t) { return 2; }
}  // namespace partloc::cli
