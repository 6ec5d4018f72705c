// TEMPORARY: removed when cli/run.cpp lands.
#include "commands.hpp"
namespace partloc::cli {
int command_run(const std::string&, const std::string&, int, std::uint64_t) { return 2; }
}  // namespace partloc::cli
